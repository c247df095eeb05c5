"""Binned-SAH BVH for the GPU traversal of kernels/shared/rt_bvh.h (the paper's future work: kd-tree
against BVH), in Aila & Laine's 2009 layout.

Build (Wald 2007, "On fast construction of SAH-based bounding volume hierarchies"): top down over
triangle centroids, ``bins`` bins per axis, cost C_trav + C_isect (A_L N_L + A_R N_R) / A; a range
becomes a leaf when that is cheaper and it holds at most ``max_leaf_size`` triangles. A range whose
centroids all coincide (no bin split possible) is cut in the middle of its list, so leaves never
exceed the 15 triangles the device encoding holds. Subtrees are laid out depth first, the first
child next to its parent. Triangles that cannot be hit (a non-finite corner, zero area) are left
out, as the kd-tree builder does. With params.spatial_alpha > 0 nodes may also split in space and
reference a triangle from several leaves (SBVH: rtlab.accel.bvh_splits); off by default.

Device layout (sync with rt_bvh.h), node_data float4, 4 per node = 64 B:
  [4 i + 0] = (c0.lo.x, c0.hi.x, c0.lo.y, c0.hi.y)
  [4 i + 1] = (c1.lo.x, c1.hi.x, c1.lo.y, c1.hi.y)
  [4 i + 2] = (c0.lo.z, c0.hi.z, c1.lo.z, c1.hi.z)
  [4 i + 3] = (ref c0, ref c1, 0, 0) as int32 bits
ref >= 0: inner node index; a leaf is ~((first << BVH_LEAF_BITS) | count) over ``objects[first:first + count]``.
The root (node 0) is always inner: a one-leaf tree gets a second, identical leaf.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit, prange

from .. import paths
from ..errors import RtlabError, SceneError
from ..kernel_constants import kernel_constant
from .bvh_splits import best_spatial_split, spatial_partition
from .cache import atomic_savez, cache_key, load_or_build

FORMAT_VERSION = "bvh2-v2"   # bump when the builder's output for the same inputs changes
LEAF_BITS = int(kernel_constant("BVH_LEAF_BITS"))
MAX_LEAF = (1 << LEAF_BITS) - 1
NODE_FLOAT4S = int(kernel_constant("BVH_NODE_STRIDE"))


@dataclass(frozen=True)
class BvhBuildParams:
    bins: int = 16
    max_leaf_size: int = 8            # SAH may stop at up to this many triangles (<= 15)
    cost_traversal: float = 1.0       # one node (two box tests), relative to one triangle test
    cost_intersect: float = 1.0
    # SBVH (rtlab.accel.bvh_splits): try spatial splits where the best object split's children
    # overlap by more than spatial_alpha x the root's area (1e-5 in the paper); 0: off
    spatial_alpha: float = 0.0
    spatial_growth: float = 1.0       # references at most (1 + this) x the usable triangles

    def __post_init__(self):
        if not 1 <= self.max_leaf_size <= MAX_LEAF:
            raise RtlabError(f"BVH max_leaf_size must be 1..{MAX_LEAF} (4 bits in a leaf ref), got {self.max_leaf_size}")
        if self.bins < 2:
            raise RtlabError(f"BVH bins must be at least 2, got {self.bins}")
        if not (self.spatial_alpha >= 0.0 and self.spatial_growth >= 0.0):
            raise RtlabError(f"BVH spatial_alpha and spatial_growth must be >= 0, got {self.spatial_alpha}, "
                             f"{self.spatial_growth}")

    @property
    def spatial(self) -> bool:
        return self.spatial_alpha > 0.0 and self.spatial_growth > 0.0

    def key(self) -> str:
        spatial = f"-sa{self.spatial_alpha}-sg{self.spatial_growth}" if self.spatial else ""
        return (f"{FORMAT_VERSION}-b{self.bins}-ml{self.max_leaf_size}-ct{self.cost_traversal}"
                f"-ci{self.cost_intersect}{spatial}")


@dataclass
class Bvh:
    child_lo: np.ndarray     # (M, 2, 3) float32 child boxes
    child_hi: np.ndarray
    child_ref: np.ndarray    # (M, 2) int32 refs (encoding above)
    objects: np.ndarray      # (K,) int32 triangle ids, leaves' ranges back to back (with spatial
                             # splits a triangle may be in several leaves, never twice in one)
    bounds: np.ndarray       # (2, 3) float32 root box
    depth: int               # most inner nodes on a root-to-leaf path: the stack needs depth + 1
    params: BvhBuildParams
    build_seconds: float = 0.0

    @property
    def n_nodes(self) -> int:
        return int(self.child_ref.shape[0])

    def node_data(self) -> np.ndarray:
        """(4 M, 4) float32 in the device layout."""
        m = self.n_nodes
        out = np.zeros((m, NODE_FLOAT4S, 4), np.float32)
        lo, hi = self.child_lo, self.child_hi
        for c in range(2):
            out[:, c, 0], out[:, c, 1] = lo[:, c, 0], hi[:, c, 0]
            out[:, c, 2], out[:, c, 3] = lo[:, c, 1], hi[:, c, 1]
            out[:, 2, 2 * c], out[:, 2, 2 * c + 1] = lo[:, c, 2], hi[:, c, 2]
        out.view(np.int32)[:, 3, :2] = self.child_ref
        return out.reshape(-1, 4)


def decode_leaf(ref: int) -> tuple[int, int]:
    """(first, count) of a leaf ref."""
    bits = ~int(ref)
    return bits >> LEAF_BITS, bits & MAX_LEAF


@njit(parallel=True, cache=True)
def _usable_boxes(vertices, faces):
    """Triangle boxes (float32) and whether a triangle can be hit: finite corners and non-zero
    area in float64 (the kd-tree builder's rule)."""
    n = faces.shape[0]
    lo = np.empty((n, 3), np.float32)
    hi = np.empty((n, 3), np.float32)
    usable = np.zeros(n, np.bool_)
    for i in prange(n):
        finite = True
        for a in range(3):
            x0, x1, x2 = vertices[faces[i, 0], a], vertices[faces[i, 1], a], vertices[faces[i, 2], a]
            finite &= np.isfinite(x0) and np.isfinite(x1) and np.isfinite(x2)
            lo[i, a] = min(x0, x1, x2)
            hi[i, a] = max(x0, x1, x2)
        p0, p1, p2 = vertices[faces[i, 0]], vertices[faces[i, 1]], vertices[faces[i, 2]]
        ux, uy, uz = np.float64(p1[0]) - p0[0], np.float64(p1[1]) - p0[1], np.float64(p1[2]) - p0[2]
        vx, vy, vz = np.float64(p2[0]) - p0[0], np.float64(p2[1]) - p0[1], np.float64(p2[2]) - p0[2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        usable[i] = finite and nx * nx + ny * ny + nz * nz > 0.0
    return lo, hi, usable


@njit(cache=True)
def _range_box(order, start, end, tri_lo, tri_hi, centroid, box):
    """box[0:3], box[3:6]: bounds of the triangles; box[6:9], box[9:12]: of their centroids."""
    box[0:3] = np.inf
    box[3:6] = -np.inf
    box[6:9] = np.inf
    box[9:12] = -np.inf
    for j in range(start, end):
        t = order[j]
        for a in range(3):
            box[a] = min(box[a], tri_lo[t, a])
            box[3 + a] = max(box[3 + a], tri_hi[t, a])
            box[6 + a] = min(box[6 + a], centroid[t, a])
            box[9 + a] = max(box[9 + a], centroid[t, a])


@njit(cache=True, inline="always")
def _half_area(dx, dy, dz):
    return dx * dy + dy * dz + dz * dx


@njit(cache=True, inline="always")
def _bin_of(c, lo, scale, n_bins):
    return min(int((c - lo) * scale), n_bins - 1)


@njit(cache=True)
def _best_split(order, start, end, tri_lo, tri_hi, centroid, box, n_bins, bins, bin_n, right_cost, right_box):
    """Binned SAH over the three axes: (axis, bin k: centroids in bins < k go left, cost in
    half-area x triangles, half-area of the two children's overlap); axis -1 when no plane
    separates the centroids. bins[b] holds the bounds of bin b (lo xyz, hi xyz)."""
    best_axis, best_k, best_cost, overlap = -1, 0, np.inf, np.inf
    for a in range(3):
        extent = box[9 + a] - box[6 + a]
        if not extent > 0.0:
            continue
        scale = n_bins / extent
        bins[:, 0:3] = np.inf
        bins[:, 3:6] = -np.inf
        bin_n[:] = 0
        for j in range(start, end):
            t = order[j]
            b = _bin_of(centroid[t, a], box[6 + a], scale, n_bins)
            bin_n[b] += 1
            for m in range(3):
                bins[b, m] = min(bins[b, m], tri_lo[t, m])
                bins[b, 3 + m] = max(bins[b, 3 + m], tri_hi[t, m])
        # Sweep from the right: half area times count of bins >= k, then from the left
        x0 = y0 = z0 = np.inf
        x1 = y1 = z1 = -np.inf
        count = 0
        for k in range(n_bins - 1, 0, -1):
            count += bin_n[k]
            x0, y0, z0 = min(x0, bins[k, 0]), min(y0, bins[k, 1]), min(z0, bins[k, 2])
            x1, y1, z1 = max(x1, bins[k, 3]), max(y1, bins[k, 4]), max(z1, bins[k, 5])
            right_cost[k] = _half_area(x1 - x0, y1 - y0, z1 - z0) * count if count > 0 else 0.0
            right_box[k, 0], right_box[k, 1], right_box[k, 2] = x0, y0, z0
            right_box[k, 3], right_box[k, 4], right_box[k, 5] = x1, y1, z1
        x0 = y0 = z0 = np.inf
        x1 = y1 = z1 = -np.inf
        count = 0
        for k in range(1, n_bins):
            count += bin_n[k - 1]
            x0, y0, z0 = min(x0, bins[k - 1, 0]), min(y0, bins[k - 1, 1]), min(z0, bins[k - 1, 2])
            x1, y1, z1 = max(x1, bins[k - 1, 3]), max(y1, bins[k - 1, 4]), max(z1, bins[k - 1, 5])
            if count == 0 or count == end - start:
                continue
            cost = _half_area(x1 - x0, y1 - y0, z1 - z0) * count + right_cost[k]
            if cost < best_cost:
                best_axis, best_k, best_cost = a, k, cost
                r = right_box[k]
                dx, dy, dz = min(x1, r[3]) - max(x0, r[0]), min(y1, r[4]) - max(y0, r[1]), min(z1, r[5]) - max(z0, r[2])
                overlap = _half_area(dx, dy, dz) if dx >= 0.0 and dy >= 0.0 and dz >= 0.0 else 0.0
    return best_axis, best_k, best_cost, overlap


@njit(cache=True)
def _partition(order, start, end, centroid, axis, k, box, n_bins):
    """Move centroids in bins < k to the front (the same binning as _best_split); returns the
    first index of the right part."""
    lo = box[6 + axis]
    scale = n_bins / (box[9 + axis] - lo)
    i, j = start, end - 1
    while i <= j:
        t = order[i]
        if _bin_of(centroid[t, axis], lo, scale, n_bins) < k:
            i += 1
        else:
            order[i], order[j] = order[j], order[i]
            j -= 1
    return i


@njit(cache=True)
def _shift_right(order, mid, end, by):
    """Move order[mid:end] up by ``by`` slots (the left child's share of the free slots)."""
    for j in range(end - 1, mid - 1, -1):
        order[j + by] = order[j]


@njit(cache=True)
def _build(order, n, ref_lo, ref_hi, centroid, ref_tri, n_ids, vertices, faces, n_bins, max_leaf, ct, ci,
           alpha_area):
    """The tree over references order[:n] (ids into ref_lo, ref_hi, centroid, ref_tri); the rest
    of ``order`` is the pool that spatial splits (alpha_area >= 0) may fill, n_ids the first free
    reference id. Returns child_lo, child_hi, child_ref, depth, objects (triangle ids)."""
    pool = order.shape[0]
    spatial = alpha_area >= 0.0 and pool > n
    cap = max(1, 2 * pool)
    child_lo = np.zeros((cap, 2, 3), np.float32)
    child_hi = np.zeros((cap, 2, 3), np.float32)
    child_ref = np.full((cap, 2), -1, np.int32)            # ~0: an empty leaf
    objects = np.empty(pool, np.int32)
    n_objects = 0
    bins = np.empty((n_bins, 6), np.float32)
    bin_n = np.empty(n_bins, np.int64)
    right_cost = np.empty(n_bins)
    right_box = np.empty((n_bins, 6))
    box = np.empty(12)
    s_bins = np.empty((n_bins, 6))
    s_enter = np.zeros(n_bins, np.int64)
    s_leave = np.zeros(n_bins, np.int64)
    s_right_n = np.zeros(n_bins, np.int64)
    piece = np.empty(6, np.float32)
    side = np.empty(pool if spatial else 1, np.int8)
    pieces = np.empty((pool if spatial else 1, 2, 6), np.float32)
    # Work items, depth first: (parent node or -1 for the root, child slot, start, end, inner
    # nodes above, end of the slots the range may grow into)
    work = np.empty((2 * pool + 8, 6), np.int64)
    n_nodes = 1
    depth = 1
    top = 0
    if n <= 1:
        # The root is inner: one leaf (or none) in slot 0, copied to slot 1 below (one copy of its
        # objects: the pool holds n)
        work[top, 0], work[top, 1], work[top, 2], work[top, 3], work[top, 4], work[top, 5] = 0, 0, 0, n, 1, n
        top += 1
    else:
        work[top, 0], work[top, 1], work[top, 2], work[top, 3], work[top, 4], work[top, 5] = -1, 0, 0, n, 0, pool
        top += 1
    while top > 0:
        top -= 1
        parent, slot, start, end, above, cap_end = work[top, 0], work[top, 1], work[top, 2], work[top, 3], \
            work[top, 4], work[top, 5]
        count = end - start
        _range_box(order, start, end, ref_lo, ref_hi, centroid, box)
        if parent >= 0:
            for a in range(3):
                child_lo[parent, slot, a] = box[a]
                child_hi[parent, slot, a] = box[3 + a]
        axis, k, cost, overlap = -1, 0, np.inf, np.inf
        if count > 1:
            axis, k, cost, overlap = _best_split(order, start, end, ref_lo, ref_hi, centroid, box, n_bins, bins,
                                                 bin_n, right_cost, right_box)
        s_axis, s_k = -1, 0
        if spatial and count > 1 and cap_end > end and overlap > alpha_area:
            s_axis, s_k, s_cost = best_spatial_split(order, start, end, ref_lo, ref_hi, ref_tri, vertices, faces,
                                                     box, n_bins, s_bins, s_enter, s_leave, right_cost, s_right_n,
                                                     piece)
            if s_axis >= 0 and s_cost < cost:
                cost = s_cost
            else:
                s_axis = -1
        make_leaf = parent >= 0 and count <= max_leaf
        if make_leaf and count > 1 and (axis >= 0 or s_axis >= 0):
            area = _half_area(box[3] - box[0], box[4] - box[1], box[5] - box[2])
            make_leaf = area <= 0.0 or ci * count <= ct + ci * cost / area
        if make_leaf:
            child_ref[parent, slot] = ~((n_objects << LEAF_BITS) | count)
            for j in range(start, end):
                objects[n_objects] = ref_tri[order[j]]
                n_objects += 1
            depth = max(depth, above)
            continue
        node = 0
        if parent >= 0:
            node = n_nodes
            n_nodes += 1
            child_ref[parent, slot] = node
        n_left = -1
        if s_axis >= 0:
            n_left, right, n_right, n_ids = spatial_partition(order, start, end, cap_end, s_axis, s_k, box, n_bins,
                                                              ref_lo, ref_hi, centroid, ref_tri, n_ids, vertices,
                                                              faces, side, pieces)
        if n_left < 0:
            if axis >= 0:
                mid = _partition(order, start, end, centroid, axis, k, box, n_bins)
            else:
                mid = start + count // 2       # coincident centroids: cut the list in the middle
            n_left, right, n_right = mid - start, mid, end - mid
            # Share the free slots by the counts
            by = (cap_end - end) * n_left // count
            if by > 0:
                _shift_right(order, mid, end, by)
                right += by
        # Push the second child first, so the first is built (and laid out) next to its parent
        work[top, 0], work[top, 1], work[top, 2], work[top, 3], work[top, 4] = node, 1, right, right + n_right, above + 1
        work[top, 5] = cap_end
        work[top + 1, 0], work[top + 1, 1], work[top + 1, 2] = node, 0, start
        work[top + 1, 3], work[top + 1, 4], work[top + 1, 5] = start + n_left, above + 1, right
        top += 2
    if n <= 1:
        child_lo[0, 1], child_hi[0, 1], child_ref[0, 1] = child_lo[0, 0], child_hi[0, 0], child_ref[0, 0]
    return (child_lo[:n_nodes].copy(), child_hi[:n_nodes].copy(), child_ref[:n_nodes].copy(), depth,
            objects[:n_objects].copy())


def build_bvh(vertices: np.ndarray, faces: np.ndarray, params: BvhBuildParams = BvhBuildParams()) -> Bvh:
    """Build the binned-SAH BVH of a triangle mesh (module docstring), with spatial splits when
    params.spatial (rtlab.accel.bvh_splits)."""
    t0 = time.perf_counter()
    vertices = np.ascontiguousarray(vertices, np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise SceneError(f"BVH build: face indices out of range of the {len(vertices)} vertices")
    tri_lo, tri_hi, usable = _usable_boxes(vertices, faces)
    order = np.flatnonzero(usable).astype(np.int32)
    n, n_faces = len(order), len(faces)
    extra = int(params.spatial_growth * n) if params.spatial else 0
    if n + extra >= 1 << (31 - LEAF_BITS):
        raise SceneError(f"BVH build: {n + extra:,} triangle references, more than a leaf ref addresses "
                         f"({1 << (31 - LEAF_BITS):,})")
    # References: ids 0..n_faces-1 are the triangles, spatial splits add up to ``extra`` more
    ref_lo = np.zeros((n_faces + extra, 3), np.float32)
    ref_hi = np.zeros((n_faces + extra, 3), np.float32)
    ref_lo[:n_faces], ref_hi[:n_faces] = tri_lo, tri_hi
    ref_tri = np.arange(n_faces + extra, dtype=np.int32)
    centroid = 0.5 * (ref_lo.astype(np.float64) + ref_hi)
    pool = np.empty(n + extra, np.int32)
    pool[:n] = order
    if n:
        bounds = np.stack([tri_lo[order].min(0), tri_hi[order].max(0)]).astype(np.float32)
    else:
        bounds = np.zeros((2, 3), np.float32)
    e = bounds[1].astype(np.float64) - bounds[0]
    alpha_area = params.spatial_alpha * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0]) if params.spatial else -1.0
    child_lo, child_hi, child_ref, depth, objects = _build(
        pool, n, ref_lo, ref_hi, centroid, ref_tri, n_faces, vertices, faces, params.bins, params.max_leaf_size,
        float(params.cost_traversal), float(params.cost_intersect), float(alpha_area))
    return Bvh(child_lo, child_hi, child_ref, objects, bounds, int(depth), params, time.perf_counter() - t0)


def _save(path: Path, bvh: Bvh) -> None:
    atomic_savez(path, child_lo=bvh.child_lo, child_hi=bvh.child_hi, child_ref=bvh.child_ref,
                 objects=bvh.objects, bounds=bvh.bounds, depth=np.int64(bvh.depth),
                 build_seconds=np.float64(bvh.build_seconds), format=np.str_(FORMAT_VERSION))


def _load(path: Path, params: BvhBuildParams) -> Bvh:
    with np.load(path, allow_pickle=False) as z:
        if str(z["format"]) != FORMAT_VERSION:
            raise ValueError(f"{path.name}: format {z['format']}, expected {FORMAT_VERSION}")
        ref = z["child_ref"]
        if ref.dtype != np.int32 or ref.ndim != 2 or ref.shape[1] != 2 or z["child_lo"].shape != (len(ref), 2, 3):
            raise ValueError(f"{path.name}: unexpected array shapes or types")
        return Bvh(z["child_lo"], z["child_hi"], ref, z["objects"], z["bounds"], int(z["depth"]), params,
                   float(z["build_seconds"]))


def load_or_build_bvh(vertices: np.ndarray, faces: np.ndarray, params: BvhBuildParams = BvhBuildParams(),
                      cache_dir: str | os.PathLike | None = None) -> tuple[Bvh, bool]:
    """The mesh's BVH from the on-disk cache (keyed like the kd-tree's: mesh content and build
    parameters; RTLAB_NO_CACHE=1 turns it off), else built and stored. Returns (bvh, from_cache)."""
    if not paths.cache_enabled():
        return build_bvh(vertices, faces, params), False
    directory = Path(cache_dir) if cache_dir is not None else paths.accel_cache_dir()
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{cache_key(vertices, faces, params)}.npz"
    return load_or_build(path, lambda p: _load(p, params), lambda: build_bvh(vertices, faces, params), _save, "BVH")
