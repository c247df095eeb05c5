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
from typing import NamedTuple

import numpy as np

from ..jit import njit, prange
from .. import paths
from ..errors import RtlabError, SceneError
from ..kernel_constants import kernel_constant
from .bvh_sah import best_object_split, half_area, partition_by_bin, range_box
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
def _shift_right(order, mid, end, by):
    """Move order[mid:end] up by ``by`` slots (the left child's share of the free slots)."""
    for j in range(end - 1, mid - 1, -1):
        order[j + by] = order[j]


# The build's work stack: one record a range still to build, depth first
WORK_ITEM = np.dtype([("parent", np.int64),     # node whose child this range becomes; -1: the root
                      ("slot", np.int64),       # which of its two children
                      ("start", np.int64),      # order[start:end], the range's references
                      ("end", np.int64),
                      ("above", np.int64),      # inner nodes above it
                      ("cap_end", np.int64)])   # end of the slots the range may grow into (spatial splits)
# What the build has made so far, in BuildState.counts
N_NODES, N_OBJECTS, TOP, N_IDS, DEPTH = 0, 1, 2, 3, 4


class BuildState(NamedTuple):
    """Everything one build reads and writes, passed to its steps (numba takes a tuple of arrays)."""
    order: np.ndarray          # reference ids, ranges of it become nodes; the tail is the spatial pool
    ref_lo: np.ndarray         # reference boxes and centroids, and the triangle of each reference
    ref_hi: np.ndarray
    centroid: np.ndarray
    ref_tri: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    child_lo: np.ndarray       # the output: child boxes and refs a node, the leaves' triangle ids
    child_hi: np.ndarray
    child_ref: np.ndarray
    objects: np.ndarray
    work: np.ndarray           # WORK_ITEM records
    counts: np.ndarray         # N_NODES, N_OBJECTS, TOP, N_IDS, DEPTH
    box: np.ndarray            # scratch: the range's bounds (rtlab.accel.bvh_sah.range_box)
    bins: np.ndarray           # scratch of the object and spatial split searches
    bin_n: np.ndarray
    right_cost: np.ndarray
    right_box: np.ndarray
    s_bins: np.ndarray
    s_enter: np.ndarray
    s_leave: np.ndarray
    s_right_n: np.ndarray
    piece: np.ndarray
    side: np.ndarray
    pieces: np.ndarray


# Why many parameters: a BuildState's fields, set once here.
def _new_state(order, n, ref_lo, ref_hi, centroid, ref_tri, n_ids, vertices, faces, n_bins, spatial) -> BuildState:
    pool = order.shape[0]
    cap = max(1, 2 * pool)
    counts = np.zeros(5, np.int64)
    counts[N_NODES], counts[N_IDS], counts[DEPTH] = 1, n_ids, 1
    return BuildState(order, ref_lo, ref_hi, centroid, ref_tri, vertices, faces,
                      np.zeros((cap, 2, 3), np.float32), np.zeros((cap, 2, 3), np.float32),
                      np.full((cap, 2), -1, np.int32),           # ~0: an empty leaf
                      np.empty(pool, np.int32), np.zeros(2 * pool + 8, WORK_ITEM), counts, np.empty(12),
                      np.empty((n_bins, 6), np.float32), np.empty(n_bins, np.int64), np.empty(n_bins),
                      np.empty((n_bins, 6)), np.empty((n_bins, 6)), np.zeros(n_bins, np.int64),
                      np.zeros(n_bins, np.int64), np.zeros(n_bins, np.int64), np.empty(6, np.float32),
                      np.empty(pool if spatial else 1, np.int8),
                      np.empty((pool if spatial else 1, 2, 6), np.float32))


@njit(cache=True)
def _push(st, parent, slot, start, end, above, cap_end):
    w = st.work[st.counts[TOP]]
    w["parent"], w["slot"], w["start"], w["end"], w["above"], w["cap_end"] = parent, slot, start, end, above, cap_end
    st.counts[TOP] += 1


@njit(cache=True)
def _make_leaf(st, parent, slot, start, end, above):
    """The range becomes a leaf: its triangles appended to the objects, the parent's ref to them."""
    count = end - start
    st.child_ref[parent, slot] = ~((st.counts[N_OBJECTS] << LEAF_BITS) | count)
    for j in range(start, end):
        st.objects[st.counts[N_OBJECTS]] = st.ref_tri[st.order[j]]
        st.counts[N_OBJECTS] += 1
    st.counts[DEPTH] = max(st.counts[DEPTH], above)


@njit(cache=True)
def _object_split(st, start, end, cap_end, axis, k, n_bins):
    """Partition the range by the binned plane (or in the middle of its list when its centroids
    coincide) and share the range's free slots by the children's counts: (n_left, right, n_right)."""
    count = end - start
    if axis >= 0:
        mid = partition_by_bin(st.order, start, end, st.centroid, axis, k, st.box, n_bins)
    else:
        mid = start + count // 2
    n_left, right, n_right = mid - start, mid, end - mid
    by = (cap_end - end) * n_left // count
    if by > 0:
        _shift_right(st.order, mid, end, by)
        right += by
    return n_left, right, n_right


@njit(cache=True)
def _choose_split(st, start, end, cap_end, n_bins, alpha_area):
    """The cheapest split of the range: (object axis, bin k, spatial axis or -1, spatial bin, cost)."""
    count = end - start
    axis, k, cost, overlap = -1, 0, np.inf, np.inf
    if count > 1:
        axis, k, cost, overlap = best_object_split(st.order, start, end, st.ref_lo, st.ref_hi, st.centroid, st.box, n_bins,
                                             st.bins, st.bin_n, st.right_cost, st.right_box)
    s_axis, s_k = -1, 0
    spatial = alpha_area >= 0.0 and st.order.shape[0] > 0
    if spatial and count > 1 and cap_end > end and overlap > alpha_area:
        s_axis, s_k, s_cost = best_spatial_split(st.order, start, end, st.ref_lo, st.ref_hi, st.ref_tri, st.vertices,
                                                 st.faces, st.box, n_bins, st.s_bins, st.s_enter, st.s_leave,
                                                 st.right_cost, st.s_right_n, st.piece)
        if s_axis >= 0 and s_cost < cost:
            cost = s_cost
        else:
            s_axis = -1
    return axis, k, s_axis, s_k, cost


@njit(cache=True)
def _build(st, n, n_bins, max_leaf, ct, ci, alpha_area):
    """The tree over references order[:n]; the rest of ``order`` is the pool that spatial splits
    (alpha_area >= 0) may fill. Each range becomes a leaf when that is cheaper by the SAH and it
    holds at most max_leaf references, else an inner node whose children are split by objects or
    (SBVH) in space. Returns the number of nodes made."""
    if n <= 1:
        # The root is inner: one leaf (or none) in slot 0, copied to slot 1 below (one copy of its
        # objects: the pool holds n)
        _push(st, 0, 0, 0, n, 1, n)
    else:
        _push(st, -1, 0, 0, n, 0, st.order.shape[0])
    while st.counts[TOP] > 0:
        st.counts[TOP] -= 1
        w = st.work[st.counts[TOP]]
        parent, slot, start, end, above, cap_end = w["parent"], w["slot"], w["start"], w["end"], w["above"], \
            w["cap_end"]
        count = end - start
        range_box(st.order, start, end, st.ref_lo, st.ref_hi, st.centroid, st.box)
        if parent >= 0:
            for a in range(3):
                st.child_lo[parent, slot, a] = st.box[a]
                st.child_hi[parent, slot, a] = st.box[3 + a]
        axis, k, s_axis, s_k, cost = _choose_split(st, start, end, cap_end, n_bins, alpha_area)
        make_leaf = parent >= 0 and count <= max_leaf
        if make_leaf and count > 1 and (axis >= 0 or s_axis >= 0):
            b = st.box
            area = half_area(b[3] - b[0], b[4] - b[1], b[5] - b[2])
            make_leaf = area <= 0.0 or ci * count <= ct + ci * cost / area
        if make_leaf:
            _make_leaf(st, parent, slot, start, end, above)
            continue
        node = 0
        if parent >= 0:
            node = st.counts[N_NODES]
            st.counts[N_NODES] += 1
            st.child_ref[parent, slot] = node
        n_left = -1
        if s_axis >= 0:
            n_left, right, n_right, st.counts[N_IDS] = spatial_partition(
                st.order, start, end, cap_end, s_axis, s_k, st.box, n_bins, st.ref_lo, st.ref_hi, st.centroid,
                st.ref_tri, st.counts[N_IDS], st.vertices, st.faces, st.side, st.pieces)
        if n_left < 0:
            n_left, right, n_right = _object_split(st, start, end, cap_end, axis, k, n_bins)
        # The second child first, so the first is built (and laid out) next to its parent
        _push(st, node, 1, right, right + n_right, above + 1, cap_end)
        _push(st, node, 0, start, start + n_left, above + 1, right)
    if n <= 1:
        st.child_lo[0, 1], st.child_hi[0, 1], st.child_ref[0, 1] = st.child_lo[0, 0], st.child_hi[0, 0], \
            st.child_ref[0, 0]
    return st.counts[N_NODES]


COMPILING_MESSAGE = "compiling the BVH builder (first run only: numba caches it)"


def builder_needs_compiling() -> bool:
    """Whether numba's cache lacked the builder: its first step, run here on one triangle, was
    compiled (the rest then compiles too, some seconds: a first run says so, as the kd-tree's does)."""
    _usable_boxes(np.zeros((3, 3), np.float32), np.arange(3, dtype=np.int64).reshape(1, 3))
    return bool(_usable_boxes.stats.cache_misses)


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
    st = _new_state(pool, n, ref_lo, ref_hi, centroid, ref_tri, n_faces, vertices, faces, params.bins,
                    alpha_area >= 0.0 and len(pool) > n)
    m = _build(st, n, params.bins, params.max_leaf_size, float(params.cost_traversal), float(params.cost_intersect),
               float(alpha_area))
    k = int(st.counts[N_OBJECTS])
    return Bvh(st.child_lo[:m].copy(), st.child_hi[:m].copy(), st.child_ref[:m].copy(), st.objects[:k].copy(),
               bounds, int(st.counts[DEPTH]), params, time.perf_counter() - t0)


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
