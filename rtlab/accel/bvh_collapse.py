"""Wide BVHs from the binary ones (rtlab.accel.bvh): the shared steps of rtlab.accel.bvh8 and bvh4.

 1. Each binary leaf (up to 8 triangles) is split further down to one triangle a leaf by an exact
    SAH sweep over its triangles' boxes clipped to the leaf's box (a spatial split's triangle may
    reach past its leaf; the clip keeps every point of it that the leaf covers). Above the leaves
    the binned SAH split of rtlab.accel.bvh is what a one-triangle-leaf build would choose anyway.
 2. Optimal collapse to ``width`` children a node by dynamic programming over the binary tree
    (Ylitie, Karras & Laine, "Efficient Incoherent Ray Traversal on GPUs Through Compressed Wide
    BVHs", HPG 2017): C(n, i), the least SAH cost of representing the subtree of n by at most i
    subtrees, from the choices leaf (at most ``leaf_max`` triangles), inner node (cost_node x area +
    its best distribution over ``width`` slots) and distribution of i slots among the two children.
 3. Wide nodes with child slots ordered for the ray octant (Ylitie et al.): slot s holds the
    child whose centre, from the node's centre, lies furthest along -(signs of octant s); greedy
    assignment of the cheapest (child, slot) pair first, as tinybvh does. A node's inner children
    get consecutive node indices and its leaves' triangles consecutive places, in slot order.
The plain and the spatial-split binary trees are both collapsed; the spatial-split one is kept where
its root cost is SPLIT_MIN_GAIN lower (the "bvh" traversal's rule, rtlab.accel.bvh_stats, on this cost).

Why one file: the three numba steps are one algorithm over one set of arrays (the full binary tree's
boxes, children and counts, then the cost tables), each step reading what the one before wrote.

Why many parameters: numba's compiled functions take arrays and scalars one by one (no objects in
nopython mode), so a step's inputs are its parameters.
"""
from __future__ import annotations

import numpy as np

from ..jit import njit
from .bvh import LEAF_BITS, MAX_LEAF, Bvh, BvhBuildParams, _usable_boxes, load_or_build_bvh
from .bvh_stats import SPLIT_BUILD     # the "bvh" traversal's tree

PLAIN_BUILD = BvhBuildParams()
SPLIT_MIN_GAIN = 0.02           # the spatial-split tree is taken where its cost is this much lower


# ---- 1. the binary tree down to one triangle a leaf --------------------------------------------------
@njit(cache=True, inline="always")
def _half_area(lo, hi):
    dx = max(np.float64(hi[0]) - lo[0], 0.0)
    dy = max(np.float64(hi[1]) - lo[1], 0.0)
    dz = max(np.float64(hi[2]) - lo[2], 0.0)
    return dx * dy + dy * dz + dz * dx


@njit(cache=True)
def _sweep_split(items, start, end, box_lo, box_hi, key, order, pre, suf):
    """Sort items[start:end] along the axis of the least SAH cost split (exact sweep, n <= 15) and
    return the split index."""
    n = end - start
    best_cost, best_axis, best_k = np.inf, 0, 1
    for axis in range(3):
        for j in range(n):
            t = items[start + j]
            key[j] = box_lo[t, axis] + box_hi[t, axis]
            order[j] = t
        for j in range(1, n):                 # insertion sort by centroid
            k, t = key[j], order[j]
            i = j - 1
            while i >= 0 and key[i] > k:
                key[i + 1], order[i + 1] = key[i], order[i]
                i -= 1
            key[i + 1], order[i + 1] = k, t
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for j in range(n):
            t = order[j]
            for a in range(3):
                lo[a] = min(lo[a], box_lo[t, a])
                hi[a] = max(hi[a], box_hi[t, a])
            pre[j] = _half_area(lo, hi) * (j + 1)
        lo[:] = np.inf
        hi[:] = -np.inf
        for j in range(n - 1, -1, -1):
            t = order[j]
            for a in range(3):
                lo[a] = min(lo[a], box_lo[t, a])
                hi[a] = max(hi[a], box_hi[t, a])
            suf[j] = _half_area(lo, hi) * (n - j)
        for k in range(1, n):
            cost = pre[k - 1] + suf[k]
            if cost < best_cost:
                best_cost, best_axis, best_k = cost, axis, k
    for j in range(n):                        # the best axis' order
        t = items[start + j]
        key[j] = box_lo[t, best_axis] + box_hi[t, best_axis]
        order[j] = t
    for j in range(1, n):
        k, t = key[j], order[j]
        i = j - 1
        while i >= 0 and key[i] > k:
            key[i + 1], order[i + 1] = key[i], order[i]
            i -= 1
        key[i + 1], order[i + 1] = k, t
    for j in range(n):
        items[start + j] = order[j]
    return start + best_k


# Why long: one numba loop that splits every leaf and fills four outputs in node order; split up, each part
# would pass the eight arrays again.
@njit(cache=True)
def _full_tree(child_lo, child_hi, child_ref, objects, tri_lo, tri_hi, leaf_bits, leaf_mask):
    """The binary BVH with every leaf split down to one triangle: node boxes (float32), children
    (-1 for a leaf), the triangle of a leaf, triangle references in each subtree. Node 0 is the
    root; children come after their parent."""
    n_refs = objects.shape[0]
    cap = 2 * (n_refs + child_ref.shape[0]) + 4
    lo = np.empty((cap, 3), np.float32)
    hi = np.empty((cap, 3), np.float32)
    left = np.full(cap, -1, np.int64)
    right = np.full(cap, -1, np.int64)
    tri = np.full(cap, -1, np.int64)
    count = np.zeros(cap, np.int64)
    # a leaf's triangles, boxes clipped to the leaf box (indices into clip_lo/hi)
    clip_lo = np.empty((max(n_refs, 1), 3), np.float32)
    clip_hi = np.empty((max(n_refs, 1), 3), np.float32)
    items = np.empty(16, np.int64)
    key = np.empty(16)
    order = np.empty(16, np.int64)
    pre = np.empty(16)
    suf = np.empty(16)
    sub = np.empty((32, 3), np.int64)        # (start, end, full node) of a leaf's pending ranges
    # (binary node, full node) of inner nodes to expand
    work = np.empty((child_ref.shape[0] + 1, 2), np.int64)
    n = 1
    for a in range(3):
        lo[0, a] = min(child_lo[0, 0, a], child_lo[0, 1, a])
        hi[0, a] = max(child_hi[0, 0, a], child_hi[0, 1, a])
    work[0, 0], work[0, 1] = 0, 0
    top = 1
    n_clip = 0
    while top > 0:
        top -= 1
        b, f = work[top, 0], work[top, 1]
        for c in range(2):
            g = n
            n += 1
            if c == 0:
                left[f] = g
            else:
                right[f] = g
            for a in range(3):
                lo[g, a] = child_lo[b, c, a]
                hi[g, a] = child_hi[b, c, a]
            ref = child_ref[b, c]
            if ref >= 0:
                work[top, 0], work[top, 1] = ref, g
                top += 1
                continue
            bits = ~ref
            first, cnt = bits >> leaf_bits, bits & leaf_mask
            if cnt == 0:                       # an empty mesh's root: a leaf of no triangle
                continue
            if cnt == 1:
                tri[g] = objects[first]
                count[g] = 1
                continue
            # Split the leaf down to single triangles, boxes clipped to the leaf's
            base = n_clip
            for j in range(cnt):
                t = objects[first + j]
                for a in range(3):
                    l0, h0 = lo[g, a], hi[g, a]
                    clip_lo[base + j, a] = min(max(tri_lo[t, a], l0), h0)
                    clip_hi[base + j, a] = max(min(tri_hi[t, a], h0), l0)
                items[j] = base + j
            n_clip += cnt
            stop = 1
            sub[0, 0], sub[0, 1], sub[0, 2] = 0, cnt, g
            while stop > 0:
                stop -= 1
                s, e, node = sub[stop, 0], sub[stop, 1], sub[stop, 2]
                count[node] = e - s
                if e - s == 1:
                    tri[node] = objects[first + items[s] - base]
                    continue
                mid = _sweep_split(items, s, e, clip_lo, clip_hi, key, order, pre, suf)
                for part in range(2):
                    ps, pe = (s, mid) if part == 0 else (mid, e)
                    h = n
                    n += 1
                    if part == 0:
                        left[node] = h
                    else:
                        right[node] = h
                    for a in range(3):
                        lo[h, a] = np.float32(np.inf)
                        hi[h, a] = np.float32(-np.inf)
                    for j in range(ps, pe):
                        for a in range(3):
                            lo[h, a] = min(lo[h, a], clip_lo[items[j], a])
                            hi[h, a] = max(hi[h, a], clip_hi[items[j], a])
                    sub[stop, 0], sub[stop, 1], sub[stop, 2] = ps, pe, h
                    stop += 1
    # Triangle references in each subtree (children come after parents)
    for g in range(n - 1, -1, -1):
        if left[g] >= 0:
            count[g] = count[left[g]] + count[right[g]]
    return lo[:n].copy(), hi[:n].copy(), left[:n].copy(), right[:n].copy(), tri[:n].copy(), count[:n].copy()


# ---- 2. optimal collapse (Ylitie et al. 2017) --------------------------------------------------
@njit(cache=True)
def _collapse_costs(lo, hi, left, right, count, cost_node, cost_prim, leaf_max, width):
    """cost[n, i] (i = 1..width): the least cost of the subtree of n as at most i subtrees;
    leaf[n]: whether n is best a leaf when it takes one slot; split[n, i]: the left child's share
    of i slots in the best distribution of i slots (i >= 2), 0 where fewer than i slots do as well;
    inner_k[n]: the left child's share of the width slots of n as an inner node."""
    m = lo.shape[0]
    cost = np.full((m, width + 1), np.inf)
    leaf = np.zeros(m, np.bool_)
    split = np.zeros((m, width + 1), np.int64)
    inner_k = np.zeros(m, np.int64)
    dist = np.empty(width + 1)
    dist_k = np.empty(width + 1, np.int64)
    for n in range(m - 1, -1, -1):
        area = _half_area(lo[n], hi[n])
        c_leaf = area * count[n] * cost_prim if count[n] <= leaf_max else np.inf
        if left[n] < 0:
            for i in range(1, width + 1):
                cost[n, i] = c_leaf
            leaf[n] = True
            continue
        l, r = left[n], right[n]
        for j in range(2, width + 1):
            best, best_k = np.inf, 1
            for k in range(1, j):
                c = cost[l, k] + cost[r, j - k]
                if c < best:
                    best, best_k = c, k
            dist[j], dist_k[j] = best, best_k
        c_inner = area * cost_node + dist[width]
        inner_k[n] = dist_k[width]
        leaf[n] = c_leaf <= c_inner
        cost[n, 1] = min(c_leaf, c_inner)
        for i in range(2, width + 1):
            if dist[i] < cost[n, i - 1]:
                cost[n, i], split[n, i] = dist[i], dist_k[i]
            else:
                cost[n, i], split[n, i] = cost[n, i - 1], 0
    return cost, leaf, split, inner_k


@njit(cache=True)
def _collect(n, width, left, right, split, inner_k, out, stack):
    """The children of n as an inner node (the subtree roots of its best distribution of ``width``
    slots), left to right, in out; returns how many."""
    k_out = 0
    k = inner_k[n]
    stack[0, 0], stack[0, 1] = right[n], width - k
    stack[1, 0], stack[1, 1] = left[n], k
    top = 2
    while top > 0:
        top -= 1
        x, i = stack[top, 0], stack[top, 1]
        while i > 1 and left[x] >= 0 and split[x, i] == 0:
            i -= 1
        if i == 1 or left[x] < 0:
            out[k_out] = x
            k_out += 1
            continue
        k = split[x, i]
        stack[top, 0], stack[top, 1] = right[x], i - k
        stack[top + 1, 0], stack[top + 1, 1] = left[x], k
        top += 2
    return k_out


@njit(cache=True)
def _leaf_tris(x, left, right, tri, out):
    """The distinct triangles of the leaves under x (a spatial split may reference one twice) in out;
    returns how many."""
    k = 0
    stack = np.empty(64, np.int64)
    stack[0] = x
    top = 1
    while top > 0:
        top -= 1
        y = stack[top]
        if left[y] >= 0:
            stack[top] = right[y]
            stack[top + 1] = left[y]
            top += 2
            continue
        t = tri[y]
        seen = False
        for j in range(k):
            seen |= out[j] == t
        if not seen:
            out[k] = t
            k += 1
    return k


# ---- 3. wide nodes, slots ordered by octant (Ylitie et al.) ---------------------------------------
# Why long: one top-down pass that fills every per-node and per-slot array together: the slot layout reads in
# one place.
@njit(cache=True)
def _wide_nodes(lo, hi, left, right, tri, count, leaf, split, inner_k, width, max_tris):
    """The wide tree: per node its box, per slot (kind 0 empty, 1 inner, 2 leaf) the child box, the
    inner child's node index, the leaf's triangle count and offset; per node the first inner child
    and the first triangle; the triangle ids in leaf order; the depth."""
    m = lo.shape[0]
    cap = m + 1
    n_lo = np.zeros((cap, 3), np.float32)
    n_hi = np.zeros((cap, 3), np.float32)
    kind = np.zeros((cap, width), np.int8)
    c_lo = np.zeros((cap, width, 3), np.float32)
    c_hi = np.zeros((cap, width, 3), np.float32)
    c_node = np.full((cap, width), -1, np.int64)
    c_count = np.zeros((cap, width), np.int64)
    c_offset = np.zeros((cap, width), np.int64)
    child_base = np.zeros(cap, np.int64)
    tri_base = np.zeros(cap, np.int64)
    tris = np.empty(max(1, max_tris), np.int64)
    children = np.empty(width, np.int64)
    stack2 = np.empty((4 * width + 64, 2), np.int64)
    slot_of = np.empty(width, np.int64)
    taken = np.zeros(width, np.bool_)
    cost = np.empty((width, width))
    ltris = np.empty(64, np.int64)
    work = np.empty((cap, 3), np.int64)    # (binary node, wide node, depth)
    work[0, 0], work[0, 1], work[0, 2] = 0, 0, 1
    top = 1
    n_wide = 1
    n_tris = 0
    depth = 1
    while top > 0:
        top -= 1
        b, w, d = work[top, 0], work[top, 1], work[top, 2]
        depth = max(depth, d)
        for a in range(3):
            n_lo[w, a], n_hi[w, a] = lo[b, a], hi[b, a]
        if left[b] < 0:
            # the root is a leaf: one child slot holding it
            k = 1
            children[0] = b
        else:
            k = _collect(b, width, left, right, split, inner_k, children, stack2)
        # Greedy slot assignment: cheapest (child, slot) first; cost = (child centre - node centre)
        # . (signs of the octant): slot s takes the child first along the rays of octant s
        for s in range(width):
            taken[s] = False
            sx = -1.0 if (s >> 2) & 1 else 1.0
            sy = -1.0 if (s >> 1) & 1 else 1.0
            sz = -1.0 if s & 1 else 1.0
            for i in range(k):
                x = children[i]
                cx = (np.float64(lo[x, 0]) + hi[x, 0]) - (np.float64(lo[b, 0]) + hi[b, 0])
                cy = (np.float64(lo[x, 1]) + hi[x, 1]) - (np.float64(lo[b, 1]) + hi[b, 1])
                cz = (np.float64(lo[x, 2]) + hi[x, 2]) - (np.float64(lo[b, 2]) + hi[b, 2])
                cost[i, s] = cx * sx + cy * sy + cz * sz
        for i in range(k):
            slot_of[i] = -1
        for _ in range(k):
            best, bi, bs = np.inf, -1, -1
            for i in range(k):
                if slot_of[i] >= 0:
                    continue
                for s in range(width):
                    if not taken[s] and (bi < 0 or cost[i, s] < best):
                        best, bi, bs = cost[i, s], i, s
            slot_of[bi] = bs
            taken[bs] = True
        # Children in slot order: inner ones get consecutive node indices, leaves consecutive triangles
        child_base[w] = n_wide
        tri_base[w] = n_tris
        for s in range(width):
            i = -1
            for j in range(k):
                if slot_of[j] == s:
                    i = j
            if i < 0:
                continue
            x = children[i]
            for a in range(3):
                c_lo[w, s, a], c_hi[w, s, a] = lo[x, a], hi[x, a]
            if count[x] == 0:
                continue                       # an empty mesh's leaf: the slot stays empty
            if left[x] >= 0 and not leaf[x]:
                kind[w, s] = 1
                c_node[w, s] = n_wide
                work[top, 0], work[top, 1], work[top, 2] = x, n_wide, d + 1
                top += 1
                n_wide += 1
            else:
                kind[w, s] = 2
                cnt = _leaf_tris(x, left, right, tri, ltris)
                c_count[w, s] = cnt
                c_offset[w, s] = n_tris - tri_base[w]
                for j in range(cnt):
                    tris[n_tris] = ltris[j]
                    n_tris += 1
    return (n_lo[:n_wide].copy(), n_hi[:n_wide].copy(), kind[:n_wide].copy(), c_lo[:n_wide].copy(),
            c_hi[:n_wide].copy(), c_node[:n_wide].copy(), c_count[:n_wide].copy(), c_offset[:n_wide].copy(),
            child_base[:n_wide].copy(), tri_base[:n_wide].copy(), tris[:n_tris].copy(), depth)


def collapse(bvh: Bvh, vertices, faces, width: int, leaf_max: int, cost_node: float, cost_prim: float):
    """(wide-tree arrays of _wide_nodes, cost = C(root as an inner node) / area(root)) of the binary BVH
    collapsed to ``width`` children a node."""
    vertices = np.ascontiguousarray(vertices, np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, np.int64).reshape(-1, 3)
    tri_lo, tri_hi, _ = _usable_boxes(vertices, faces)
    lo, hi, left, right, tri, count = _full_tree(bvh.child_lo, bvh.child_hi, bvh.child_ref.astype(np.int64),
                                                 np.asarray(bvh.objects, np.int64), tri_lo, tri_hi, LEAF_BITS,
                                                 MAX_LEAF)
    cost, leaf, split, inner_k = _collapse_costs(lo, hi, left, right, count, float(cost_node), float(cost_prim),
                                                 int(leaf_max), width)
    wide = _wide_nodes(lo, hi, left, right, tri, count, leaf, split, inner_k, width, int(count[0]) + 1)
    area = _half_area(lo[0].astype(np.float64), hi[0].astype(np.float64))
    if left[0] < 0:
        root = float(cost[0, 1])
    else:
        k = int(inner_k[0])
        root = area * cost_node + float(cost[left[0], k] + cost[right[0], width - k])
    return wide, (root / area if area > 0 else 0.0)


def collapse_best(vertices, faces, binary: str, width: int, leaf_max: int, cost_node: float, cost_prim: float,
                  cache_dir=None):
    """(name, binary BVH, wide-tree arrays, cost) of the binary tree ``binary`` ("plain", "split", or
    "auto": both, the spatial-split one where it is SPLIT_MIN_GAIN cheaper) collapsed to ``width``."""
    candidates = []
    for name, params in (("plain", PLAIN_BUILD), ("split", SPLIT_BUILD)):
        if binary in ("auto", name):
            bvh, _ = load_or_build_bvh(vertices, faces, params, cache_dir)
            candidates.append((name, bvh) + collapse(bvh, vertices, faces, width, leaf_max, cost_node, cost_prim))
    if len(candidates) == 2 and not candidates[1][3] <= (1.0 - SPLIT_MIN_GAIN) * candidates[0][3]:
        candidates = candidates[:1]
    return candidates[-1]
