"""Where rtlab finds its kernels, scene files and caches.

Scene files: ``$RTLAB_SCENES``, then ``../shared/scenes`` beside the checkout, then a per-user cache
(``platformdirs.user_cache_dir('rtlab')/scenes``). Acceleration structures are cached under
``$RTLAB_CACHE`` or the per-user cache.
"""
from __future__ import annotations

import os
from pathlib import Path

import platformdirs

PACKAGE_DIR = Path(__file__).resolve().parent
PROJECT_DIR = PACKAGE_DIR.parent
# $RTLAB_KERNEL_DIR swaps in another kernel tree: the grader compiles a submission from a copy of
# kernels/ with the student's files laid over it.
KERNEL_DIR = Path(os.environ.get("RTLAB_KERNEL_DIR") or PROJECT_DIR / "kernels")
SHARED_KERNEL_DIR = KERNEL_DIR / "shared"
LABS_DIR = PROJECT_DIR / "labs"


def user_cache_dir() -> Path:
    return Path(os.environ.get("RTLAB_CACHE") or platformdirs.user_cache_dir("rtlab"))


def scene_search_dirs() -> list[Path]:
    """Directories searched for scene files, in order."""
    dirs: list[Path] = []
    env = os.environ.get("RTLAB_SCENES")
    if env:
        dirs += [Path(p) for p in env.split(os.pathsep) if p]
    dirs.append(PROJECT_DIR.parent / "shared" / "scenes")
    dirs.append(user_cache_dir() / "scenes")
    return dirs


def find_scene_file(relpath: str) -> Path | None:
    """First existing ``dir/relpath`` over :func:`scene_search_dirs`, or None."""
    for d in scene_search_dirs():
        p = d / relpath
        if p.is_file():
            return p
    return None


def accel_cache_dir() -> Path:
    d = user_cache_dir() / "accel"
    d.mkdir(parents=True, exist_ok=True)
    return d
