"""What the collapsed wide BVHs (rtlab.accel.bvh4, bvh8) keep and how they are cached: their rows in a
traversal's layout (nodes, then triangles), the tree facts, and the on-disk cache entry, once for both."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from .. import paths
from .cache import atomic_savez, cache_key, load_or_build


@dataclass
class WideBvh:
    rows: np.ndarray         # (R, 4) float32: nodes, then triangles (the traversal's layout)
    n_nodes: int
    tri_ids: np.ndarray      # (T,) int32 triangle ids in leaf order
    bounds: np.ndarray       # (2, 3) float32 root box
    depth: int               # nodes on the longest root-to-leaf path: the stack needs at most depth entries
    cost: float              # the collapse's SAH cost (C(root) / area(root))
    binary: str              # "plain" or "split": the binary tree it was collapsed from
    params: object
    build_seconds: float = 0.0
    node_rows: ClassVar[int] = 0     # float4 rows a node and a triangle (the subclass's layout)
    tri_rows: ClassVar[int] = 0
    format_version: ClassVar[str] = ""

    @property
    def tri_row0(self) -> int:
        return self.node_rows * self.n_nodes

    def save(self, path: Path) -> None:
        atomic_savez(path, rows=self.rows, n_nodes=np.int64(self.n_nodes), tri_ids=self.tri_ids, bounds=self.bounds,
                     depth=np.int64(self.depth), cost=np.float64(self.cost), binary=np.str_(self.binary),
                     build_seconds=np.float64(self.build_seconds), format=np.str_(self.format_version))

    @classmethod
    def load(cls, path: Path, params) -> "WideBvh":
        with np.load(path, allow_pickle=False) as z:
            if str(z["format"]) != cls.format_version:
                raise ValueError(f"{path.name}: format {z['format']}, expected {cls.format_version}")
            rows, n_nodes, tri_ids = z["rows"], int(z["n_nodes"]), z["tri_ids"]
            if (rows.dtype != np.float32 or rows.ndim != 2 or rows.shape[1] != 4 or tri_ids.dtype != np.int32
                    or rows.shape[0] != cls.node_rows * n_nodes + cls.tri_rows * len(tri_ids)):
                raise ValueError(f"{path.name}: unexpected array shapes or types")
            return cls(rows, n_nodes, tri_ids, z["bounds"], int(z["depth"]), float(z["cost"]), str(z["binary"]),
                       params, float(z["build_seconds"]))

    @classmethod
    def cached(cls, vertices, faces, params, build, what: str, cache_dir: str | os.PathLike | None = None):
        """(tree, from_cache): from the on-disk cache (keyed like the other structures: mesh content and
        build parameters; RTLAB_NO_CACHE=1 turns it off), else ``build()`` and stored."""
        if not paths.cache_enabled():
            return build(), False
        directory = Path(cache_dir) if cache_dir is not None else paths.accel_cache_dir()
        directory.mkdir(parents=True, exist_ok=True)
        path = directory / f"{cache_key(vertices, faces, params, cls.format_version)}.npz"
        return load_or_build(path, lambda p: cls.load(p, params), build, lambda p, b: b.save(p), what)
