"""A 4-wide BVH with float child boxes for the GPU traversal of kernels/shared/rt_bvh4.h.

Built as rtlab.accel.bvh8 builds its tree, with 4 slots a node: the binary SAH trees of
rtlab.accel.bvh (plain and spatial-split, from their disk cache) refined to one triangle a leaf, then
collapsed by Ylitie, Karras & Laine's dynamic programme (HPG 2017) with leaves of up to
``leaf_max`` triangles; the spatial-split tree kept where its cost is SPLIT_MIN_GAIN lower. Child
boxes stay float32 (exact), so the traversal's box test is rt_bvh.h's fused one; triangles in leaf
order after the nodes, as in the BVH8 (the scene's own vertex floats, the id in the first row's w).

Device layout (sync with rt_bvh4.h), node_data float4 rows; node at rows r .. r + 6 = 112 B:
  r + 0 .. r + 5  lo.x, hi.x, lo.y, hi.y, lo.z, hi.z of the four children (one float4 a plane)
  r + 6           child refs (int32 bits): >= 0 the row of an inner node; a leaf is
                  ~((first triangle row << LEAF_BITS) | count); an empty slot has the box
                  (+inf, -inf) and ref ~0
Triangles: three rows each, (v0.xyz, id bits), (v1.xyz, 0), (v2.xyz, 0). The root is row 0.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass

import numpy as np

from ..errors import RtlabError, SceneError
from ..kernel_constants import kernel_constant
from .bvh import Bvh
from .bvh8 import TRI_ROWS
from .bvh_collapse import PLAIN_BUILD, SPLIT_BUILD, collapse, collapse_best
from .wide_store import WideBvh

FORMAT_VERSION = "bvh4f-v1"
WIDTH = 4
NODE_ROWS = int(kernel_constant("BVH4_NODE_ROWS"))
LEAF_BITS = int(kernel_constant("BVH4_LEAF_BITS"))
MAX_COORD = 1e18                 # rt_bvh.h's fused box test stays finite below this (FUSED_BOX_MAX_COORD)
MAX_ROW = (1 << (31 - LEAF_BITS)) - 2   # a leaf ref addresses rows below this (BVH4_NONE is the next)


@dataclass(frozen=True)
class Bvh4BuildParams:
    """Collapse costs (a 4-wide node test costs about one triangle test: cost_prim 0.8), leaves of up
    to ``leaf_max`` triangles (<= 15), and which binary tree: "auto", "plain" or "split"."""
    cost_node: float = 1.0
    cost_prim: float = 0.8
    leaf_max: int = 8
    binary: str = "auto"

    def __post_init__(self):
        if self.binary not in ("auto", "plain", "split"):
            raise RtlabError(f"Bvh4BuildParams.binary must be 'auto', 'plain' or 'split', got {self.binary!r}")
        if not 1 <= self.leaf_max <= (1 << LEAF_BITS) - 1:
            raise RtlabError(f"BVH4 leaf_max must be 1..{(1 << LEAF_BITS) - 1}, got {self.leaf_max}")
        if not (self.cost_node > 0.0 and self.cost_prim > 0.0):
            raise RtlabError(f"BVH4 costs must be positive, got {self.cost_node}, {self.cost_prim}")

    def key(self) -> str:
        return (f"{FORMAT_VERSION}-cn{self.cost_node}-cp{self.cost_prim}-lm{self.leaf_max}-{self.binary}-"
                f"{PLAIN_BUILD.key()}-{SPLIT_BUILD.key()}")


class Bvh4(WideBvh):
    node_rows = NODE_ROWS
    tri_rows = TRI_ROWS
    format_version = FORMAT_VERSION

    def planes(self) -> np.ndarray:
        """(M, 6, 4) float32: lo.x, hi.x, lo.y, hi.y, lo.z, hi.z of each node's four slots."""
        return self.rows[:self.tri_row0].reshape(self.n_nodes, NODE_ROWS, 4)[:, :6]

    def refs(self) -> np.ndarray:
        """(M, 4) int32 child refs."""
        return self.rows[:self.tri_row0].reshape(self.n_nodes, NODE_ROWS, 4)[:, 6].view(np.int32)


def decode_leaf(ref: int) -> tuple[int, int]:
    """(first triangle row, count) of a leaf ref."""
    bits = ~int(ref)
    return bits >> LEAF_BITS, bits & ((1 << LEAF_BITS) - 1)


def collapse4(bvh: Bvh, vertices, faces, params: Bvh4BuildParams = Bvh4BuildParams()):
    """(wide-tree arrays, cost) of the binary BVH collapsed to 4 children a node (rtlab.accel.bvh_collapse)."""
    return collapse(bvh, vertices, faces, WIDTH, params.leaf_max, params.cost_node, params.cost_prim)


def _pack(vertices, faces, wide) -> tuple[np.ndarray, int, np.ndarray]:
    (n_lo, n_hi, kind, c_lo, c_hi, c_node, c_count, c_offset, child_base, tri_base, tris, _) = wide
    m = len(n_lo)
    tri_row0 = NODE_ROWS * m
    n_rows = tri_row0 + TRI_ROWS * len(tris)
    if n_rows > MAX_ROW:
        raise SceneError(f"BVH4: {n_rows:,} rows, more than a leaf ref addresses ({MAX_ROW:,})")
    rows = np.zeros((n_rows, 4), np.float32)
    nodes = rows[:tri_row0].reshape(m, NODE_ROWS, 4)
    valid = kind > 0
    for a in range(3):
        nodes[:, 2 * a, :] = np.where(valid, c_lo[:, :, a], np.float32(np.inf))
        nodes[:, 2 * a + 1, :] = np.where(valid, c_hi[:, :, a], np.float32(-np.inf))
    first = tri_row0 + TRI_ROWS * (tri_base[:, None] + c_offset)
    refs = np.where(kind == 1, NODE_ROWS * c_node, ~((first << LEAF_BITS) | c_count))
    refs = np.where(valid, refs, ~0)
    nodes.view(np.int32)[:, 6, :] = refs.astype(np.int32)
    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.int64)[tris]
    t = rows[tri_row0:].reshape(len(tris), TRI_ROWS, 4)
    for k in range(3):
        t[:, k, :3] = v[f[:, k]]
    t.view(np.int32)[:, 0, 3] = tris.astype(np.int32)
    return rows, m, tris.astype(np.int32)


def build_bvh4(vertices: np.ndarray, faces: np.ndarray, params: Bvh4BuildParams = Bvh4BuildParams(),
               cache_dir=None) -> Bvh4:
    """The 4-wide BVH of a mesh (module docstring), from the binary trees in the disk cache."""
    t0 = time.perf_counter()
    vertices = np.ascontiguousarray(vertices, np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, np.int64).reshape(-1, 3)
    name, binary, wide, cost = collapse_best(vertices, faces, params.binary, WIDTH, params.leaf_max,
                                             params.cost_node, params.cost_prim, cache_dir)
    used = wide[-2]
    if len(used) and np.abs(vertices[faces[used]]).max() > MAX_COORD:
        raise SceneError("BVH4: coordinates beyond 1e18, where its fused box test could overflow: use the bvh "
                         "traversal")
    rows, n_nodes, tri_ids = _pack(vertices, faces, wide)
    return Bvh4(rows, n_nodes, tri_ids, binary.bounds.astype(np.float32), int(wide[-1]), float(cost), name, params,
                time.perf_counter() - t0)


def load_or_build_bvh4(vertices: np.ndarray, faces: np.ndarray, params: Bvh4BuildParams = Bvh4BuildParams(),
                       cache_dir: str | os.PathLike | None = None) -> tuple[Bvh4, bool]:
    """The mesh's BVH4 from the on-disk cache, else built and stored. Returns (bvh4, from_cache)."""
    return Bvh4.cached(vertices, faces, params, lambda: build_bvh4(vertices, faces, params, cache_dir), "BVH4",
                        cache_dir)
