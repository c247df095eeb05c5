"""A non-editable install works from any directory: the wheel ships kernels/ and labs/
as rtlab/_data, and rtlab run from an unpacked wheel, in another directory, finds them there,
renders and writes a lab template. scripts/check_wheel.sh does the same from a fresh venv (CI).
Also: caches still work without a writable home.
"""
from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import pytest

import rtlab
from rtlab.paths import PROJECT_DIR

DATA_PACKAGES = {"rtlab._data.kernels": "kernels", "rtlab._data.labs": "labs"}


def _pyproject() -> dict:
    return tomllib.loads((PROJECT_DIR / "pyproject.toml").read_text())


def _source_files(folder: str) -> list[str]:
    """Files of the checkout's folder that ship: git's list when this is a git checkout (so stray
    local files do not count), else every file below it."""
    try:
        out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", folder],
                             cwd=PROJECT_DIR, capture_output=True, text=True, check=True).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        out = [p.relative_to(PROJECT_DIR).as_posix() for p in (PROJECT_DIR / folder).rglob("*") if p.is_file()]
    return [f for f in out if "__pycache__" not in f]


def test_pyproject_lists_every_package():
    """setuptools gets an explicit package list (the data packages are mapped folders, which
    discovery cannot find): it must name every package under rtlab/."""
    config = _pyproject()["tool"]["setuptools"]
    on_disk = {".".join(p.parent.relative_to(PROJECT_DIR).parts) for p in (PROJECT_DIR / "rtlab").rglob("__init__.py")}
    assert set(config["packages"]) == on_disk | set(DATA_PACKAGES)
    assert config["package-dir"] == DATA_PACKAGES


def _build_isolation_args() -> list[str]:
    """Build with this environment's setuptools when it can (>= 68, and bdist_wheel: built in
    from 70.1, else the wheel package), so no index is needed; else pip's isolated build."""
    try:
        major, minor = (int(x) for x in version("setuptools").split(".")[:2])
    except (PackageNotFoundError, ValueError):
        return []
    has_bdist_wheel = (major, minor) >= (70, 1) or importlib.util.find_spec("wheel") is not None
    return ["--no-build-isolation"] if major >= 68 and has_bdist_wheel else []


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel, built from a copy of the checkout (no build/ leftovers) as pip builds it."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    src.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "build", "dist", ".venv")
    for item in ("pyproject.toml", "README.md", "rtlab", "kernels", "labs"):
        path = PROJECT_DIR / item
        if path.is_dir():
            shutil.copytree(path, src / item, ignore=ignore)
        else:
            shutil.copy2(path, src / item)
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", *_build_isolation_args(), "-q",
                           "-w", str(tmp / "dist"), str(src)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    [whl] = (tmp / "dist").glob("rtlab-*.whl")
    return whl


def test_wheel_ships_kernels_labs_and_package_data(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for folder in ("kernels", "labs"):
        files = _source_files(folder)
        assert files, folder
        missing = [f for f in files if f"rtlab/_data/{f}" not in names]
        assert not missing, f"not in the wheel: {missing}"
    package_data = [p.relative_to(PROJECT_DIR).as_posix() for p in (PROJECT_DIR / "rtlab").rglob("*")
                    if p.is_file() and p.suffix not in (".py", ".pyc") and "__pycache__" not in p.parts
                    and not p.name.endswith((".nbi", ".nbc"))]
    assert package_data and not [f for f in package_data if f not in names]
    assert not [n for n in names if n.startswith(("kernels/", "labs/"))], "top-level folders in site-packages"


def _run_installed(site: Path, cwd: Path, *args, env_extra=None):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "RTLAB_KERNEL_DIR")}
    env.update(PYTHONPATH=str(site), RTLAB_CACHE=str(cwd / "cache"), **(env_extra or {}))
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> tuple[Path, Path]:
    """(site, elsewhere): the wheel unpacked as pip would lay it out in site-packages, and an empty
    directory outside the checkout to run it from."""
    tmp = tmp_path_factory.mktemp("installed")
    zipfile.ZipFile(wheel).extractall(tmp / "site")
    (tmp / "elsewhere").mkdir()
    return tmp / "site", tmp / "elsewhere"


def test_installed_copy_finds_its_data(installed):
    site, elsewhere = installed
    code = ("import rtlab, rtlab.paths as p, rtlab.device.kernels as k; "
            "print(rtlab.__file__); print(p.IN_CHECKOUT); print(p.DATA_ROOT); print(','.join(k.lab_steps()))")
    proc = _run_installed(site, elsewhere, "-c", code)
    assert proc.returncode == 0, proc.stderr
    module, in_checkout, data_root, steps = proc.stdout.split()
    assert Path(module).is_relative_to(site) and in_checkout == "False"
    assert Path(data_root) == site / "rtlab" / "_data"
    assert "00_primary" in steps.split(",")


def test_installed_lab_template(installed):
    """rtlab lab template from the installed copy writes what the checkout's generator writes."""
    from rtlab.course.config import load_config
    from rtlab.course.template import template_files
    site, elsewhere = installed
    proc = _run_installed(site, elsewhere, "-m", "rtlab", "lab", "template", "00_primary", "--out", "tpl")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    expected = template_files(load_config("00_primary"))
    assert expected
    for rel, text in expected.items():
        assert (elsewhere / "tpl" / rel).read_bytes() == text.encode("latin-1")   # templates keep the bytes


@pytest.mark.slow
def test_installed_render(installed):
    """rtlab render from the installed copy compiles its kernels from rtlab/_data (a cold numba
    cache for this copy: the builder compiles once, with its progress line)."""
    site, elsewhere = installed
    proc = _run_installed(site, elsewhere, "-m", "rtlab", "render", "--size", "16", "--repeats", "1",
                          "--out", "r.png", env_extra={"NUMBA_CACHE_DIR": str(elsewhere / "numba")})
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stdout + proc.stderr
    assert "compiling the BVH builder" in proc.stdout         # the CPU default reads a BVH, no kd-tree
    assert (elsewhere / "r.png").stat().st_size > 0


def test_no_writable_home_caches_in_tmp(tmp_path):
    """A home whose cache cannot be created (a file in the way: unwritable even for root) sends
    $XDG_CACHE_HOME, and with it rtlab's, numba's and pyopencl's caches, to the temporary directory
    (once the process needs one: numba through rtlab.jit here)."""
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    env = {k: v for k, v in os.environ.items() if k not in ("XDG_CACHE_HOME", "RTLAB_CACHE")}
    env.update(HOME=str(blocker / "home"), TMPDIR=str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    code = "import os, rtlab.jit, rtlab.paths as p; print(os.environ['XDG_CACHE_HOME']); print(p.user_cache_dir())"
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120,
                          cwd=Path(rtlab.__file__).parent.parent)
    assert proc.returncode == 0, proc.stderr
    xdg, cache = proc.stdout.split()
    assert Path(xdg).parent == tmp_path / "tmp" and Path(cache).is_relative_to(xdg)
