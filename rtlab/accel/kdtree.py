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
  -> both children, or only the flat child of a split on the node's face (``_sides``). A triangle that only touches the plane from one side stays on that side: it
  overlaps only that cell, and a ray hitting it on the plane visits that cell (inclusive ranges).
* Zero-area triangles (and any with a non-finite vertex) are never referenced: no ray can hit them.
"""
from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numba
import numpy as np
from numba import njit

from ..device.constants import kernel_constant

LEAF_TAG = int(kernel_constant("KD_LEAF"))   # axis field 3 marks a leaf (rt_kdtree.h)
# Told to build_kdtree's progress when numba compiles the builder (a fresh install, once)
COMPILING_MESSAGE = "compiling the kd-tree builder (first run only: numba caches it)"

# Event types of the exact sweep, in the order they are processed at one position: references
# ending there leave the right side before planar and starting ones enter the left side.
_EV_END, _EV_PLANAR, _EV_START = 0, 1, 2
_WINDOW = 1    # binned SAH: bins on each side of the best boundary swept exactly


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
# numba kernels. Boxes are float32 rows (lo x, y, z, hi x, y, z); a box stored here never holds
# -0.0 (adding +0.0 turns it into +0.0), so equal coordinates have equal bits in the exact sweep.
# ---------------------------------------------------------------------------------------------

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
def _box_area(box):
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
def _plan_nodes(ref_box, ref_bits, node_box, node_start, node_count, ct, ci, eb, max_leaf, nbins,
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
        area = _box_area(node_box[i])
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
def _scatter_nodes(vertices, faces, ref_tri, ref_box, node_box, node_start, node_count, axis, pos,
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
def _triangle_boxes(vertices, faces):
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
def _link_level(node_box, node_count, axis, pos, n_left, n_right, first_node, first_object, ct,
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
        area = _box_area(node_box[i])
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
    tri_box, usable = _triangle_boxes(vertices, faces)
    if progress is not None and _triangle_boxes.stats.cache_misses:
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
    root_area = _box_area(bounds.reshape(6))
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
        _on_threads(_plan_nodes, chunks, ref_box, ref_box.view(np.int32), node_box, node_start,
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
         n_objects, level_cost) = _link_level(node_box, node_count, axis, pos, n_left, n_right,
                                              n_nodes_before, n_objects_before, ct, ci)
        out_tri = np.empty(n_refs_next, np.int32)
        out_box = np.empty((n_refs_next, 6), np.float32)
        objects = np.empty(n_objects, np.int32)
        _on_threads(_scatter_nodes, chunks, vertices, faces, ref_tri, ref_box, node_box, node_start,
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
