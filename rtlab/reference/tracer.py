"""The float64 reference tracer: closest hits that every kernel is checked against.

Ground truth must not share mistakes with what it checks, so nothing here is shared with the GPU
kernels or with ``rtlab.accel``: a bounding-volume hierarchy instead of a kd-tree, float64
instead of float32, and a different triangle test.

Semantics (the contract every kernel is compared with)
-------------------------------------------------------
* Inputs are the float32 scene values, promoted to float64; all arithmetic is float64.
* A ray ``o + t d`` (``d`` need not be normalised; ``t`` is in units of ``|d|``) hits a triangle
  when ``tmin < t < tmax`` (both strict) and the hit point lies inside the triangle or on its
  boundary: edges and vertices are inclusive, triangles are two-sided.
* Closest hit wins; two triangles at exactly the same ``t`` (a shared edge or vertex): the lower
  triangle id wins, so the answer never depends on traversal order.
* ``u``, ``v`` are barycentrics of the hit: point = (1-u-v) v0 + u v1 + v v2.
* Triangles whose area cannot be told apart from zero in float64 (degenerate, see
  :func:`usable_triangle_mask`) or with a non-finite corner are never hit.
* A ray with a NaN/Inf component or a zero direction misses.

Triangle test: the watertight test of Woop, Benthin & Wald, "Watertight Ray/Triangle Intersection",
JCGT 2(1), 2013, in float64. After translating to the ray origin and shearing so the ray runs along
+z, each edge function is computed from the two transformed corners of that edge only, so the two
triangles sharing an edge compute exactly negated values: a ray through a shared edge or vertex
hits at least one of them (no leaks), and with inclusive edges both (their two t may still differ
by an ulp; then the nearer wins). Möller & Trumbore (1997), one of the kernels' tests, has no such
guarantee; a test the kernels do not use also keeps the reference independent.

Traversal: a padded slab test in the spirit of Ize, "Robust BVH Ray Traversal", JCGT 2(2), 2013:
slab distances are widened by their worst-case relative rounding, plus an absolute slack far
above float64 rounding of the triangle t, and node boxes are grown a little in space, so rounding
can never cull a box that holds the closest hit. Zero direction components are handled on their
own (no 0 * inf = NaN).
"""
from __future__ import annotations

import hashlib
import math
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

__all__ = [
    "RefHits",
    "ReferenceBVH",
    "reference_trace",
    "brute_force_trace",
    "intersect_ray_triangles_f64",
    "build_reference_bvh",
    "usable_triangle_mask",
    "cached_reference_bvh",
]

_UNIT_ROUNDOFF = 2.0 ** -53
# Relative widening of one slab distance (b - o) * (1/d): three roundings (subtract, reciprocal,
# multiply), Ize 2013 eq. 7 gives 1 + 2*gamma(3); we take double that for headroom.
_SLAB_REL_PAD = 4.0 * 3.0 * _UNIT_ROUNDOFF / (1.0 - 3.0 * _UNIT_ROUNDOFF)
# Absolute slack, relative to the coordinate magnitudes involved: the float64 triangle t of a
# well-conditioned hit is off by ~1e-15 of those magnitudes; 1e-9 leaves a wide margin and costs
# nothing measurable in culling.
_T_SLACK_REL = 1e-9
_BOX_SPATIAL_PAD_REL = 1e-9

_BVH_MAX_LEAF = 4          # SAH may stop at up to this many triangles per leaf
_BVH_BINS = 16             # binned SAH (Wald 2007, "On fast construction of SAH-based BVHs")
_BVH_TRAVERSAL_COST = 1.0  # relative to one triangle test
_RAYS_PER_TASK = 64        # rays traced by one parallel task (one traversal stack each)


# --------------------------------------------------------------------------------------------
# Result type and input normalisation
# --------------------------------------------------------------------------------------------
@dataclass
class RefHits:
    """Closest hits, one entry per ray."""
    t: np.ndarray    # (R,) float64, inf on miss
    tri: np.ndarray  # (R,) int64 triangle id, -1 on miss
    u: np.ndarray    # (R,) float64 barycentric weight of v1 (nan on miss)
    v: np.ndarray    # (R,) float64 barycentric weight of v2 (nan on miss)

    def __len__(self) -> int:
        return int(self.tri.shape[0])

    @property
    def hit(self) -> np.ndarray:
        return self.tri >= 0

    def points(self, vertices, faces) -> np.ndarray:
        """(R, 3) float64 hit points from the barycentrics (nan on miss)."""
        v64 = np.asarray(vertices, np.float32).astype(np.float64)
        f = np.asarray(faces, np.int64)
        out = np.full((len(self), 3), np.nan)
        h = self.hit
        corners = v64[f[self.tri[h]]]
        u, v = self.u[h, None], self.v[h, None]
        out[h] = (1.0 - u - v) * corners[:, 0] + u * corners[:, 1] + v * corners[:, 2]
        return out


def _mesh_f64(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """The float32 scene values promoted to float64, and faces as int64, validated."""
    v32 = np.asarray(vertices, dtype=np.float32)
    f = np.asarray(faces)
    if v32.ndim != 2 or v32.shape[1] != 3:
        raise ValueError(f"vertices must be (V, 3), got {v32.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must be (F, 3), got {f.shape}")
    f = f.astype(np.int64, copy=False)
    if f.size and (f.min() < 0 or f.max() >= v32.shape[0]):
        raise ValueError("faces index outside vertices")
    return v32.astype(np.float64), f


def _rays_f64(origins, directions) -> tuple[np.ndarray, np.ndarray]:
    o = np.atleast_2d(np.asarray(origins, dtype=np.float64))
    d = np.atleast_2d(np.asarray(directions, dtype=np.float64))
    o, d = np.broadcast_arrays(o, d)
    if o.ndim != 2 or o.shape[1] != 3:
        raise ValueError(f"origins/directions must be (R, 3), got {o.shape}")
    return np.ascontiguousarray(o), np.ascontiguousarray(d)


def _ray_interval(tmin, tmax, n_rays: int) -> tuple[np.ndarray, np.ndarray]:
    """tmin/tmax as (R,) float64: scalars or per-ray arrays (shadow rays want a per-ray tmax)."""
    lo = np.ascontiguousarray(np.broadcast_to(np.asarray(tmin, np.float64), (n_rays,)))
    hi = np.ascontiguousarray(np.broadcast_to(np.asarray(tmax, np.float64), (n_rays,)))
    return lo, hi


def usable_triangle_mask(v0: np.ndarray, v1: np.ndarray, v2: np.ndarray) -> np.ndarray:
    """(F,) bool: corners finite and area certainly non-zero.

    The normal (v1-v0) x (v2-v0) is computed in float64 with a forward error bound per component
    (a Shewchuk-style filter: two differences, two products and a subtraction, each rounding once,
    stay below 8 u (|a b| + |c d|)). A triangle is usable when some component exceeds its bound,
    i.e. its exact area is provably non-zero. Exactly collinear or repeated corners always fail;
    so do slivers thinner than float64 can resolve, which no test could hit reliably anyway.
    """
    finite = np.isfinite(v0).all(1) & np.isfinite(v1).all(1) & np.isfinite(v2).all(1)
    with np.errstate(invalid="ignore", over="ignore"):
        e1 = v1 - v0
        e2 = v2 - v0
        usable = np.zeros(v0.shape[0], dtype=bool)
        for a, b in ((1, 2), (2, 0), (0, 1)):
            p = e1[:, a] * e2[:, b]
            q = e1[:, b] * e2[:, a]
            bound = 8.0 * _UNIT_ROUNDOFF * (np.abs(p) + np.abs(q))
            usable |= np.abs(p - q) > bound
    return usable & finite


# --------------------------------------------------------------------------------------------
# Ray setup shared by all three tracers (numpy and numba versions do the same float operations in
# the same order, so BVH and brute force give bit-identical t)
# --------------------------------------------------------------------------------------------
def _ray_shear_numpy(d: np.ndarray):
    """Woop 2013 section 3: axis permutation (kx, ky, kz) and shear (sx, sy, sz) per ray."""
    absd = np.abs(d)
    # first maximum wins, like the strict '>' chain in _ray_shear below
    kz = np.where(absd[:, 1] > absd[:, 0], 1, 0)
    kz = np.where(absd[:, 2] > absd[np.arange(d.shape[0]), kz], 2, kz)
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    dz = d[np.arange(d.shape[0]), kz]
    flip = dz < 0.0  # keep the winding; irrelevant for two-sided hits but matches the paper
    kx, ky = np.where(flip, ky, kx), np.where(flip, kx, ky)
    with np.errstate(divide="ignore", invalid="ignore"):
        sx = d[np.arange(d.shape[0]), kx] / dz
        sy = d[np.arange(d.shape[0]), ky] / dz
        sz = 1.0 / dz
    valid = np.isfinite(d).all(1) & np.isfinite(sx) & np.isfinite(sy) & np.isfinite(sz)
    return valid, kx, ky, kz, sx, sy, sz


def _woop_numpy(a, b, c, kx, ky, kz, sx, sy, sz):
    """Woop's watertight test on corner-minus-origin arrays a, b, c of shape (..., 3).

    kx..sz broadcast against a[..., 0]. Returns (t, b0, b1, b2, inside): t and the barycentric
    weights of v0, v1, v2 (garbage where not inside), and inside = edge functions of one sign
    with a non-zero determinant (edges inclusive).
    """
    def pick(x, k):
        return np.take_along_axis(x, np.broadcast_to(k, x.shape[:-1])[..., None], -1)[..., 0]

    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        akx, aky, akz = pick(a, kx), pick(a, ky), pick(a, kz)
        bkx, bky, bkz = pick(b, kx), pick(b, ky), pick(b, kz)
        ckx, cky, ckz = pick(c, kx), pick(c, ky), pick(c, kz)
        ax = akx - sx * akz
        ay = aky - sy * akz
        bx = bkx - sx * bkz
        by = bky - sy * bkz
        cx = ckx - sx * ckz
        cy = cky - sy * ckz
        eu = cx * by - cy * bx
        ev = ax * cy - ay * cx
        ew = bx * ay - by * ax
        mixed = ((eu < 0) | (ev < 0) | (ew < 0)) & ((eu > 0) | (ev > 0) | (ew > 0))
        det = eu + ev + ew
        inside = ~mixed & (det != 0.0)
        tt = eu * (sz * akz) + ev * (sz * bkz) + ew * (sz * ckz)
        t = tt / det
        return t, eu / det, ev / det, ew / det, inside


@njit(cache=True, inline="always")
def _ray_shear(dx, dy, dz):
    """Woop 2013 section 3, scalar: (valid, kx, ky, kz, sx, sy, sz)."""
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    kz = 0
    m = ax
    if ay > m:
        kz = 1
        m = ay
    if az > m:
        kz = 2
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    d = (dx, dy, dz)
    dkz = d[kz]
    if dkz < 0.0:
        kx, ky = ky, kx
    if dkz == 0.0 or not (math.isfinite(dx) and math.isfinite(dy) and math.isfinite(dz)):
        return False, kx, ky, kz, 0.0, 0.0, 0.0
    sx = d[kx] / dkz
    sy = d[ky] / dkz
    sz = 1.0 / dkz
    valid = math.isfinite(sx) and math.isfinite(sy) and math.isfinite(sz)
    return valid, kx, ky, kz, sx, sy, sz


@njit(cache=True, inline="always")
def _woop_hit(tv, j, ox, oy, oz, kx, ky, kz, sx, sy, sz):
    """Woop 2013 on triangle row j of tv (v0xyz v1xyz v2xyz) -> (inside, t, u, v).

    Same operations in the same order as _woop_numpy: the brute-force check compares bit for bit.
    """
    o = (ox, oy, oz)
    akx = tv[j, kx] - o[kx]
    aky = tv[j, ky] - o[ky]
    akz = tv[j, kz] - o[kz]
    bkx = tv[j, 3 + kx] - o[kx]
    bky = tv[j, 3 + ky] - o[ky]
    bkz = tv[j, 3 + kz] - o[kz]
    ckx = tv[j, 6 + kx] - o[kx]
    cky = tv[j, 6 + ky] - o[ky]
    ckz = tv[j, 6 + kz] - o[kz]
    ax = akx - sx * akz
    ay = aky - sy * akz
    bx = bkx - sx * bkz
    by = bky - sy * bkz
    cx = ckx - sx * ckz
    cy = cky - sy * ckz
    # edge functions: each uses only the two corners of its edge, so a neighbour sharing the edge
    # computes exactly the negated value (the watertightness argument of Woop 2013)
    eu = cx * by - cy * bx
    ev = ax * cy - ay * cx
    ew = bx * ay - by * ax
    if (eu < 0.0 or ev < 0.0 or ew < 0.0) and (eu > 0.0 or ev > 0.0 or ew > 0.0):
        return False, 0.0, 0.0, 0.0
    det = eu + ev + ew
    if det == 0.0:
        return False, 0.0, 0.0, 0.0
    tt = eu * (sz * akz) + ev * (sz * bkz) + ew * (sz * ckz)
    return True, tt / det, ev / det, ew / det


# --------------------------------------------------------------------------------------------
# BVH: binned SAH over centroids, float64 boxes
# --------------------------------------------------------------------------------------------
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
    v64, f = _mesh_f64(vertices, faces)
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


# --------------------------------------------------------------------------------------------
# BVH traversal
# --------------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _widen_down(t, slack):
    # multiply rather than subtract |t|*pad, so +-inf stays +-inf (inf - inf would be NaN)
    return (t * (1.0 - _SLAB_REL_PAD) if t > 0.0 else t * (1.0 + _SLAB_REL_PAD)) - slack


@njit(cache=True, inline="always")
def _widen_up(t, slack):
    return (t * (1.0 + _SLAB_REL_PAD) if t > 0.0 else t * (1.0 - _SLAB_REL_PAD)) + slack


@njit(cache=True, inline="always")
def _box_entry(node_lo, node_hi, node, o, inv, t_lo, t_hi, slack):
    """Padded slab test (Kay & Kajiya 1986, widened after Ize 2013): entry distance of the ray
    into the box within [t_lo, t_hi], or inf when the box can be skipped."""
    tnear = t_lo
    tfar = t_hi
    for a in range(3):
        lo = node_lo[node, a]
        hi = node_hi[node, a]
        if math.isinf(inv[a]):
            # direction component zero (or subnormal): the ray stays in its slab or never enters
            if o[a] < lo or o[a] > hi:
                return np.inf
            continue
        t0 = (lo - o[a]) * inv[a]
        t1 = (hi - o[a]) * inv[a]
        if t0 > t1:
            t0, t1 = t1, t0
        tnear = max(tnear, _widen_down(t0, slack))
        tfar = min(tfar, _widen_up(t1, slack))
    if tnear <= tfar:
        return tnear
    return np.inf


@njit(cache=True)
def _trace_one(node_lo, node_hi, node_child, node_first, node_count, tri_verts, tri_ids,
               scene_max_abs, ox, oy, oz, dx, dy, dz, tmin, tmax, stack_node, stack_t):
    """Closest hit of one ray: (t, tri, u, v), tri = -1 on a miss."""
    valid, kx, ky, kz, sx, sy, sz = _ray_shear(dx, dy, dz)
    if not (valid and math.isfinite(ox) and math.isfinite(oy) and math.isfinite(oz)):
        return np.inf, -1, np.nan, np.nan
    if math.isnan(tmin) or math.isnan(tmax) or not tmin < tmax:
        return np.inf, -1, np.nan, np.nan
    o = (ox, oy, oz)
    # zero components get inf, which _box_entry treats on its own
    inv = (1.0 / dx if dx != 0.0 else np.inf, 1.0 / dy if dy != 0.0 else np.inf,
           1.0 / dz if dz != 0.0 else np.inf)
    dmax = max(abs(dx), abs(dy), abs(dz))
    # slack in t units for the float64 error of a triangle t (see module docstring)
    slack = _T_SLACK_REL * (scene_max_abs + max(abs(ox), abs(oy), abs(oz))) / dmax
    best_t = tmax
    best_tri = -1
    best_u = np.nan
    best_v = np.nan
    if _box_entry(node_lo, node_hi, 0, o, inv, tmin, best_t, slack) == np.inf:
        return np.inf, -1, np.nan, np.nan
    node = 0
    sp = 0
    while True:
        count = node_count[node]
        if count > 0:
            first = node_first[node]
            for j in range(first, first + count):
                inside, t, u, v = _woop_hit(tri_verts, j, ox, oy, oz, kx, ky, kz, sx, sy, sz)
                if inside and t > tmin and t < tmax:
                    tid = tri_ids[j]
                    # equal t: the lower id wins, whatever order the leaves come in
                    if t < best_t or (t == best_t and tid < best_tri):
                        best_t, best_tri, best_u, best_v = t, tid, u, v
            node = -1
        else:
            left = node_child[node]
            e_left = _box_entry(node_lo, node_hi, left, o, inv, tmin, best_t, slack)
            e_right = _box_entry(node_lo, node_hi, left + 1, o, inv, tmin, best_t, slack)
            if e_left < np.inf and e_right < np.inf:
                near, far, e_far = left, left + 1, e_right
                if e_right < e_left:
                    near, far, e_far = left + 1, left, e_left
                stack_node[sp] = far
                stack_t[sp] = e_far
                sp += 1
                node = near
            elif e_left < np.inf:
                node = left
            elif e_right < np.inf:
                node = left + 1
            else:
                node = -1
        while node < 0 and sp > 0:
            sp -= 1
            # entries were padded when pushed; a closer hit found since may make them skippable
            if stack_t[sp] <= best_t:
                node = stack_node[sp]
        if node < 0:
            break
    if best_tri < 0:
        return np.inf, -1, np.nan, np.nan
    return best_t, best_tri, best_u, best_v


@njit(cache=True, parallel=True)
def _trace_bvh(node_lo, node_hi, node_child, node_first, node_count, tri_verts, tri_ids,
               scene_max_abs, depth, origins, directions, tmin, tmax,
               out_t, out_tri, out_u, out_v):
    n_rays = origins.shape[0]
    n_tasks = (n_rays + _RAYS_PER_TASK - 1) // _RAYS_PER_TASK
    for task in prange(n_tasks):
        stack_node = np.empty(depth + 2, np.int64)  # one entry per level at most
        stack_t = np.empty(depth + 2)
        for r in range(task * _RAYS_PER_TASK, min(n_rays, (task + 1) * _RAYS_PER_TASK)):
            t, tri, u, v = _trace_one(
                node_lo, node_hi, node_child, node_first, node_count, tri_verts, tri_ids,
                scene_max_abs, origins[r, 0], origins[r, 1], origins[r, 2],
                directions[r, 0], directions[r, 1], directions[r, 2], tmin[r], tmax[r],
                stack_node, stack_t)
            out_t[r] = t
            out_tri[r] = tri
            out_u[r] = u
            out_v[r] = v


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


def reference_trace(vertices, faces, origins, directions, tmin=0.0, tmax=np.inf, *,
                    bvh: ReferenceBVH | None = None, cache: bool = True) -> RefHits:
    """Closest hit of every ray in float64 through a BVH (semantics in the module docstring).

    tmin/tmax: scalars or (R,) arrays; hits need tmin < t < tmax. ``bvh``: a prebuilt tree of
    this very mesh (else one is built, and kept in memory when ``cache``).
    """
    o, d = _rays_f64(origins, directions)
    lo, hi = _ray_interval(tmin, tmax, o.shape[0])
    if bvh is None:
        bvh = cached_reference_bvh(vertices, faces) if cache else build_reference_bvh(vertices,
                                                                                       faces)
    n = o.shape[0]
    out_t = np.empty(n)
    out_tri = np.empty(n, np.int64)
    out_u = np.empty(n)
    out_v = np.empty(n)
    if bvh.tri_ids.size == 0:  # no usable triangle: the tree is a placeholder, nothing to hit
        out_t[:], out_tri[:], out_u[:], out_v[:] = np.inf, -1, np.nan, np.nan
    elif n:
        _trace_bvh(bvh.node_lo, bvh.node_hi, bvh.node_child, bvh.node_first, bvh.node_count,
                   bvh.tri_verts, bvh.tri_ids, bvh.scene_max_abs, bvh.depth, o, d, lo, hi,
                   out_t, out_tri, out_u, out_v)
    return RefHits(out_t, out_tri, out_u, out_v)


# --------------------------------------------------------------------------------------------
# Brute force and per-triangle re-intersection (numpy; same arithmetic as the BVH path)
# --------------------------------------------------------------------------------------------
def brute_force_trace(vertices, faces, origins, directions, tmin=0.0, tmax=np.inf, *,
                      pairs_per_chunk: int = 1 << 19) -> RefHits:
    """Every ray against every triangle, numpy-vectorised over chunks of rays. Same contract and
    same float64 operations as :func:`reference_trace`, so results agree bit for bit; meant for
    small inputs and for validating the BVH."""
    v64, f = _mesh_f64(vertices, faces)
    o, d = _rays_f64(origins, directions)
    n = o.shape[0]
    lo, hi = _ray_interval(tmin, tmax, n)
    v0, v1, v2 = v64[f[:, 0]], v64[f[:, 1]], v64[f[:, 2]]
    ids = np.flatnonzero(usable_triangle_mask(v0, v1, v2))  # ascending: argmin picks lowest id
    v0, v1, v2 = v0[ids], v1[ids], v2[ids]
    out = RefHits(np.full(n, np.inf), np.full(n, -1, np.int64), np.full(n, np.nan),
                  np.full(n, np.nan))
    valid, kx, ky, kz, sx, sy, sz = _ray_shear_numpy(d)
    valid &= np.isfinite(o).all(1) & (lo < hi)
    if ids.size == 0:
        return out
    chunk = max(1, pairs_per_chunk // ids.size)
    for s in range(0, n, chunk):
        r = np.arange(s, min(n, s + chunk))
        r = r[valid[r]]
        if r.size == 0:
            continue
        oc = o[r][:, None, :]
        col = (slice(None), None)
        t, _, b1, b2, inside = _woop_numpy(
            v0[None] - oc, v1[None] - oc, v2[None] - oc,
            kx[r][col], ky[r][col], kz[r][col], sx[r][col], sy[r][col], sz[r][col])
        ok = inside & (t > lo[r][col]) & (t < hi[r][col])
        t = np.where(ok, t, np.inf)
        best = np.argmin(t, axis=1)  # first minimum: lowest id among equal t
        rows = np.arange(r.size)
        hit = np.isfinite(t[rows, best])
        rh, bh = r[hit], best[hit]
        out.t[rh] = t[rows[hit], bh]
        out.tri[rh] = ids[bh]
        out.u[rh] = b1[rows[hit], bh]
        out.v[rh] = b2[rows[hit], bh]
    return out


def _intersect_pairs(origin, direction, tri_ids, vertices, faces, eps=0.0, tmin=0.0,
                     tmax=np.inf):
    """Per (ray, triangle) pair: (t, b0, b1, b2), t = inf and b = nan where not hit."""
    v64, f = _mesh_f64(vertices, faces)
    o, d = _rays_f64(origin, direction)
    tri = np.atleast_1d(np.asarray(tri_ids, np.int64))
    k = max(o.shape[0], tri.shape[0])
    o = np.broadcast_to(o, (k, 3))
    d = np.broadcast_to(d, (k, 3))
    tri = np.broadcast_to(tri, (k,))
    t_out = np.full(k, np.inf)
    b_out = np.full((3, k), np.nan)
    known = (tri >= 0) & (tri < f.shape[0])
    if not known.any():
        return t_out, b_out[0], b_out[1], b_out[2]
    fk = f[np.where(known, tri, 0)]
    v0, v1, v2 = v64[fk[:, 0]], v64[fk[:, 1]], v64[fk[:, 2]]
    valid, kx, ky, kz, sx, sy, sz = _ray_shear_numpy(d)
    valid &= known & np.isfinite(o).all(1) & usable_triangle_mask(v0, v1, v2)
    t, b0, b1, b2, inside = _woop_numpy(v0 - o, v1 - o, v2 - o, kx, ky, kz, sx, sy, sz)
    eps = np.broadcast_to(np.asarray(eps, np.float64), (k,))
    with np.errstate(invalid="ignore"):
        # edge slack: accept points up to eps (in barycentric units) outside the triangle;
        # eps = 0 keeps the exact sign test of the tracers
        slack = eps > 0.0
        det_ok = np.isfinite(b0) & np.isfinite(b1) & np.isfinite(b2)
        inside_slack = det_ok & (np.minimum(np.minimum(b0, b1), b2) >= -eps)
        inside = np.where(slack, inside_slack, inside)
        lo, hi = _ray_interval(tmin, tmax, k)
        hit = valid & inside & (t > lo) & (t < hi)
    t_out[hit] = t[hit]
    b_out[0, hit], b_out[1, hit], b_out[2, hit] = b0[hit], b1[hit], b2[hit]
    return t_out, b_out[0], b_out[1], b_out[2]


def intersect_ray_triangles_f64(origin, direction, tri_ids, vertices, faces, eps=0.0, tmin=0.0,
                                tmax=np.inf):
    """Intersect rays with given triangles in float64: (t, u, v) arrays, t = inf (u, v nan)
    where missed.

    origin/direction: (3,) or (K, 3); tri_ids: scalar or (K,), broadcast together. ``eps``:
    barycentric slack (scalar or (K,)): a point counts as inside when all of (1-u-v, u, v) are
    >= -eps; eps = 0 gives exactly the decision of :func:`reference_trace`. Unknown ids (e.g. -1)
    and degenerate triangles give inf. tmin < t < tmax as in the tracer.
    """
    t, _, u, v = _intersect_pairs(origin, direction, tri_ids, vertices, faces, eps, tmin, tmax)
    return t, u, v
