"""The float64 reference's BVH: binned SAH over triangle centroids (Wald 2007, "On fast construction
of SAH-based bounding volume hierarchies"), float64 boxes grown a little in space, built with numba,
and kept in memory for a few meshes, keyed by their content."""
from __future__ import annotations

import hashlib
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from numba import njit

from .watertight import mesh_f64, usable_triangle_mask

_BOX_SPATIAL_PAD_REL = 1e-9
_BVH_MAX_LEAF = 4          # SAH may stop at up to this many triangles per leaf
_BVH_BINS = 16             # binned SAH (Wald 2007, "On fast construction of SAH-based BVHs")
_BVH_TRAVERSAL_COST = 1.0  # relative to one triangle test


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
def _node_bounds(order, start, end, tri_lo, tri_hi, centroid):
    box = np.empty(6)
    cbox = np.empty(6)
    for a in range(3):
        box[a] = np.inf
        box[3 + a] = -np.inf
        cbox[a] = np.inf
        cbox[3 + a] = -np.inf
    for i in range(start, end):
        p = order[i]
        for a in range(3):
            box[a] = min(box[a], tri_lo[p, a])
            box[3 + a] = max(box[3 + a], tri_hi[p, a])
            cbox[a] = min(cbox[a], centroid[p, a])
            cbox[3 + a] = max(cbox[3 + a], centroid[p, a])
    return box, cbox


@njit(cache=True, inline="always")
def _half_area(lo0, lo1, lo2, hi0, hi1, hi2):
    e0, e1, e2 = hi0 - lo0, hi1 - lo1, hi2 - lo2
    return e0 * e1 + e1 * e2 + e2 * e0


@njit(cache=True, inline="always")
def _bin_of(c, cmin, bin_scale, n_bins):
    k = int((c - cmin) * bin_scale)
    return min(max(k, 0), n_bins - 1)


@njit(cache=True)
def _best_sah_split(order, start, end, tri_lo, tri_hi, centroid, cbox, n_bins):
    """Binned SAH: (cost, axis, split_bin) with the left side = bins < split_bin; axis -1 if no
    axis has any centroid extent."""
    best_cost = np.inf
    best_axis = -1
    best_split = -1
    counts = np.zeros(n_bins, np.int64)
    blo = np.empty((n_bins, 3))
    bhi = np.empty((n_bins, 3))
    right_area = np.empty(n_bins)
    right_count = np.empty(n_bins, np.int64)
    for axis in range(3):
        cmin = cbox[axis]
        extent = cbox[3 + axis] - cmin
        if not extent > 0.0:
            continue
        bin_scale = n_bins / extent
        counts[:] = 0
        blo[:, :] = np.inf
        bhi[:, :] = -np.inf
        for i in range(start, end):
            p = order[i]
            k = _bin_of(centroid[p, axis], cmin, bin_scale, n_bins)
            counts[k] += 1
            for a in range(3):
                blo[k, a] = min(blo[k, a], tri_lo[p, a])
                bhi[k, a] = max(bhi[k, a], tri_hi[p, a])
        # sweep from the right: area and count of bins >= s
        lo0 = lo1 = lo2 = np.inf
        hi0 = hi1 = hi2 = -np.inf
        n = 0
        for s in range(n_bins - 1, 0, -1):
            if counts[s] > 0:
                lo0, lo1, lo2 = min(lo0, blo[s, 0]), min(lo1, blo[s, 1]), min(lo2, blo[s, 2])
                hi0, hi1, hi2 = max(hi0, bhi[s, 0]), max(hi1, bhi[s, 1]), max(hi2, bhi[s, 2])
                n += counts[s]
            right_count[s] = n
            right_area[s] = _half_area(lo0, lo1, lo2, hi0, hi1, hi2) if n > 0 else 0.0
        lo0 = lo1 = lo2 = np.inf
        hi0 = hi1 = hi2 = -np.inf
        n = 0
        for s in range(1, n_bins):
            k = s - 1
            if counts[k] > 0:
                lo0, lo1, lo2 = min(lo0, blo[k, 0]), min(lo1, blo[k, 1]), min(lo2, blo[k, 2])
                hi0, hi1, hi2 = max(hi0, bhi[k, 0]), max(hi1, bhi[k, 1]), max(hi2, bhi[k, 2])
                n += counts[k]
            if n == 0 or right_count[s] == 0:
                continue
            cost = _half_area(lo0, lo1, lo2, hi0, hi1, hi2) * n + right_area[s] * right_count[s]
            if cost < best_cost:
                best_cost = cost
                best_axis = axis
                best_split = s
    return best_cost, best_axis, best_split


@njit(cache=True)
def _partition_by_bin(order, start, end, centroid, axis, cmin, bin_scale, n_bins, split):
    """In-place partition of order[start:end]: bins < split first. Returns the first right index."""
    i = start
    j = end - 1
    while i <= j:
        if _bin_of(centroid[order[i], axis], cmin, bin_scale, n_bins) < split:
            i += 1
        else:
            order[i], order[j] = order[j], order[i]
            j -= 1
    return i


@njit(cache=True)
def _build_bvh_arrays(tri_lo, tri_hi, centroid, max_leaf, n_bins, traversal_cost):
    """Top-down binned-SAH build with an explicit stack. Where SAH cannot separate the centroids
    (all in one bin, or identical) the range is split at its middle, so the build always ends."""
    m = tri_lo.shape[0]
    order = np.arange(m)
    cap = max(2 * m - 1, 1)
    node_lo = np.empty((cap, 3))
    node_hi = np.empty((cap, 3))
    node_child = np.full(cap, -1, np.int64)
    node_first = np.zeros(cap, np.int64)
    node_count = np.zeros(cap, np.int64)
    task_node = np.empty(m + 1, np.int64)
    task_start = np.empty(m + 1, np.int64)
    task_end = np.empty(m + 1, np.int64)
    task_depth = np.empty(m + 1, np.int64)
    n_nodes = 1
    sp = 1
    task_node[0], task_start[0], task_end[0], task_depth[0] = 0, 0, m, 1
    max_depth = 1
    while sp > 0:
        sp -= 1
        node, start, end, depth = task_node[sp], task_start[sp], task_end[sp], task_depth[sp]
        max_depth = max(max_depth, depth)
        box, cbox = _node_bounds(order, start, end, tri_lo, tri_hi, centroid)
        for a in range(3):
            node_lo[node, a] = box[a]
            node_hi[node, a] = box[3 + a]
        count = end - start
        node_first[node] = start
        if count <= 1:
            node_count[node] = count
            continue
        cost, axis, split = _best_sah_split(order, start, end, tri_lo, tri_hi, centroid, cbox,
                                            n_bins)
        leaf_cost = count * _half_area(box[0], box[1], box[2], box[3], box[4], box[5])
        split_cost = traversal_cost * _half_area(box[0], box[1], box[2], box[3], box[4], box[5]) \
            + cost
        mid = -1
        if axis >= 0:
            if count <= max_leaf and leaf_cost <= split_cost:
                node_count[node] = count
                continue
            cmin = cbox[axis]
            mid = _partition_by_bin(order, start, end, centroid, axis, cmin,
                                    n_bins / (cbox[3 + axis] - cmin), n_bins, split)
        if mid <= start or mid >= end:
            if count <= max_leaf:
                node_count[node] = count
                continue
            mid = (start + end) // 2  # coincident centroids: any split is as good as another
        child = n_nodes
        n_nodes += 2
        node_child[node] = child
        task_node[sp], task_start[sp], task_end[sp], task_depth[sp] = child, start, mid, depth + 1
        sp += 1
        task_node[sp], task_start[sp], task_end[sp], task_depth[sp] = child + 1, mid, end, depth + 1
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
    centroid = np.ascontiguousarray(0.5 * (tri_lo + tri_hi))  # box centres bin better than means
    if ids.size == 0:
        # an empty root box that no ray can enter
        node_lo = np.full((1, 3), np.inf)
        node_hi = np.full((1, 3), -np.inf)
        return ReferenceBVH(node_lo, node_hi, np.full(1, -1, np.int64), np.zeros(1, np.int64),
                            np.zeros(1, np.int64), np.zeros((0, 9)), np.zeros(0, np.int64), 1,
                            0.0, time.perf_counter() - t0, int(f.shape[0]))
    order, node_lo, node_hi, node_child, node_first, node_count, depth = _build_bvh_arrays(
        tri_lo, tri_hi, centroid, _BVH_MAX_LEAF, _BVH_BINS, _BVH_TRAVERSAL_COST)
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
