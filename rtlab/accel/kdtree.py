"""SAH kd-tree in the paper's layout (Fig. 2): node list -> object list -> triangle lists.

Node encoding (``nodes``: (N, 2) int32, 8 bytes a node; mirrored by kernels/shared/rt_kdtree.h):
  interior: nodes[i, 0] = (left_child << 2) | axis   (axis 0, 1, 2; right child = left_child + 1)
            nodes[i, 1] = split position, float32 bits (nodes.view(np.float32)[i, 1])
  leaf:     nodes[i, 0] = (n_triangles << 2) | 3
            nodes[i, 1] = offset of its first entry in ``objects``
The root is node 0. Children of one node are stored side by side; the builder stores the tree
level by level (breadth first), so children always come after their parent.
A triangle overlapping (or lying in) a split plane is referenced by both sides, so the traversal
only needs inclusive [tmin, tmax] cell ranges to find every hit; the one exception, flat cells
(below), keeps a triangle lying in the plane in the zero-thickness side, which those ranges
still visit wherever a ray crosses the plane inside the cell.

How the builder works (``build_kdtree``)
----------------------------------------
Breadth first, one level of the tree at a time (as in Zhou et al. 2008 and Shevtsov et al. 2007):
every node of a level is planned and split in parallel (runs of nodes of about equal work on a
pool of threads, the jitted kernels releasing the GIL), so both cores stay busy from the second
level down. The kernels avoid what numba is slow to compile (parallel functions, ndarray.sort,
array broadcasting): a fresh install compiles the builder once in a few seconds, then loads it
from numba's cache (``cache=True``: ``__pycache__`` beside this file, or numba's per-user cache
directory when that is read-only).

* Split choice: Havran's surface area heuristic (Havran 2000, ch. 4; Wald & Havran 2006),
      cost(p) = lambda(p) * (C_trav + C_isect * (SA_L/SA * N_L + SA_R/SA * N_R)),
  lambda = 1 - empty_bonus when one side holds no triangle, else 1 (Wald & Havran's lambda is
  0.8, i.e. empty_bonus 0.2; pbrt's emptyBonus 0.5 scales only the C_isect term).
  Nodes with more than ``exact_below`` references are binned first (``bins`` bins on each of the 3
  axes, min-max binning after Wald 2007 / Shevtsov 2007); then the events within one bin either
  side of each axis' best bin boundary are swept exactly, so planes still land on clipped triangle
  bounds. Smaller nodes sweep all their events exactly (Wald & Havran 2006, section 4.2).
  Measured on DRAGON and BUNNY: the SAH cost of an exact sweep at every node (within 0.1 %) in
  ~60 % of its build time, where plain binning down to 32 references costs 3-4 % more, with up
  to 70 % more nodes (DRAGON).
  Candidates lie strictly inside the node box, except flat cells:
* Flat cells (Wald & Havran 2006, section 4.3): triangles lying in a face of the node (the
  ground under a scene, a wall, a table top) are cut off by a split on that face into a
  zero-thickness child; the other child keeps the node's box without them. Priced like any split
  (the flat side's area is the face's, the rest keeps N - N_face at the full area) and favoured
  by the empty bonus when nothing else is in the node, so the empty space above a ground plane is
  split off instead of every column cell above it keeping ground triangles: on the default scene
  (a 32K-triangle ground seen at a shallow angle) the SAH cost fell from 161 to 29 and PoCL
  traced 10x faster; SPONZA 96 -> 90, KITCHEN 39 -> 31, BUNNY and DRAGON unchanged.
  A flat cell is never split along its flat axis again, so the empty bonus cannot cut
  zero-volume slabs forever.
* Default cost model C_trav 1, C_isect 1.25, empty_bonus 0.1, chosen by measurement on the paper's
  four scenes: non-empty leaves and references per leaf close to the paper's Table 2, and an SAH
  cost within ~1 % of the lowest (yardstick C_isect/C_trav = 1.5) among the settings tried
  (C_isect 1 to 1.5, empty_bonus 0 to 0.2). empty_bonus 0 costs 5-10 % more; Wald & Havran's
  0.2 with C_isect 1.5 gives 8-25 % more nodes for the same cost.
* Leaf when N <= max_leaf_size, at the depth limit (pbrt's 8 + 1.3 log2 N), or when no split
  is cheaper than C_isect * N.
* "Perfect splits" (Havran 2000, Wald & Havran 2006 section 4.3): a triangle that straddles the
  split plane is clipped to each child box (Sutherland-Hodgman, float64) and keeps the box of the
  clipped polygon, rounded outwards to float32. This removes most references a triangle would
  otherwise get in cells its bounding box overlaps but the triangle does not.
* Classification of a reference with clipped extent [lo, hi] on the split axis at p:
  lo < p -> left, hi > p -> right (both when it straddles), and lo == hi == p (lying in the plane)
  -> both children, or only the flat child of a split on the node's face (``_sides`` in rtlab.accel.kdtree_kernels). A triangle that only touches the plane from one side stays on that side: it
  overlaps only that cell, and a ray hitting it on the plane visits that cell (inclusive ranges).
* Zero-area triangles (and any with a non-finite vertex) are never referenced: no ray can hit them.
"""
from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

from ..jit import numba
import numpy as np

from .kdtree_kernels import LEAF_TAG, box_area, link_level, plan_nodes, scatter_nodes, triangle_boxes
# Told to build_kdtree's progress when numba compiles the builder (a fresh install, once)
COMPILING_MESSAGE = "compiling the kd-tree builder (first run only: numba caches it)"

@dataclass(frozen=True)
class KdBuildParams:
    """Havran's SAH cost model. ``max_depth`` 0 means round(8 + 1.3 floor(log2 N)) (pbrt's rule)."""
    cost_traversal: float = 1.0
    cost_intersect: float = 1.25
    empty_bonus: float = 0.1          # cost times (1 - empty_bonus) when one side is empty
    max_leaf_size: int = 1            # a node with no more triangles than this is always a leaf
    max_depth: int = 0
    bins: int = 32                    # binned SAH for large nodes; 0: exact sweep everywhere
    exact_below: int = 32             # nodes with at most this many references sweep exactly
    flat_cells: bool = True           # cut triangles lying in a node's face off into flat cells

    def key(self) -> str:
        return (f"kd-ct{self.cost_traversal}-ci{self.cost_intersect}-eb{self.empty_bonus}"
                f"-ml{self.max_leaf_size}-md{self.max_depth}-b{self.bins}-x{self.exact_below}"
                f"-fc{int(self.flat_cells)}")

    def depth_limit(self, n_triangles: int) -> int:
        if self.max_depth > 0:
            return self.max_depth
        floor_log2 = max(int(n_triangles), 1).bit_length() - 1
        return int(round(8 + 1.3 * floor_log2))


@dataclass
class KdTree:
    nodes: np.ndarray          # (N, 2) int32, encoding above
    objects: np.ndarray        # (M,) int32 triangle indices, leaves' lists back to back
    bounds: np.ndarray         # (2, 3) float32 root box
    depth: int                 # deepest leaf's depth (root = 0): the traversal stack needs depth + 1
    params: KdBuildParams = field(default_factory=KdBuildParams)
    build_seconds: float = 0.0
    sah_cost: float = 0.0      # expected cost of the tree under the SAH model (root = 1 area unit)

    # --- decoding helpers (host side; the kernels decode the same bits) ---
    def is_leaf(self) -> np.ndarray:
        return (self.nodes[:, 0] & 3) == LEAF_TAG

    def split_axis(self) -> np.ndarray:
        return self.nodes[:, 0] & 3

    def split_pos(self) -> np.ndarray:
        return self.nodes[:, 1].view(np.float32)

    def child_or_count(self) -> np.ndarray:
        return self.nodes[:, 0] >> 2


# ---------------------------------------------------------------------------------------------
# host side
# ---------------------------------------------------------------------------------------------

def _threads() -> int:
    return max(1, int(numba.config.NUMBA_NUM_THREADS))


_pool: ThreadPoolExecutor | None = None


def _forget_pool() -> None:
    # A forked child inherits the pool object but not its threads: it would wait forever
    global _pool
    _pool = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def _on_threads(kernel, runs: np.ndarray, *args) -> None:
    """kernel(*args, runs, t, T) on T threads of a pool (the kernels release the GIL), thread t
    taking runs t, t + T, ... of the level's nodes (a static schedule, as prange's). Threads
    rather than numba's prange: a parallel function costs seconds more to compile on first use,
    and the runs are planned here anyway."""
    global _pool
    n_threads = min(_threads(), len(runs) - 1)
    if n_threads <= 1:
        kernel(*args, runs, 0, 1)
        return
    if _pool is None:
        _pool = ThreadPoolExecutor(_threads(), thread_name_prefix="rtlab-kd")
    for done in [_pool.submit(kernel, *args, runs, t, n_threads) for t in range(n_threads)]:
        done.result()


def _work_chunks(node_count: np.ndarray) -> np.ndarray:
    """Boundaries splitting a level's nodes into runs of about equal work (references plus a
    per-node overhead), a few per thread, so that no thread waits long for the last run."""
    n = len(node_count)
    n_chunks = min(n, 4 * _threads())
    work = np.cumsum(node_count + 16)
    cuts = np.searchsorted(work, np.linspace(0, work[-1], n_chunks + 1)[1:-1])
    return np.unique(np.concatenate([[0], cuts, [n]])).astype(np.int64)


def build_kdtree(vertices: np.ndarray, faces: np.ndarray, params: KdBuildParams = KdBuildParams(),
                 progress=None) -> KdTree:
    """Build Havran's SAH kd-tree over a triangle mesh (see the module docstring).

    vertices: (V, 3) float32; faces: (F, 3) int32 indices into vertices.
    progress: optional ``progress(message: str)`` (rtlab's convention), told after each level.
    """
    t0 = time.perf_counter()
    vertices = np.ascontiguousarray(vertices, np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, np.int32).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError("face indices out of range of the vertex array")
    tri_box, usable = triangle_boxes(vertices, faces)
    if progress is not None and triangle_boxes.stats.cache_misses:
        # Not in numba's cache: the rest of the builder is not either
        progress(COMPILING_MESSAGE)
    ref_tri = np.flatnonzero(usable).astype(np.int32)
    if len(ref_tri) == 0:
        nodes = np.array([[LEAF_TAG, 0]], np.int32)
        return KdTree(nodes, np.zeros(0, np.int32), np.zeros((2, 3), np.float32), 0, params,
                      time.perf_counter() - t0, 0.0)
    ref_box = np.ascontiguousarray(tri_box[ref_tri])
    bounds = np.stack([ref_box[:, :3].min(0), ref_box[:, 3:].max(0)]).astype(np.float32)
    nodes, objects, depth, cost = _build_levels(vertices, faces, ref_tri, ref_box, bounds, params,
                                                progress)
    root_area = box_area(bounds.reshape(6))
    sah_cost = cost / root_area if root_area > 0 else float("nan")
    return KdTree(nodes, objects, bounds, depth, params, time.perf_counter() - t0, sah_cost)


def _plan_level(ref_box, node_box, node_start, node_count, chunks, params: KdBuildParams,
                leaves_only: bool):
    """Splits of a level's nodes (axis -1: leaf) and their children's reference counts."""
    n = len(node_count)
    axis = np.full(n, -1, np.int32)
    pos = np.zeros(n, np.float32)
    n_left = np.zeros(n, np.int64)
    n_right = np.zeros(n, np.int64)
    if not leaves_only:
        _on_threads(plan_nodes, chunks, ref_box, ref_box.view(np.int32), node_box, node_start,
                        node_count, float(params.cost_traversal), float(params.cost_intersect),
                        float(params.empty_bonus), int(params.max_leaf_size), int(params.bins),
                        int(params.exact_below), bool(params.flat_cells), axis, pos, n_left, n_right)
    return axis, pos, n_left, n_right


def _build_levels(vertices, faces, ref_tri, ref_box, bounds, params: KdBuildParams, progress):
    """The level loop: returns nodes, objects, depth and the unnormalised SAH cost."""
    max_depth = params.depth_limit(len(ref_tri))
    ct, ci = float(params.cost_traversal), float(params.cost_intersect)
    node_box = bounds.reshape(1, 6).copy()
    node_start = np.zeros(1, np.int64)
    node_count = np.array([len(ref_tri)], np.int64)
    node_levels, object_levels = [], []
    n_nodes_before = n_objects_before = 0
    cost = 0.0
    depth = 0
    while True:
        chunks = _work_chunks(node_count)
        axis, pos, n_left, n_right = _plan_level(ref_box, node_box, node_start, node_count, chunks,
                                                 params, depth >= max_depth)
        (words, dst_left, dst_right, leaf_dst, next_box, next_start, next_count, n_refs_next,
         n_objects, level_cost) = link_level(node_box, node_count, axis, pos, n_left, n_right,
                                              n_nodes_before, n_objects_before, ct, ci)
        out_tri = np.empty(n_refs_next, np.int32)
        out_box = np.empty((n_refs_next, 6), np.float32)
        objects = np.empty(n_objects, np.int32)
        _on_threads(scatter_nodes, chunks, vertices, faces, ref_tri, ref_box, node_box, node_start,
                        node_count, axis, pos, dst_left, dst_right, leaf_dst, out_tri, out_box, objects)
        node_levels.append(words)
        object_levels.append(objects)
        cost += level_cost
        n_nodes_before += len(node_count)
        n_objects_before += n_objects
        if progress is not None:
            progress(f"kd-tree level {depth} of at most {max_depth}: {len(node_count):,} nodes")
        if len(next_count) == 0:
            break
        node_box, node_start, node_count = next_box, next_start, next_count
        ref_tri, ref_box = out_tri, out_box
        depth += 1
    return np.concatenate(node_levels), np.concatenate(object_levels), depth, cost


def kd_stats(tree: KdTree, n_triangles: int) -> dict:
    """The paper's Table 2 columns (and a few more) for a built tree.

    size_bytes counts nodes (8 B), object list entries (4 B), and per triangle 3 float4 vertices
    plus 3 float4 vertex normals (96 B): the layout of Fig. 2, which gives the paper's 11 MB BUNNY.
    """
    leaf = tree.is_leaf()
    counts = tree.child_or_count()[leaf]
    nonempty = int((counts > 0).sum())
    n_nodes = len(tree.nodes)
    return {
        "triangles": int(n_triangles),
        "nodes": n_nodes,
        "nonempty_leaves": nonempty,
        "refs_per_nonempty_leaf": float(counts.sum() / nonempty) if nonempty else 0.0,
        "size_bytes": int(n_nodes * 8 + len(tree.objects) * 4 + n_triangles * 48 + n_triangles * 48),
        "depth": int(tree.depth),
        "leaves": int(leaf.sum()),
        "empty_leaves": int(leaf.sum()) - nonempty,
        "sah_cost": float(tree.sah_cost),
        "build_seconds": float(tree.build_seconds),
    }
