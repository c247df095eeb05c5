"""A Gradescope autograder for one lab step: ``rtlab grade --bundle STEP --out DIR``.

DIR (and DIR/autograder.zip, what Gradescope takes) holds rtlab itself (pyproject, rtlab/,
kernels/, labs/), the scene files the step's tests load, and Gradescope's two scripts:
``setup.sh`` (run once when the image is built: PoCL from apt, Python >= 3.11, rtlab in a venv,
then a self-check that grades the reference, which also warms the kd-tree and kernel caches) and
``run_autograder`` (per submission: grades /autograder/submission, writes
/autograder/results/results.json, and writes one even when the grader cannot start).
"""
from __future__ import annotations

import shutil
import stat
import zipfile
from pathlib import Path

from ..paths import IN_CHECKOUT, PROJECT_DIR, find_scene_file
from .config import load_config
from .regions import LabError

VENV = "/opt/rtlab"
SOURCE = "/autograder/source"

SETUP_SH = """#!/usr/bin/env bash
# Gradescope runs this once, as root, when it builds the autograder image (Ubuntu). Written by
# `rtlab grade --bundle {step}`.
set -euo pipefail
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
# PoCL: OpenCL on the CPU, where the grader runs every test
apt-get install -y -qq --no-install-recommends pocl-opencl-icd ocl-icd-libopencl1 python3 python3-venv python3-pip
# rtlab needs Python >= 3.11 (Ubuntu 22.04's python3 is 3.10)
PY=""
for p in python3.13 python3.12 python3.11 python3; do
  if command -v "$p" >/dev/null && "$p" -c 'import sys; sys.exit(sys.version_info < (3, 11))'; then PY=$(command -v "$p"); break; fi
done
if [ -z "$PY" ]; then
  apt-get install -y -qq --no-install-recommends python3.11 python3.11-venv
  PY=$(command -v python3.11)
fi
"$PY" -m venv {venv}
{venv}/bin/pip install -q --upgrade pip
{venv}/bin/pip install -q -e {source}
# No OpenCL platform from apt (an old image)? PoCL from PyPI instead
{venv}/bin/python -c 'import pyopencl as cl; assert cl.get_platforms()' 2>/dev/null || \\
  {{ apt-get install -y -qq --no-install-recommends build-essential; {venv}/bin/pip install -q pocl-binary-distribution; }}
# Self-check: grade the reference solution (also builds the kd-trees and fills the caches)
export RTLAB_SCENES={source}/scenes RTLAB_CACHE=/autograder/cache
{venv}/bin/rtlab info
{venv}/bin/rtlab grade {step} {source} --backend opencl --format table --out /autograder/cache/self-check.json
"""

RUN_AUTOGRADER = """#!/usr/bin/env bash
# Gradescope runs this for every submission (files in /autograder/submission). Written by
# `rtlab grade --bundle {step}`. The grader writes results.json even when a test crashes or hangs;
# the fallback below covers a grader that cannot start at all.
export RTLAB_SCENES={source}/scenes RTLAB_CACHE=/autograder/cache RTLAB_BACKEND=opencl
mkdir -p /autograder/results
cd {source}
{venv}/bin/rtlab grade {step} /autograder/submission --backend opencl --format gradescope \\
    --out /autograder/results/results.json
status=$?
if [ ! -s /autograder/results/results.json ]; then
  printf '{{"score": 0, "output": "The autograder could not start (exit status %s). This is not your code: please tell the course staff.", "tests": []}}\\n' "$status" \\
    > /autograder/results/results.json
fi
"""

PROJECT_ITEMS = ("pyproject.toml", "README.md", "rtlab", "kernels", "labs")


def scene_files(step: str) -> list[tuple[str, Path]]:
    """(relpath, found path) of every scene file the step's tests load."""
    from ..scene.presets import PRESETS
    config = load_config(step)
    out = []
    for name in sorted({t.scene for t in config.tests}):
        preset = PRESETS.get(name)
        if preset is None:
            continue   # the procedural default scene needs no file
        for rel in (preset.relpath, *(r for r, _ in preset.companions)):
            path = find_scene_file(rel)
            if path is None:
                raise LabError(f"lab {step} needs scene file {rel}, not found; see `rtlab scenes`")
            out.append((rel, path))
    return out


def write_bundle(step: str, out: Path | None = None) -> Path:
    """Write the autograder folder and its zip; returns the zip's path."""
    load_config(step)
    if not IN_CHECKOUT:
        raise LabError("rtlab grade --bundle copies rtlab's sources: run it from a checkout (or a student "
                       "release) of rtlab, not an installed wheel")
    out = Path(out or f"autograder-{step}")
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info", "template")
    for item in PROJECT_ITEMS:
        src = PROJECT_DIR / item
        if src.is_dir():
            shutil.copytree(src, out / item, ignore=ignore if item != "labs" else shutil.ignore_patterns("__pycache__"))
        elif src.is_file():
            shutil.copy2(src, out / item)
    for rel, path in scene_files(step):
        dst = out / "scenes" / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(path, dst)
    fmt = {"step": step, "venv": VENV, "source": SOURCE}
    for name, text in (("setup.sh", SETUP_SH), ("run_autograder", RUN_AUTOGRADER)):
        p = out / name
        p.write_text(text.format(**fmt))
        p.chmod(p.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    zpath = out / "autograder.zip"
    with zipfile.ZipFile(zpath, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(out.rglob("*")):
            if f.is_file() and f != zpath:
                info = zipfile.ZipInfo.from_file(f, f.relative_to(out).as_posix())
                with open(f, "rb") as fh:
                    z.writestr(info, fh.read(), zipfile.ZIP_DEFLATED)
    return zpath
