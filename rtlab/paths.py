"""Where rtlab finds its kernels, lab steps, scene files and caches.

Kernels and lab steps: ``kernels/`` and ``labs/`` are the course's source of truth at the top of a
checkout (or of a student release, which has the same layout); a wheel ships them inside the
package as ``rtlab/_data/kernels`` and ``rtlab/_data/labs`` (pyproject.toml maps the folders
there, as PyOpenCL ships its device headers), so a plain ``pip install .`` works from any
directory. ``DATA_ROOT`` is the folder holding both, so a path named as in the checkout
(``kernels/shared/rt_types.h`` in a grading.toml) is ``DATA_ROOT / path`` in either. A checkout
wins when the package runs from one (editable install, or ``python -m rtlab`` in it).

Scene files: ``$RTLAB_SCENES``, then ``../shared/scenes`` beside the checkout, then a per-user cache
(``platformdirs.user_cache_dir('rtlab')/scenes``). Acceleration structures are cached under
``$RTLAB_CACHE`` or the per-user cache.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import platformdirs

from . import settings

PACKAGE_DIR = Path(__file__).resolve().parent
# The folder above the package: a checkout's root, or site-packages for an installed wheel
PROJECT_DIR = PACKAGE_DIR.parent


def _is_source_tree(root: Path) -> bool:
    """Whether root holds the course's kernels/ and labs/ (checked by a file of each, so a foreign
    ``kernels`` folder in site-packages is never taken for rtlab's)."""
    try:
        return (root / "kernels" / "shared" / "rt_port.h").is_file() and (root / "labs").is_dir()
    except OSError:         # a folder this user may not enter (the grader's test processes)
        return False


IN_CHECKOUT = _is_source_tree(PROJECT_DIR)
DATA_ROOT = PROJECT_DIR if IN_CHECKOUT else PACKAGE_DIR / "_data"
# The reference kernels, always these (the grader compiles the reference from here)
REFERENCE_KERNEL_DIR = DATA_ROOT / "kernels"
# $RTLAB_KERNEL_DIR swaps in other kernel sources: the grader compiles a submission from a copy of
# kernels/ with the student's files laid over it. The tree at startup; kernel_dir() is the one in use.
KERNEL_DIR = Path(settings.get("RTLAB_KERNEL_DIR") or REFERENCE_KERNEL_DIR)
SHARED_KERNEL_DIR = KERNEL_DIR / "shared"
LABS_DIR = DATA_ROOT / "labs"
_kernel_dir = KERNEL_DIR
# $RTLAB_KERNEL_DIR is checked at first use, as --kernels is when given: a mistyped export would
# otherwise compile nothing and be summed up as a tree with every lab function written
_kernel_dir_checked = not settings.get("RTLAB_KERNEL_DIR")


def kernel_dir() -> Path:
    """The kernel sources this process compiles from (shared/, cuda/, opencl/)."""
    global _kernel_dir_checked
    if not _kernel_dir_checked:
        _check_kernel_tree(_kernel_dir, " (from $RTLAB_KERNEL_DIR)")
        _kernel_dir_checked = True
    return _kernel_dir


# What a stubbed solution region holds (rtlab.course.regions writes it): a student tree's unwritten functions
STUB_MARK = "TODO (lab "


def tree_has_stubs(relpath: str) -> bool:
    """Whether file ``relpath`` of the kernel sources in use (e.g. "shared/rt_intersect_lanes.h") holds a
    stubbed solution region: a student release or a grading tree."""
    try:
        return STUB_MARK in (kernel_dir() / relpath).read_text(errors="replace")
    except OSError:
        return False


def use_kernel_dir(root) -> Path:
    """Compile from the kernel sources at ``root`` from now on in this process (``rtlab render --kernels
    DIR``, the grader's reference); returns the tree used before."""
    global _kernel_dir, _kernel_dir_checked
    root = Path(root).expanduser().resolve()
    _check_kernel_tree(root)
    previous, _kernel_dir, _kernel_dir_checked = _kernel_dir, root, True
    return previous


def _check_kernel_tree(root: Path, origin: str = "") -> None:
    """A VariantError unless ``root`` holds shared/ and opencl/ or cuda/ under a UTF-8 name (the
    compilers take include paths as UTF-8 text)."""
    from .errors import VariantError
    try:
        str(root).encode("utf-8")
    except UnicodeEncodeError:
        shown = os.fsencode(root).decode("utf-8", "backslashreplace")
        raise VariantError(f"{shown}{origin}: file names must be UTF-8 (rename the folder)") from None
    if not (root / "shared").is_dir() or not ((root / "opencl").is_dir() or (root / "cuda").is_dir()):
        raise VariantError(f"{root}{origin} is not a folder of kernel sources: it needs shared/ and opencl/ or cuda/ "
                           f"(a copy of the project's kernels/ folder)")


def include_dirs(source) -> list[Path]:
    """Where a kernel source's quoted includes are searched after its own folder: the shared headers
    of the tree it belongs to (kernels/opencl/x.cl -> kernels/shared), then the current tree's (the
    grader's harness kernels live outside any tree)."""
    own = Path(source).resolve().parent.parent / "shared"
    dirs = [own] if own.is_dir() else []
    current = kernel_dir() / "shared"
    if current not in dirs:
        dirs.append(current)
    return dirs


def user_cache_dir() -> Path:
    return Path(settings.get("RTLAB_CACHE") or platformdirs.user_cache_dir("rtlab"))


def scene_search_dirs() -> list[Path]:
    """Directories searched for scene files, in order."""
    dirs: list[Path] = []
    env = settings.get("RTLAB_SCENES")
    if env:
        dirs += [Path(p) for p in env.split(os.pathsep) if p]
    if IN_CHECKOUT:
        dirs.append(PROJECT_DIR.parent / "shared" / "scenes")
    dirs.append(user_cache_dir() / "scenes")
    unique: dict[Path, Path] = {}          # RTLAB_SCENES often names the checkout's own folder again
    for d in dirs:
        unique.setdefault(d.resolve(), d)
    return list(unique.values())


def find_scene_file(relpath: str) -> Path | None:
    """First existing ``dir/relpath`` over :func:`scene_search_dirs`, or None."""
    for d in scene_search_dirs():
        p = d / relpath
        if p.is_file():
            return p
    return None


def _writable_dir(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(path, os.W_OK | os.X_OK)


_PREPARED = False


def prepare_process() -> None:
    """What this process needs before numba, pyopencl or pycuda is first imported (rtlab.jit and the
    backends call it; ``import rtlab`` alone changes nothing): a writable cache folder, and numba's
    OpenMP workers waiting passively. Once per process."""
    global _PREPARED
    if _PREPARED:
        return
    _PREPARED = True
    # numba's prange (kd-tree and BVH builders, the float64 reference) runs on GNU OpenMP, whose default
    # spin-waiting made each parallel launch cost ~8 ms while other processes kept both cores of the
    # 2-core lab machine busy; passive workers started in ~0.05 ms (~5 % slower on an idle machine).
    # Read only when numba first starts its threads.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    ensure_user_cache()
    if "NUMBA_CACHE_DIR" not in os.environ:     # read when numba is first imported, right after this
        os.environ["NUMBA_CACHE_DIR"] = str(numba_cache_dir())


def numba_cache_dir(keep: int = 3) -> Path:
    """numba's cache of rtlab's compiled functions: a folder per content of the modules that compile
    with numba. numba revalidates a cached function by its own file's time stamp only, so a function
    that inlines another module's (the float64 reference's walk and its triangle test) would keep a
    stale compile when only that module changed. The ``keep`` most recent folders stay."""
    import hashlib
    digest = hashlib.sha256()
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        text = path.read_bytes()
        if b"jit import" in text:              # a module compiling with numba (rtlab.jit)
            digest.update(path.relative_to(PACKAGE_DIR).as_posix().encode() + b"\0" + text)
    root = user_cache_dir() / "numba"
    folder = root / digest.hexdigest()[:16]
    if not folder.is_dir():
        folder.mkdir(parents=True, exist_ok=True)
        import shutil
        older = sorted((d for d in root.iterdir() if d.is_dir() and d != folder), key=lambda d: d.stat().st_mtime)
        for stale in older[:max(0, len(older) - (keep - 1))]:
            shutil.rmtree(stale, ignore_errors=True)
    return folder


def ensure_user_cache() -> None:
    """Caches live in the per-user cache directory ($XDG_CACHE_HOME or ~/.cache): rtlab's trees,
    numba's compiled builder (numba's choice when the installed package's ``__pycache__`` is
    read-only), pyopencl's binaries. Where that cannot be written (no home, or a read-only one:
    some containers and service accounts), numba refuses to define cached functions and pyopencl
    fails; point $XDG_CACHE_HOME at a per-user folder in the temporary directory instead, so they
    all still work and cache. Runs before numba or pyopencl is imported (prepare_process)."""
    if _writable_dir(Path(platformdirs.user_cache_dir())):
        return
    uid = getattr(os, "getuid", lambda: "user")()
    os.environ["XDG_CACHE_HOME"] = str(Path(tempfile.gettempdir()) / f"rtlab-cache-{uid}")


def cache_enabled() -> bool:
    """Whether the on-disk caches (trees, parsed meshes) are used: ``RTLAB_NO_CACHE=1`` turns them off."""
    return not settings.flag("RTLAB_NO_CACHE")


def write_atomically(target: Path, write) -> None:
    """``write(file)`` to a temporary name beside ``target``, then rename it into place: a reader in
    another process never sees half a file, and two writers of the same entry do not clash."""
    fd, temporary = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(temporary, target)
    finally:
        Path(temporary).unlink(missing_ok=True)


def accel_cache_dir() -> Path:
    d = user_cache_dir() / "accel"
    d.mkdir(parents=True, exist_ok=True)
    return d
