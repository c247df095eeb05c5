"""The binned SAH of the BVH builders (Wald 2007, "On fast construction of SAH-based bounding volume
hierarchies"): a range's bounds, the best object split over ``bins`` bins per axis, the partition by
it. rtlab.accel.bvh builds with these; rtlab.accel.bvh_splits adds spatial splits to them.

Why many parameters: numba's compiled functions take arrays and scalars one by one (no objects in
nopython mode), so a step's inputs are its parameters.
"""
from __future__ import annotations

import numpy as np
from ..jit import njit


@njit(cache=True)
def range_box(order, start, end, tri_lo, tri_hi, centroid, box):
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
def half_area(dx, dy, dz):
    return dx * dy + dy * dz + dz * dx


@njit(cache=True, inline="always")
def bin_of(c, lo, scale, n_bins):
    return min(int((c - lo) * scale), n_bins - 1)


@njit(cache=True)
def best_object_split(order, start, end, tri_lo, tri_hi, centroid, box, n_bins, bins, bin_n, right_cost, right_box):
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
            b = bin_of(centroid[t, a], box[6 + a], scale, n_bins)
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
            right_cost[k] = half_area(x1 - x0, y1 - y0, z1 - z0) * count if count > 0 else 0.0
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
            cost = half_area(x1 - x0, y1 - y0, z1 - z0) * count + right_cost[k]
            if cost < best_cost:
                best_axis, best_k, best_cost = a, k, cost
                r = right_box[k]
                dx, dy, dz = min(x1, r[3]) - max(x0, r[0]), min(y1, r[4]) - max(y0, r[1]), min(z1, r[5]) - max(z0, r[2])
                overlap = half_area(dx, dy, dz) if dx >= 0.0 and dy >= 0.0 and dz >= 0.0 else 0.0
    return best_axis, best_k, best_cost, overlap


@njit(cache=True)
def partition_by_bin(order, start, end, centroid, axis, k, box, n_bins):
    """Move centroids in bins < k to the front (the same binning as best_object_split); returns the
    first index of the right part."""
    lo = box[6 + axis]
    scale = n_bins / (box[9 + axis] - lo)
    i, j = start, end - 1
    while i <= j:
        t = order[i]
        if bin_of(centroid[t, axis], lo, scale, n_bins) < k:
            i += 1
        else:
            order[i], order[j] = order[j], order[i]
            j -= 1
    return i


@njit(cache=True, inline="always")
def half_area6(b):
    """Half the surface area of a box given as (lo xyz, hi xyz); 0 for an empty one."""
    dx, dy, dz = b[3] - b[0], b[4] - b[1], b[5] - b[2]
    if dx < 0.0 or dy < 0.0 or dz < 0.0:
        return 0.0
    return half_area(dx, dy, dz)
