"""Spatial splits for the binned-SAH BVH of rtlab.accel.bvh: the SBVH of Stich, Friedrich &
Dietrich, "Spatial splits in bounding volume hierarchies" (HPG 2009).

A node holds *references*: a triangle id and a box around (part of) that triangle. Besides the
object split over reference centroids, a node whose best object split leaves children that overlap
by more than alpha x the root's area also tries spatial splits: ``bins`` planes per axis over the
node box; each reference is chopped into the bins it spans (the triangle clipped to the
bin's slab, in float64, its box intersected with the reference's box). A spatial split is taken
when its SAH cost is lower; references crossing the plane then go to both children with clipped
boxes, unless moving one whole to one side is cheaper (the paper's reference unsplitting).

Every clipped box is conservative: float64 clip points are padded by their rounding bound and
the box is rounded outward to float32, so each point of the triangle inside the reference's box
lies in (the closed box of) at least one child reference, and a child reference's box lies inside
its parent reference's box (child node boxes nest in parent boxes). The reference pool has a
fixed size (the build's budget); a node can only split spatially into the free slots it owns
(its *slack*), which a split shares between the children by their reference counts.

Measured with experiments/bench_bvh_quality.py (512², GPU cost proxy 65 nodes + 45 triangles a ray
against the build without spatial splits), alpha 1e-5 and 32 bins: SPONZA -33 % primary, -28 %
diffuse; CONFERENCE +2 % primary, -17 % diffuse; DRAGON -5 %; BUNNY -0.5 %; KITCHEN +13 % primary
(big walls chopped into pieces that sit deeper, so primary rays find their first hit later), -4 %
diffuse. Off by default in BvhBuildParams; the "bvh" traversal takes the split tree where it lowers
the SAH cost (rtlab.accel.bvh_stats.traversal_bvh, which also gives the H100 figures).

Why many parameters: numba's compiled functions take arrays and scalars one by one (no objects in
nopython mode), so a step's inputs are its parameters.
"""
from __future__ import annotations

import numpy as np

from ..jit import njit
from .bvh_sah import half_area6

CLIP_PAD = 2.0 ** -46        # relative rounding bound of a float64 clip point (a few ulps of 2^-52)


@njit(cache=True, inline="always")
def _down(x):
    """The largest float32 <= x."""
    f = np.float32(x)
    if f > x:
        f = np.nextafter(f, np.float32(-np.inf))
    return f


@njit(cache=True, inline="always")
def _up(x):
    """The smallest float32 >= x."""
    f = np.float32(x)
    if f < x:
        f = np.nextafter(f, np.float32(np.inf))
    return f


@njit(cache=True)
def clip_triangle(vertices, faces, tri, axis, x0, x1, rlo, rhi, out):
    """out[0:3], out[3:6]: a float32 box holding every point p of triangle ``tri`` with
    x0 <= p[axis] <= x1 that lies in the box [rlo, rhi]; False when there is none. The points of
    the triangle in the slab are its corners there and its edges' crossings of the two planes."""
    lo0 = lo1 = lo2 = np.inf
    hi0 = hi1 = hi2 = -np.inf
    for e in range(3):
        a = vertices[faces[tri, e]]
        b = vertices[faces[tri, (e + 1) % 3]]
        xa, xb = np.float64(a[axis]), np.float64(b[axis])
        if x0 <= xa <= x1:
            lo0, hi0 = min(lo0, a[0]), max(hi0, a[0])
            lo1, hi1 = min(lo1, a[1]), max(hi1, a[1])
            lo2, hi2 = min(lo2, a[2]), max(hi2, a[2])
        for plane in (x0, x1):
            if (xa < plane < xb) or (xb < plane < xa):
                # The crossing point, padded by its rounding on the two other axes
                s = (plane - xa) / (xb - xa)
                for m in range(3):
                    if m == axis:
                        p, pad = plane, 0.0
                    else:
                        am, bm = np.float64(a[m]), np.float64(b[m])
                        p = am + (bm - am) * s
                        pad = (abs(am) + abs(bm)) * CLIP_PAD
                    if m == 0:
                        lo0, hi0 = min(lo0, p - pad), max(hi0, p + pad)
                    elif m == 1:
                        lo1, hi1 = min(lo1, p - pad), max(hi1, p + pad)
                    else:
                        lo2, hi2 = min(lo2, p - pad), max(hi2, p + pad)
    if lo0 > hi0:
        return False
    out[0], out[1], out[2] = max(_down(lo0), rlo[0]), max(_down(lo1), rlo[1]), max(_down(lo2), rlo[2])
    out[3], out[4], out[5] = min(_up(hi0), rhi[0]), min(_up(hi1), rhi[1]), min(_up(hi2), rhi[2])
    return out[0] <= out[3] and out[1] <= out[4] and out[2] <= out[5]


@njit(cache=True, inline="always")
def _grow(b, lo, hi):
    for m in range(3):
        b[m] = min(b[m], lo[m])
        b[3 + m] = max(b[3 + m], hi[m])


@njit(cache=True, inline="always")
def plane_at(lo, hi, k, n_bins):
    """Plane k of n_bins equal bins over [lo, hi] (float64; plane n_bins is hi itself)."""
    return hi if k == n_bins else lo + (hi - lo) * k / n_bins


@njit(cache=True, inline="always")
def _spatial_bin(x, lo, scale, n_bins):
    return max(0, min(int((x - lo) * scale), n_bins - 1))


@njit(cache=True)
def best_spatial_split(order, start, end, ref_lo, ref_hi, ref_tri, vertices, faces, box, n_bins, bins,
                       enter, leave, right_cost, right_n, piece):
    """Binned spatial split over the node box box[0:6]: (axis, plane index k, cost in
    half-area x references); axis -1 when no plane leaves references on both sides. bins[b]:
    the bounds of bin b's reference pieces; enter/leave: references starting/ending in bin b."""
    best_axis, best_k, best_cost = -1, 0, np.inf
    acc = np.empty(6)
    for a in range(3):
        lo, hi = np.float64(box[a]), np.float64(box[3 + a])
        if not hi > lo:
            continue
        scale = n_bins / (hi - lo)
        bins[:, 0:3] = np.inf
        bins[:, 3:6] = -np.inf
        enter[:] = 0
        leave[:] = 0
        for j in range(start, end):
            r = order[j]
            first = _spatial_bin(ref_lo[r, a], lo, scale, n_bins)
            last = _spatial_bin(ref_hi[r, a], lo, scale, n_bins)
            enter[first] += 1
            leave[last] += 1
            if first == last:
                _grow(bins[first], ref_lo[r], ref_hi[r])
                continue
            # Chop the reference into the bins it spans
            for b in range(first, last + 1):
                if clip_triangle(vertices, faces, ref_tri[r], a, plane_at(lo, hi, b, n_bins),
                                 plane_at(lo, hi, b + 1, n_bins), ref_lo[r], ref_hi[r], piece):
                    _grow(bins[b], piece[0:3], piece[3:6])
        # Sweep from the right (references ending in bins >= k), then from the left
        acc[0:3] = np.inf
        acc[3:6] = -np.inf
        n_right = 0
        for k in range(n_bins - 1, 0, -1):
            n_right += leave[k]
            _grow(acc, bins[k, 0:3], bins[k, 3:6])
            right_cost[k] = half_area6(acc) * n_right
            right_n[k] = n_right
        acc[0:3] = np.inf
        acc[3:6] = -np.inf
        n_left = 0
        for k in range(1, n_bins):
            n_left += enter[k - 1]
            _grow(acc, bins[k - 1, 0:3], bins[k - 1, 3:6])
            if n_left == 0 or right_n[k] == 0:
                continue
            cost = half_area6(acc) * n_left + right_cost[k]
            if cost < best_cost:
                best_axis, best_k, best_cost = a, k, cost
    return best_axis, best_k, best_cost


# Why long: reference unsplitting and the in-place two-sided partition share every index; apart, they would pass
# the 17 arrays again.
@njit(cache=True)
def spatial_partition(order, start, end, cap_end, axis, k, box, n_bins, ref_lo, ref_hi, centroid, ref_tri,
                      n_ids, vertices, faces, side, pieces):
    """Split the references order[start:end] at plane k on ``axis`` of the node box (as
    best_spatial_split numbers them), with reference unsplitting. Left references go to
    order[start:start + n_left], right ones to order[right:right + n_right]; the node's free
    slots up to cap_end are shared by the counts. A reference sent to both sides keeps its id on
    the left and gets id n_ids, n_ids + 1, ... on the right. Returns (n_left, right, n_right,
    new n_ids), or n_left = -1 (nothing written) when the split leaves a side empty or does not
    fit in cap_end. ``side``, ``pieces``: scratch of at least end - start entries."""
    lo, hi = np.float64(box[axis]), np.float64(box[3 + axis])
    s = plane_at(lo, hi, k, n_bins)
    b_left = np.empty(6)
    b_right = np.empty(6)
    b_left[0:3], b_right[0:3] = np.inf, np.inf
    b_left[3:6], b_right[3:6] = -np.inf, -np.inf
    n_left = n_right = 0
    for j in range(start, end):
        r = order[j]
        i = j - start
        if ref_hi[r, axis] <= s:
            side[i] = 0
        elif ref_lo[r, axis] >= s:
            side[i] = 1
        else:
            has_l = clip_triangle(vertices, faces, ref_tri[r], axis, lo, s, ref_lo[r], ref_hi[r], pieces[i, 0])
            has_r = clip_triangle(vertices, faces, ref_tri[r], axis, s, hi, ref_lo[r], ref_hi[r], pieces[i, 1])
            side[i] = 2 if has_l and has_r else (0 if has_l or not has_r else 1)
            if side[i] == 2:
                _grow(b_left, pieces[i, 0, 0:3], pieces[i, 0, 3:6])
                _grow(b_right, pieces[i, 1, 0:3], pieces[i, 1, 3:6])
                n_left += 1
                n_right += 1
                continue
            # The triangle misses one side within its box: keep the other piece's box
            if not (has_l or has_r):          # cannot happen for a triangle inside its box
                pieces[i, 0, 0:3], pieces[i, 0, 3:6] = ref_lo[r], ref_hi[r]
            p = pieces[i, 0] if has_l or not has_r else pieces[i, 1]
            ref_lo[r], ref_hi[r] = p[0:3], p[3:6]
        if side[i] == 0:
            _grow(b_left, ref_lo[r], ref_hi[r])
            n_left += 1
        else:
            _grow(b_right, ref_lo[r], ref_hi[r])
            n_right += 1
    # Reference unsplitting: a straddling reference goes whole to one side when that is cheaper
    grown = np.empty(6)
    for j in range(start, end):
        i = j - start
        if side[i] != 2:
            continue
        r = order[j]
        a_l, a_r = half_area6(b_left), half_area6(b_right)
        c_split = a_l * n_left + a_r * n_right
        grown[:] = b_left
        _grow(grown, ref_lo[r], ref_hi[r])
        c_left = half_area6(grown) * n_left + a_r * (n_right - 1)
        grown[:] = b_right
        _grow(grown, ref_lo[r], ref_hi[r])
        c_right = a_l * (n_left - 1) + half_area6(grown) * n_right
        if c_left < c_split and c_left <= c_right:
            side[i] = 3
            _grow(b_left, ref_lo[r], ref_hi[r])
            n_right -= 1
        elif c_right < c_split:
            side[i] = 4
            _grow(b_right, ref_lo[r], ref_hi[r])
            n_left -= 1
    total = n_left + n_right
    if n_left == 0 or n_right == 0 or start + total > cap_end:
        return -1, 0, 0, n_ids
    # Share the free slots by the counts; write from a copy of the ids
    right = start + n_left + (cap_end - start - total) * n_left // total
    ids = order[start:end].copy()
    jl, jr = start, right
    for i in range(end - start):
        r = ids[i]
        if side[i] == 0 or side[i] == 3:
            order[jl] = r
            jl += 1
        elif side[i] == 1 or side[i] == 4:
            order[jr] = r
            jr += 1
        else:
            q = n_ids
            n_ids += 1
            ref_tri[q] = ref_tri[r]
            ref_lo[r], ref_hi[r] = pieces[i, 0, 0:3], pieces[i, 0, 3:6]
            ref_lo[q], ref_hi[q] = pieces[i, 1, 0:3], pieces[i, 1, 3:6]
            for m in range(3):
                centroid[q, m] = 0.5 * (np.float64(ref_lo[q, m]) + ref_hi[q, m])
            order[jl] = r
            order[jr] = q
            jl += 1
            jr += 1
        for m in range(3):
            centroid[r, m] = 0.5 * (np.float64(ref_lo[r, m]) + ref_hi[r, m])
    return n_left, right, n_right, n_ids
