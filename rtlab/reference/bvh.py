"""The float64 reference's BVH: midpoint splits of the triangle centroids' longest extent, float64
boxes grown a little in space, built with numba, kept in memory for a few meshes keyed by their
content. Deliberately not the kernels' builders (binned SAH, spatial splits: rtlab.accel): the
reference shares no code with what it checks, and its tree only has to be correct, not optimal."""
from __future__ import annotations

import hashlib
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ..jit import njit
from .watertight import mesh_f64, usable_triangle_mask

_BOX_SPATIAL_PAD_REL = 1e-9
_BVH_MAX_LEAF = 4          # triangles a leaf holds at most


@dataclass
class ReferenceBVH:
    """A float64 BVH over the usable triangles of one mesh.

    Node i: box node_lo[i]..node_hi[i] (already padded); an inner node has its children at
    node_child[i] and node_child[i] + 1; a leaf (node_count[i] > 0) holds rows
    node_first[i] .. node_first[i] + node_count[i] of tri_verts (v0, v1, v2 as 9 float64 per row),
    whose original ids are tri_ids.
    """
    node_lo: np.ndarray
    node_hi: np.ndarray
    node_child: np.ndarray
    node_first: np.ndarray
    node_count: np.ndarray
    tri_verts: np.ndarray
    tri_ids: np.ndarray
    depth: int
    scene_max_abs: float
    build_seconds: float
    n_triangles: int          # all triangles of the mesh, usable or not

    @property
    def n_nodes(self) -> int:
        return int(self.node_lo.shape[0])


@njit(cache=True)
def _centroid_bounds(order, start, end, centroid):
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for k in range(start, end):
        c = centroid[order[k]]
        for a in range(3):
            lo[a] = min(lo[a], c[a])
            hi[a] = max(hi[a], c[a])
    return lo, hi


@njit(cache=True)
def _partition_at_midpoint(order, start, end, centroid, axis, mid_value):
    """Reorder order[start:end] so that centroids below mid_value come first; returns the first of the rest."""
    i, j = start, end - 1
    while i <= j:
        if centroid[order[i], axis] < mid_value:
            i += 1
        else:
            order[i], order[j] = order[j], order[i]
            j -= 1
    return i


@njit(cache=True)
def _build_bvh_arrays(tri_lo, tri_hi, centroid, max_leaf):
    """Top-down midpoint splits with an explicit stack: each node's triangles go to the side of the
    middle of their centroids' longest extent (Kay & Kajiya 1986's simplest rule; no cost model, so
    nothing in common with the SAH builders the kernels use). Coincident centroids split at the
    middle of the range, so the build always ends."""
    m = tri_lo.shape[0]
    order = np.arange(m)
    cap = max(2 * m - 1, 1)
    node_lo = np.empty((cap, 3))
    node_hi = np.empty((cap, 3))
    node_child = np.full(cap, -1, np.int64)
    node_first = np.zeros(cap, np.int64)
    node_count = np.zeros(cap, np.int64)
    stack_node = np.empty(m + 1, np.int64)
    stack_start = np.empty(m + 1, np.int64)
    stack_end = np.empty(m + 1, np.int64)
    stack_depth = np.empty(m + 1, np.int64)
    n_nodes, sp, max_depth = 1, 1, 1
    stack_node[0], stack_start[0], stack_end[0], stack_depth[0] = 0, 0, m, 1
    while sp > 0:
        sp -= 1
        node, start, end, depth = stack_node[sp], stack_start[sp], stack_end[sp], stack_depth[sp]
        max_depth = max(max_depth, depth)
        for a in range(3):
            node_lo[node, a] = np.inf
            node_hi[node, a] = -np.inf
        for k in range(start, end):
            for a in range(3):
                node_lo[node, a] = min(node_lo[node, a], tri_lo[order[k], a])
                node_hi[node, a] = max(node_hi[node, a], tri_hi[order[k], a])
        node_first[node] = start
        if end - start <= max_leaf:
            node_count[node] = end - start
            continue
        clo, chi = _centroid_bounds(order, start, end, centroid)
        axis = 0
        for a in range(1, 3):
            if chi[a] - clo[a] > chi[axis] - clo[axis]:
                axis = a
        mid = -1
        if chi[axis] > clo[axis]:
            mid = _partition_at_midpoint(order, start, end, centroid, axis, 0.5 * (clo[axis] + chi[axis]))
        if mid <= start or mid >= end:
            mid = (start + end) // 2
        child = n_nodes
        n_nodes += 2
        node_child[node] = child
        stack_node[sp], stack_start[sp], stack_end[sp], stack_depth[sp] = child, start, mid, depth + 1
        sp += 1
        stack_node[sp], stack_start[sp], stack_end[sp], stack_depth[sp] = child + 1, mid, end, depth + 1
        sp += 1
    return (order, node_lo[:n_nodes], node_hi[:n_nodes], node_child[:n_nodes],
            node_first[:n_nodes], node_count[:n_nodes], max_depth)


def build_reference_bvh(vertices, faces) -> ReferenceBVH:
    """Build the float64 BVH over the usable triangles of (vertices, faces). Uncached; see
    :func:`reference_trace` for the in-memory cache."""
    t0 = time.perf_counter()
    v64, f = mesh_f64(vertices, faces)
    v0, v1, v2 = v64[f[:, 0]], v64[f[:, 1]], v64[f[:, 2]]
    ids = np.flatnonzero(usable_triangle_mask(v0, v1, v2))
    corners = np.stack([v0[ids], v1[ids], v2[ids]], axis=1)          # (M, 3, 3)
    tri_lo = np.ascontiguousarray(corners.min(axis=1))
    tri_hi = np.ascontiguousarray(corners.max(axis=1))
    centroid = np.ascontiguousarray(0.5 * (tri_lo + tri_hi))
    if ids.size == 0:
        # an empty root box that no ray can enter
        node_lo = np.full((1, 3), np.inf)
        node_hi = np.full((1, 3), -np.inf)
        return ReferenceBVH(node_lo, node_hi, np.full(1, -1, np.int64), np.zeros(1, np.int64),
                            np.zeros(1, np.int64), np.zeros((0, 9)), np.zeros(0, np.int64), 1,
                            0.0, time.perf_counter() - t0, int(f.shape[0]))
    order, node_lo, node_hi, node_child, node_first, node_count, depth = _build_bvh_arrays(
        tri_lo, tri_hi, centroid, _BVH_MAX_LEAF)
    scene_max_abs = float(np.abs(corners).max())
    # Grow every box a little in space: exact boxes hold their triangles exactly, but a float64
    # triangle test may still accept a ray passing ~1e-16 outside an edge that lies on the box face.
    pad = _BOX_SPATIAL_PAD_REL * scene_max_abs + 1e-300
    node_lo = node_lo - pad
    node_hi = node_hi + pad
    tri_verts = np.ascontiguousarray(corners[order].reshape(-1, 9))
    return ReferenceBVH(node_lo, node_hi, node_child, node_first, node_count, tri_verts,
                        ids[order].astype(np.int64), int(depth), scene_max_abs,
                        time.perf_counter() - t0, int(f.shape[0]))


# In-memory cache: content hash of the float32 mesh -> BVH. Keyed by content rather than id() so a
# reloaded or copied mesh reuses its tree and a mutated array never gets a stale one.
_BVH_CACHE: OrderedDict[bytes, ReferenceBVH] = OrderedDict()
_BVH_CACHE_SIZE = 4
_BVH_CACHE_LOCK = threading.Lock()


def _mesh_key(vertices, faces) -> bytes:
    """Content digest of the mesh as traced (float32 corners, int32 indices); not for security,
    sha1 because it is the fastest hashlib digest here (~60 ms for the dragon)."""
    v32 = np.ascontiguousarray(vertices, dtype=np.float32)
    f32 = np.ascontiguousarray(faces, dtype=np.int32)
    h = hashlib.sha1(usedforsecurity=False)
    h.update(np.asarray(v32.shape + f32.shape, np.int64).tobytes())
    h.update(v32.reshape(-1).view(np.uint8))  # buffer protocol: no copy
    h.update(f32.reshape(-1).view(np.uint8))
    return h.digest()


def cached_reference_bvh(vertices, faces) -> ReferenceBVH:
    """:func:`build_reference_bvh`, memoised on mesh content (a few meshes kept)."""
    key = _mesh_key(vertices, faces)
    with _BVH_CACHE_LOCK:
        bvh = _BVH_CACHE.get(key)
        if bvh is not None:
            _BVH_CACHE.move_to_end(key)
            return bvh
    bvh = build_reference_bvh(vertices, faces)
    with _BVH_CACHE_LOCK:
        _BVH_CACHE[key] = bvh
        while len(_BVH_CACHE) > _BVH_CACHE_SIZE:
            _BVH_CACHE.popitem(last=False)
    return bvh
