"""The kd-tree builder's numba kernels (rtlab.accel.kdtree builds the tree with them, level by level).

Why one file: over the ~400 lines the project keeps modules under, because these functions call
each other (sweeps, splits, clipping, linking a level), numba compiles them together on first use
and caches them beside this file as one unit; split across modules, a change to one would not
invalidate the cached code of those that inline it. Boxes are float32 rows (lo x, y, z, hi x, y, z);
a box stored here never holds -0.0 (adding +0.0 turns it into +0.0), so equal coordinates have
equal bits in the exact sweep.

Why many parameters: numba's compiled functions take arrays and scalars one by one (no objects in
nopython mode), so a step's inputs are its parameters.
"""
from __future__ import annotations

import numpy as np

from ..jit import njit
from ..kernel_constants import kernel_constant

LEAF_TAG = int(kernel_constant("KD_LEAF"))   # axis field 3 marks a leaf (rt_kdtree.h)
# Event types of the exact sweep, in the order they are processed at one position: references
# ending there leave the right side before planar and starting ones enter the left side.
_EV_END, _EV_PLANAR, _EV_START = 0, 1, 2
_WINDOW = 1    # binned SAH: bins on each side of the best boundary swept exactly


@njit(cache=True)
def _area_terms(node_box, axis, inv_area):
    """(k0, k1) with SA(child) / SA(node) = k0 + k1 * (child's extent along axis)."""
    db = np.float64(node_box[3 + (axis + 1) % 3]) - node_box[(axis + 1) % 3]
    dc = np.float64(node_box[3 + (axis + 2) % 3]) - node_box[(axis + 2) % 3]
    return 2.0 * db * dc * inv_area, 2.0 * (db + dc) * inv_area


@njit(cache=True)
def _split_cost(k0, k1, lo, hi, p, n_left, n_right, ct, ci, eb):
    """Havran's SAH cost of a split at p of the node [lo, hi] along the axis of (k0, k1)."""
    cost = ct + ci * ((k0 + k1 * (p - lo)) * n_left + (k0 + k1 * (hi - p)) * n_right)
    if n_left == 0 or n_right == 0:
        cost *= 1.0 - eb
    return cost


@njit(cache=True)
def box_area(box):
    dx = np.float64(box[3]) - box[0]
    dy = np.float64(box[4]) - box[1]
    dz = np.float64(box[5]) - box[2]
    return 2.0 * (dx * dy + dy * dz + dz * dx)


@njit(cache=True)
def _bin_of(x, lo, scale, nbins):
    return min(max(int((x - lo) * scale), 0), nbins - 1)


@njit(cache=True)
def _bin_refs(ref_box, start, n, node_box, scale, counts):
    """Min-max binning (Wald 2007): counts[0, a, k] references whose minimum on axis a falls in
    bin k, counts[1, a, k] those whose maximum does."""
    nbins = counts.shape[2]
    for side in range(2):
        for a in range(3):
            for k in range(nbins):
                counts[side, a, k] = 0
    for j in range(start, start + n):
        for a in range(3):
            counts[0, a, _bin_of(ref_box[j, a], node_box[a], scale[a], nbins)] += 1
            counts[1, a, _bin_of(ref_box[j, 3 + a], node_box[a], scale[a], nbins)] += 1


@njit(cache=True)
def _best_bin_boundary(counts, a, n, node_box, inv_area, ct, ci, eb):
    """Cheapest plane among the bin boundaries of axis a (-1 if none lies inside the node): the
    plane between bins k-1 and k has the references whose minimum lies in bins < k on its left
    and those whose maximum lies in bins >= k on its right."""
    nbins = counts.shape[2]
    lo, hi = node_box[a], node_box[3 + a]
    k0, k1 = _area_terms(node_box, a, inv_area)
    best_cost, best_k = np.inf, -1
    n_left, n_right = 0, n
    for k in range(1, nbins):
        n_left += counts[0, a, k - 1]
        n_right -= counts[1, a, k - 1]
        p = np.float32(lo + (np.float64(hi) - lo) * k / nbins)
        if not (lo < p < hi):
            continue
        cost = _split_cost(k0, k1, np.float64(lo), np.float64(hi), np.float64(p), n_left, n_right,
                           ct, ci, eb)
        if cost < best_cost:
            best_cost, best_k = cost, k
    return best_k


@njit(cache=True)
def _event_key(bits, kind, index):
    """Sort key of one sweep event: float position (its bits made monotonic), then kind, then
    the reference (so the plane's float can be read back from the winning event)."""
    b = np.int64(bits)
    ordered = b ^ ((b >> 31) & 0x7FFFFFFF)
    return (ordered << 32) | (np.int64(kind) << 30) | index


@njit(cache=True)
def _insertion_sort(keys, lo, hi):
    """Sort keys[lo:hi + 1] in place."""
    for i in range(lo + 1, hi + 1):
        x = keys[i]
        j = i - 1
        while j >= lo and keys[j] > x:
            keys[j + 1] = keys[j]
            j -= 1
        keys[j + 1] = x


@njit(cache=True)
def _sort_keys(keys):
    """Sort distinct keys in place: quicksort (median of three, the shorter part first, so the
    pending stack stays below 2 log2 n entries) down to runs of 24, then insertion sort. Not
    ndarray.sort: numba compiles its own sort for ~1 s on first use."""
    lo, hi = 0, len(keys) - 1
    if hi < 48:                 # most lists: no stack to allocate
        _insertion_sort(keys, lo, hi)
        return
    stack = np.empty(128, np.int64)
    sp = 0
    while True:
        if hi - lo < 24:
            _insertion_sort(keys, lo, hi)
            if sp == 0:
                return
            sp -= 2
            lo, hi = stack[sp], stack[sp + 1]
            continue
        mid = (lo + hi) >> 1
        if keys[mid] < keys[lo]:
            keys[mid], keys[lo] = keys[lo], keys[mid]
        if keys[hi] < keys[lo]:
            keys[hi], keys[lo] = keys[lo], keys[hi]
        if keys[hi] < keys[mid]:
            keys[hi], keys[mid] = keys[mid], keys[hi]
        pivot = keys[mid]
        i, j = lo, hi
        while i <= j:
            while keys[i] < pivot:
                i += 1
            while keys[j] > pivot:
                j -= 1
            if i <= j:
                keys[i], keys[j] = keys[j], keys[i]
                i += 1
                j -= 1
        if j - lo < hi - i:
            stack[sp], stack[sp + 1] = i, hi
            hi = j
        else:
            stack[sp], stack[sp + 1] = lo, j
            lo = i
        sp += 2


# Why long: Wald & Havran's sweep (2006, section 4.2) as one loop over the sorted events, as the paper writes
# it.
@njit(cache=True)
def _sweep_axis(ref_box, ref_bits, start, n, node_box, a, w_lo, w_hi, events, inv_area, ct, ci,
                eb, flat_cells):
    """Exact SAH sweep (Wald & Havran 2006, section 4.2) over the start/end/planar events of
    axis a in the window w_lo <= x < w_hi; every distinct event position strictly inside the
    node is a candidate plane, and with flat_cells the node's faces where triangles lie in them.
    References entirely before the window only enter the counts."""
    lo, hi = node_box[a], node_box[3 + a]
    n_left, n_right = 0, n
    n_flat_lo = n_flat_hi = 0       # references lying in the node's lower / upper face
    m = 0
    for j in range(n):
        ref = start + j
        x0, x1 = ref_box[ref, a], ref_box[ref, 3 + a]
        n_left += x0 < w_lo
        n_right -= x1 < w_lo
        b0, b1 = ref_bits[ref, a], ref_bits[ref, 3 + a]
        if b0 == b1:
            n_flat_lo += x0 == lo
            n_flat_hi += x0 == hi
            if w_lo <= x0 < w_hi:
                events[m] = _event_key(b0, _EV_PLANAR, j)
                m += 1
            continue
        if w_lo <= x0 < w_hi:
            events[m] = _event_key(b0, _EV_START, j)
            m += 1
        if w_lo <= x1 < w_hi:
            events[m] = _event_key(b1, _EV_END, j)
            m += 1
    ev = events[:m]
    _sort_keys(ev)
    k0, k1 = _area_terms(node_box, a, inv_area)
    lo64, hi64 = np.float64(lo), np.float64(hi)
    best_cost, best_pos = np.inf, np.float32(0.0)
    n_planar = n_start = 0          # events seen at the current position
    for i in range(m):
        kind = (ev[i] >> 30) & 3
        n_right -= kind != _EV_START
        n_planar += kind == _EV_PLANAR
        n_start += kind == _EV_START
        if i + 1 < m and (ev[i + 1] >> 32) == (ev[i] >> 32):
            continue
        # Last event at this position: price the plane there (references lying in it go to
        # both sides), then move the ones starting or lying there to the left
        ref = start + (ev[i] & 0x3FFFFFFF)
        p = ref_box[ref, 3 + a] if kind == _EV_END else ref_box[ref, a]
        if lo < p < hi:
            cost = _split_cost(k0, k1, lo64, hi64, np.float64(p), n_left + n_planar,
                               n_right + n_planar, ct, ci, eb)
            if cost < best_cost:
                best_cost, best_pos = cost, p
        n_left += n_start + n_planar
        n_planar = n_start = 0
    # A plane on the node's face cuts the references lying in it off into a flat cell (module
    # docstring): the rest of the node keeps its box without them
    if flat_cells and n_flat_lo > 0:
        cost = _split_cost(k0, k1, lo64, hi64, lo64, n_flat_lo, n - n_flat_lo, ct, ci, eb)
        if cost < best_cost:
            best_cost, best_pos = cost, lo
    if flat_cells and n_flat_hi > 0:
        cost = _split_cost(k0, k1, lo64, hi64, hi64, n - n_flat_hi, n_flat_hi, ct, ci, eb)
        if cost < best_cost:
            best_cost, best_pos = cost, hi
    return best_pos, best_cost


@njit(cache=True)
def _best_split(ref_box, ref_bits, start, n, node_box, binned, scale, counts, events, inv_area,
                ct, ci, eb, flat_cells):
    """Cheapest split (axis, position, cost) of a node over all three axes; axis -1 if none.
    Binned: pick each axis' cheapest bin boundary, then sweep exactly the events within _WINDOW
    bins of it, so planes still sit on clipped triangle bounds (as in the exact sweep) at a
    fraction of its cost. Otherwise sweep every event. scale, counts, events: scratch."""
    if binned:
        for a in range(3):
            extent = np.float64(node_box[3 + a]) - node_box[a]
            scale[a] = counts.shape[2] / extent if extent > 0.0 else 0.0
        _bin_refs(ref_box, start, n, node_box, scale, counts)
    best_cost, best_axis, best_pos = np.inf, -1, np.float32(0.0)
    for a in range(3):
        if not node_box[a] < node_box[3 + a]:
            continue
        w_lo, w_hi = -np.inf, np.inf
        k = _best_bin_boundary(counts, a, n, node_box, inv_area, ct, ci, eb) if binned else -1
        if k >= 0:
            w_lo = node_box[a] + (k - _WINDOW) / scale[a]
            w_hi = node_box[a] + (k + _WINDOW) / scale[a]
        p, cost = _sweep_axis(ref_box, ref_bits, start, n, node_box, a, w_lo, w_hi, events,
                              inv_area, ct, ci, eb, flat_cells)
        if cost < best_cost:
            best_cost, best_axis, best_pos = cost, a, p
    return best_axis, best_pos, best_cost


@njit(cache=True)
def _sides(lo, hi, p, cell_lo, cell_hi):
    """(left, right): whether a reference with extent [lo, hi] on the split axis goes to each
    child of a split at p of the cell [cell_lo, cell_hi] (the rule of the module docstring)."""
    planar = lo == p and hi == p
    return lo < p or (planar and p < cell_hi), hi > p or (planar and p > cell_lo)


@njit(cache=True)
def _count_sides(ref_box, start, n, node_box, axis, p):
    """References going left and right of a split at p."""
    n_left = n_right = 0
    for j in range(start, start + n):
        left, right = _sides(ref_box[j, axis], ref_box[j, 3 + axis], p, node_box[axis],
                             node_box[3 + axis])
        n_left += left
        n_right += right
    return n_left, n_right


@njit(cache=True)
def _nodes_of_runs(runs, run0, run_step):
    """Node indices of runs run0, run0 + run_step, ... (run r: runs[r] to runs[r + 1] - 1)."""
    total = 0
    for r in range(run0, runs.shape[0] - 1, run_step):
        total += runs[r + 1] - runs[r]
    nodes = np.empty(total, np.int64)
    k = 0
    for r in range(run0, runs.shape[0] - 1, run_step):
        for i in range(runs[r], runs[r + 1]):
            nodes[k] = i
            k += 1
    return nodes


@njit(nogil=True, cache=True)
def plan_nodes(ref_box, ref_bits, node_box, node_start, node_count, ct, ci, eb, max_leaf, nbins,
                exact_below, flat_cells, axis, pos, n_left, n_right, runs, run0, run_step):
    """Choose the split of the nodes in runs run0, run0 + run_step, ... (run r: nodes runs[r] to
    runs[r + 1] - 1; axis stays -1: a leaf) and count its children's references."""
    most = 0
    for r in range(run0, runs.shape[0] - 1, run_step):
        for i in range(runs[r], runs[r + 1]):
            most = max(most, node_count[i])
    events = np.empty(2 * most, np.int64)
    counts = np.empty((2, 3, max(nbins, 1)), np.int64)
    scale = np.empty(3)
    for i in _nodes_of_runs(runs, run0, run_step):
        n = node_count[i]
        area = box_area(node_box[i])
        if n <= max_leaf or not area > 0.0:
            continue
        s = node_start[i]
        a, p, cost = _best_split(ref_box, ref_bits, s, n, node_box[i], nbins > 0 and n > exact_below,
                                 scale, counts, events, 1.0 / area, ct, ci, eb, flat_cells)
        if a >= 0 and cost < ci * n:
            axis[i] = a
            pos[i] = p
            n_left[i], n_right[i] = _count_sides(ref_box, s, n, node_box[i], a, p)


@njit(cache=True)
def _clip_to_box(vertices, faces, tri, box, poly):
    """Sutherland-Hodgman: clip triangle tri to box in float64. The polygon ends in poly[which,
    :count]; returns (which, count), count 0 when nothing is left. poly: (2, 16, 3) scratch."""
    for k in range(3):
        for c in range(3):
            poly[0, k, c] = vertices[faces[tri, k], c]
    src, m = 0, 3
    for a in range(3):
        for side in range(2):
            plane = np.float64(box[3 * side + a])
            sign = 1.0 if side == 0 else -1.0       # inside: sign * (x - plane) >= 0
            outside = 0
            for k in range(m):
                outside += sign * (poly[src, k, a] - plane) < 0.0
            if outside == 0:
                continue
            dst, mm = 1 - src, 0
            for k in range(m):
                k1 = k + 1 if k + 1 < m else 0
                dp = sign * (poly[src, k, a] - plane)
                dq = sign * (poly[src, k1, a] - plane)
                if dp >= 0.0:
                    for c in range(3):
                        poly[dst, mm, c] = poly[src, k, c]
                    mm += 1
                if (dp >= 0.0) != (dq >= 0.0):
                    # Put the crossing point exactly on the plane
                    t = dp / (dp - dq)
                    for c in range(3):
                        poly[dst, mm, c] = poly[src, k, c] + t * (poly[src, k1, c] - poly[src, k, c])
                    poly[dst, mm, a] = plane
                    mm += 1
            src, m = dst, mm
            if m == 0:
                return src, 0
    return src, m


@njit(cache=True)
def _down_f32(x):
    y = np.float32(x)
    if y > x:
        y = np.nextafter(y, np.float32(-np.inf))
    return y


@njit(cache=True)
def _up_f32(x):
    y = np.float32(x)
    if y < x:
        y = np.nextafter(y, np.float32(np.inf))
    return y


@njit(cache=True)
def _split_straddler(vertices, faces, tri, ref_box_row, node_box, axis, p, poly, ext, out_left,
                     out_right):
    """Boxes of the parts of a straddling triangle on each side of the plane ("perfect splits"):
    clip it to the node box, then split the polygon at p in one pass over its edges. Boxes are
    rounded outwards and kept inside the reference's current box on that side, so they only
    ever shrink; if rounding left nothing, the side's share of the current box is kept.
    ext: (4, 3) float64 scratch for the two sides' extents."""
    lo_l, hi_l, lo_r, hi_r = ext[0], ext[1], ext[2], ext[3]
    for c in range(3):
        lo_l[c] = lo_r[c] = np.inf
        hi_l[c] = hi_r[c] = -np.inf
    src, m = _clip_to_box(vertices, faces, tri, node_box, poly)
    pp = np.float64(p)
    for k in range(m):
        k1 = k + 1 if k + 1 < m else 0
        x, x1 = poly[src, k, axis], poly[src, k1, axis]
        for c in range(3):
            v = poly[src, k, c]
            if x <= pp:
                lo_l[c] = min(lo_l[c], v)
                hi_l[c] = max(hi_l[c], v)
            if x >= pp:
                lo_r[c] = min(lo_r[c], v)
                hi_r[c] = max(hi_r[c], v)
        if (x < pp < x1) or (x1 < pp < x):
            t = (pp - x) / (x1 - x)
            for c in range(3):
                v = pp if c == axis else poly[src, k, c] + t * (poly[src, k1, c] - poly[src, k, c])
                lo_l[c] = min(lo_l[c], v)
                hi_l[c] = max(hi_l[c], v)
                lo_r[c] = min(lo_r[c], v)
                hi_r[c] = max(hi_r[c], v)
    for c in range(3):
        out_left[c] = ref_box_row[c]
        out_left[3 + c] = ref_box_row[3 + c]
        out_right[c] = ref_box_row[c]
        out_right[3 + c] = ref_box_row[3 + c]
    out_left[3 + axis] = p
    out_right[axis] = p
    if lo_l[0] <= hi_l[0]:
        for c in range(3):
            out_left[c] = max(out_left[c], _down_f32(lo_l[c])) + np.float32(0.0)
            out_left[3 + c] = min(out_left[3 + c], _up_f32(hi_l[c])) + np.float32(0.0)
    if lo_r[0] <= hi_r[0]:
        for c in range(3):
            out_right[c] = max(out_right[c], _down_f32(lo_r[c])) + np.float32(0.0)
            out_right[3 + c] = min(out_right[3 + c], _up_f32(hi_r[c])) + np.float32(0.0)


@njit(cache=True)
def _copy_row(dst, src):
    for c in range(dst.shape[0]):
        dst[c] = src[c]


@njit(nogil=True, cache=True)
def scatter_nodes(vertices, faces, ref_tri, ref_box, node_box, node_start, node_count, axis, pos,
                   dst_left, dst_right, leaf_dst, out_tri, out_box, objects, runs, run0, run_step):
    """Write the references of the split nodes in runs run0, run0 + run_step, ... to their
    children (clipping straddlers) and the triangle lists of its leaves to ``objects``. Rows are
    copied element by element: array assignment would compile numba's broadcasting (~2 s)."""
    poly = np.empty((2, 16, 3))
    ext = np.empty((4, 3))
    for i in _nodes_of_runs(runs, run0, run_step):
        s, n = node_start[i], node_count[i]
        a = axis[i]
        if a < 0:
            for j in range(n):
                objects[leaf_dst[i] + j] = ref_tri[s + j]
            continue
        p = pos[i]
        left, right = dst_left[i], dst_right[i]
        for j in range(s, s + n):
            lo, hi = ref_box[j, a], ref_box[j, 3 + a]
            if lo < p < hi:
                _split_straddler(vertices, faces, ref_tri[j], ref_box[j], node_box[i], a, p,
                                 poly, ext, out_box[left], out_box[right])
                out_tri[left] = out_tri[right] = ref_tri[j]
                left += 1
                right += 1
                continue
            to_left, to_right = _sides(lo, hi, p, node_box[i, a], node_box[i, 3 + a])
            if to_left:
                out_tri[left] = ref_tri[j]
                _copy_row(out_box[left], ref_box[j])
                left += 1
            if to_right:
                out_tri[right] = ref_tri[j]
                _copy_row(out_box[right], ref_box[j])
                right += 1


@njit(nogil=True, cache=True)
def triangle_boxes(vertices, faces):
    """Bounding box of every triangle (no -0.0), and whether it can be hit (finite, non-zero
    area)."""
    n = faces.shape[0]
    boxes = np.empty((n, 6), np.float32)
    usable = np.zeros(n, np.bool_)
    for i in range(n):
        i0, i1, i2 = faces[i, 0], faces[i, 1], faces[i, 2]
        finite = True
        for k in range(3):
            x0, x1, x2 = vertices[i0, k], vertices[i1, k], vertices[i2, k]
            finite &= np.isfinite(x0) and np.isfinite(x1) and np.isfinite(x2)
            boxes[i, k] = min(x0, x1, x2) + np.float32(0.0)
            boxes[i, 3 + k] = max(x0, x1, x2) + np.float32(0.0)
        # Twice the area, in float64: zero for collinear or repeated vertices
        ax, ay, az = np.float64(vertices[i0, 0]), np.float64(vertices[i0, 1]), np.float64(vertices[i0, 2])
        ux, uy, uz = vertices[i1, 0] - ax, vertices[i1, 1] - ay, vertices[i1, 2] - az
        vx, vy, vz = vertices[i2, 0] - ax, vertices[i2, 1] - ay, vertices[i2, 2] - az
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        usable[i] = finite and nx * nx + ny * ny + nz * nz > 0.0
    return boxes, usable


@njit(nogil=True, cache=True)
def link_level(node_box, node_count, axis, pos, n_left, n_right, first_node, first_object, ct,
                ci):
    """Encode one level's nodes (children of its k-th split node become the next level's nodes
    2k and 2k + 1), place the children's reference ranges and the leaves' object lists, and sum
    the level's share of the tree's SAH cost (unnormalised)."""
    n = node_count.shape[0]
    n_split = 0
    for i in range(n):
        n_split += axis[i] >= 0
    words = np.empty((n, 2), np.int32)
    dst_left = np.zeros(n, np.int64)
    dst_right = np.zeros(n, np.int64)
    leaf_dst = np.zeros(n, np.int64)
    next_box = np.empty((2 * n_split, 6), np.float32)
    next_start = np.empty(2 * n_split, np.int64)
    next_count = np.empty(2 * n_split, np.int64)
    n_refs = n_objects = k = 0
    cost = 0.0
    for i in range(n):
        area = box_area(node_box[i])
        a = axis[i]
        if a < 0:
            words[i, 0] = (node_count[i] << 2) | LEAF_TAG
            words[i, 1] = first_object + n_objects
            leaf_dst[i] = n_objects
            n_objects += node_count[i]
            cost += ci * node_count[i] * area
            continue
        words[i, 0] = ((first_node + n + 2 * k) << 2) | a
        words[i, 1] = np.float32(pos[i]).view(np.int32)
        dst_left[i] = n_refs
        dst_right[i] = n_refs + n_left[i]
        for side in range(2):
            _copy_row(next_box[2 * k + side], node_box[i])
        next_box[2 * k, 3 + a] = next_box[2 * k + 1, a] = pos[i]
        next_start[2 * k] = dst_left[i]
        next_start[2 * k + 1] = dst_right[i]
        next_count[2 * k] = n_left[i]
        next_count[2 * k + 1] = n_right[i]
        n_refs += n_left[i] + n_right[i]
        k += 1
        cost += ct * area
    return (words, dst_left, dst_right, leaf_dst, next_box, next_start, next_count, n_refs,
            n_objects, cost)
