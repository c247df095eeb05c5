"""On-disk cache of built acceleration structures (kd-trees; the BVH's in rtlab.accel.bvh), keyed by
mesh content and build parameters.

A structure is stored as one uncompressed ``.npz`` in ``rtlab.paths.accel_cache_dir()`` (or
``cache_dir``), named by sha256(vertices bytes, faces bytes, shapes, params.key(), format version).
Files are written to a temporary name and renamed into place, so readers never see a partial file;
a file that cannot be read back is rebuilt. ``RTLAB_NO_CACHE=1`` turns the cache off.
"""
from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path

import numpy as np

from .. import paths
from .kdtree import KdBuildParams, KdTree, build_kdtree

# Bump when the builder's output for the same inputs changes (split rules, node layout, ...)
FORMAT_VERSION = "kdtree-v2"


def cache_key(vertices: np.ndarray, faces: np.ndarray, params, format_version: str = FORMAT_VERSION) -> str:
    """The file name (without .npz) of a structure built by ``params`` (its ``key()``) over this mesh."""
    v = np.ascontiguousarray(vertices, np.float32)
    f = np.ascontiguousarray(faces, np.int32)
    h = hashlib.sha256()
    h.update(f"{format_version}|{params.key()}|v{v.shape}|f{f.shape}|".encode())
    h.update(memoryview(v).cast("B"))
    h.update(memoryview(f).cast("B"))
    return h.hexdigest()


def atomic_savez(path: Path, **arrays) -> None:
    """np.savez, written atomically (rtlab.paths.write_atomically)."""
    paths.write_atomically(path, lambda f: np.savez(f, **arrays))


def load_or_build(path: Path, load, build, save, what: str, progress=None):
    """The structure stored at ``path`` (``load(path)``), else ``build()`` and ``save(path, it)``;
    returns (structure, from_cache). A file that cannot be read back is rebuilt over; one that
    cannot be written (a read-only or full cache) leaves the structure good and says so once."""
    if path.is_file():
        try:
            return load(path), True
        except Exception as exc:          # corrupt or foreign file: rebuild over it
            if progress is not None:
                progress(f"{what} cache unreadable ({exc}); rebuilding")
    built = build()
    try:
        save(path, built)
    except OSError as exc:
        warnings.warn(f"{what} cache not written to {path.parent}: {exc}", stacklevel=3)
    return built, False


def _save(path: Path, tree: KdTree) -> None:
    atomic_savez(path, nodes=tree.nodes, objects=tree.objects, bounds=tree.bounds,
                 depth=np.int64(tree.depth), build_seconds=np.float64(tree.build_seconds),
                 sah_cost=np.float64(tree.sah_cost), format=np.str_(FORMAT_VERSION))


def _load(path: Path, params: KdBuildParams) -> KdTree:
    with np.load(path, allow_pickle=False) as z:
        if str(z["format"]) != FORMAT_VERSION:
            raise ValueError(f"{path.name}: format {z['format']}, expected {FORMAT_VERSION}")
        nodes, objects, bounds = z["nodes"], z["objects"], z["bounds"]
        if (nodes.dtype != np.int32 or nodes.ndim != 2 or nodes.shape[1] != 2
                or objects.dtype != np.int32 or bounds.shape != (2, 3)):
            raise ValueError(f"{path.name}: unexpected array shapes or types")
        return KdTree(nodes, objects, bounds.astype(np.float32), int(z["depth"]), params,
                      float(z["build_seconds"]), float(z["sah_cost"]))


def load_or_build_kdtree(vertices: np.ndarray, faces: np.ndarray,
                         params: KdBuildParams = KdBuildParams(), cache_dir: str | os.PathLike | None = None,
                         progress=None) -> tuple[KdTree, bool]:
    """The kd-tree of a mesh, from the cache when it was built before; returns (tree, from_cache).

    ``build_seconds`` of a cached tree is the time its original build took.
    progress: optional ``progress(message: str)``.
    """
    if not paths.cache_enabled():
        return build_kdtree(vertices, faces, params, progress), False
    directory = Path(cache_dir) if cache_dir is not None else paths.accel_cache_dir()
    directory.mkdir(parents=True, exist_ok=True)

    def load(path):
        tree = _load(path, params)
        if progress is not None:
            progress(f"kd-tree from cache ({len(tree.nodes):,} nodes)")
        return tree

    def build():
        if progress is not None:
            progress(f"building kd-tree over {len(faces):,} triangles")
        return build_kdtree(vertices, faces, params, progress)

    return load_or_build(directory / f"{cache_key(vertices, faces, params)}.npz", load, build, _save, "kd-tree",
                         progress)
