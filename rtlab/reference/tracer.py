"""The float64 reference tracer: closest hits that every kernel is checked against. The triangle test
is rtlab.reference.watertight's, the tree rtlab.reference.bvh's; this module holds the contract, the
traversal and the entry points.

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
by an ulp; then the nearer wins). The edge functions only decide whether the ray hits; t is the
distance to the triangle's plane, n.(v0 - o) / n.d with n from the exact float64 edge differences,
which stays accurate for slivers seen at grazing angles where Woop's scaled-barycentric t does not.
Möller & Trumbore (1997), one of the kernels' tests, has no such guarantee.

Traversal: a padded slab test in the spirit of Ize, "Robust BVH Ray Traversal", JCGT 2(2), 2013:
slab distances are widened by their worst-case relative rounding, plus an absolute slack far
above float64 rounding of the triangle t, and node boxes are grown a little in space, so rounding
can never cull a box that holds the closest hit. Zero direction components are handled on their
own (no 0 * inf = NaN).

Why many parameters: numba's compiled functions take arrays and scalars one by one (no objects in
nopython mode), so a step's inputs are its parameters.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..jit import njit, prange
from .bvh import ReferenceBVH, build_reference_bvh, cached_reference_bvh
from .watertight import (UNIT_ROUNDOFF, mesh_f64, ray_shear, ray_shear_numpy, usable_triangle_mask, woop_hit,
                         woop_numpy)

__all__ = ["RefHits", "reference_trace", "brute_force_trace", "intersect_ray_triangles_f64", "intersect_pairs"]

# Relative widening of one slab distance (b - o) * (1/d): three roundings (subtract, reciprocal,
# multiply), Ize 2013 eq. 7 gives 1 + 2*gamma(3); we take double that for headroom.
_SLAB_REL_PAD = 4.0 * 3.0 * UNIT_ROUNDOFF / (1.0 - 3.0 * UNIT_ROUNDOFF)
# Absolute slack, relative to the coordinate magnitudes involved: the float64 triangle t of a
# well-conditioned hit is off by ~1e-15 of those magnitudes; 1e-9 leaves a wide margin and costs
# nothing measurable in culling.
_T_SLACK_REL = 1e-9
_RAYS_PER_TASK = 64        # rays traced by one parallel task (one traversal stack each)


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


# Why long: the reference's whole traversal in one numba function, on purpose: it shares no call with the code
# it checks.
@njit(cache=True)
def _trace_one(node_lo, node_hi, node_child, node_first, node_count, tri_verts, tri_ids,
               scene_max_abs, ox, oy, oz, dx, dy, dz, tmin, tmax, stack_node, stack_t):
    """Closest hit of one ray: (t, tri, u, v), tri = -1 on a miss."""
    valid, kx, ky, kz, sx, sy, sz = ray_shear(dx, dy, dz)
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
                inside, t, u, v = woop_hit(tri_verts, j, ox, oy, oz, dx, dy, dz, kx, ky, kz, sx, sy, sz)
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


def brute_force_trace(vertices, faces, origins, directions, tmin=0.0, tmax=np.inf, *,
                      pairs_per_chunk: int = 1 << 19) -> RefHits:
    """Every ray against every triangle, numpy-vectorised over chunks of rays. Same contract and
    same float64 operations as :func:`reference_trace`, so results agree bit for bit; meant for
    small inputs and for validating the BVH."""
    v64, f = mesh_f64(vertices, faces)
    o, d = _rays_f64(origins, directions)
    n = o.shape[0]
    lo, hi = _ray_interval(tmin, tmax, n)
    v0, v1, v2 = v64[f[:, 0]], v64[f[:, 1]], v64[f[:, 2]]
    ids = np.flatnonzero(usable_triangle_mask(v0, v1, v2))  # ascending: argmin picks lowest id
    v0, v1, v2 = v0[ids], v1[ids], v2[ids]
    out = RefHits(np.full(n, np.inf), np.full(n, -1, np.int64), np.full(n, np.nan),
                  np.full(n, np.nan))
    valid, kx, ky, kz, sx, sy, sz = ray_shear_numpy(d)
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
        t, _, b1, b2, inside = woop_numpy(
            v0[None] - oc, v1[None] - oc, v2[None] - oc, d[r][:, None, :],
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


def intersect_pairs(origin, direction, tri_ids, vertices, faces, eps=0.0, tmin=0.0,
                     tmax=np.inf):
    """Per (ray, triangle) pair: (t, b0, b1, b2), t = inf and b = nan where not hit."""
    v64, f = mesh_f64(vertices, faces)
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
    valid, kx, ky, kz, sx, sy, sz = ray_shear_numpy(d)
    valid &= known & np.isfinite(o).all(1) & usable_triangle_mask(v0, v1, v2)
    t, b0, b1, b2, inside = woop_numpy(v0 - o, v1 - o, v2 - o, d, kx, ky, kz, sx, sy, sz)
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
    t, _, u, v = intersect_pairs(origin, direction, tri_ids, vertices, faces, eps, tmin, tmax)
    return t, u, v
