"""A compressed 8-wide BVH for the GPU traversal of kernels/shared/rt_bvh8.h, after Ylitie, Karras &
Laine, "Efficient Incoherent Ray Traversal on GPUs Through Compressed Wide BVHs" (HPG 2017).

Build, from the binary SAH trees of rtlab.accel.bvh (their disk cache, plain and spatial-split):
 1. Each binary leaf (up to 8 triangles) is split further down to one triangle a leaf by an exact
    SAH sweep over its triangles' boxes clipped to the leaf's box (a spatial split's triangle may
    reach past its leaf; the clip keeps every point of it that the leaf covers). Above the leaves
    the binned SAH split of rtlab.accel.bvh is what a one-triangle-leaf build would choose anyway.
 2. Optimal collapse to 8 children a node by dynamic programming over the binary tree (Ylitie et
    al. §3.1): C(n, i), the least SAH cost of representing the subtree of n by at most i subtrees,
    from the choices leaf (at most 3 triangles: the 3-bit unary count of the encoding), inner node
    (cost_node x area + its best distribution over 8 slots) and distribution of i slots among the
    two children. The plain and the spatial-split trees are both collapsed; the spatial-split one
    is kept where its root cost is SPLIT_MIN_GAIN lower (the "bvh" traversal's rule, on this cost).
 3. Child slots ordered for the ray octant (Ylitie et al. §3.2): slot s holds the child whose centre,
    from the node's centre, lies furthest along -(signs of octant s); the traversal visits slot
    s ^ octinv first, so a ray of octant s starts with that child. Greedy assignment of the cheapest
    (child, slot) pair first, as tinybvh does.
 4. Child boxes quantised to 8 bits a plane, rounded outward with a slack (below), relative to a
    node origin p and a power-of-two step 2^e per axis.
 5. Triangles in leaf order after the nodes, three float4 rows each (v0 with the triangle id in w, v1,
    v2: the very floats the scene's tris buffer holds, so the triangle tests give the same bits as
    the binary BVH's), so a node's leaves read contiguous rows and no object list.

Device layout (sync with rt_bvh8.h), node_data float4 rows; node i at rows 5 i .. 5 i + 4 = 80 B:
  row 0  p.x, p.y, p.z (float), w: bytes e.x + 127, e.y + 127, e.z + 127, imask (bit s: slot s is
         an inner node)                                                                  16 B
  row 1  x: row of the first inner child; y: row of the node's first triangle;
         z, w: meta of slots 0-3, 4-7 (a byte a slot)                                    16 B
  rows 2-4  q_lo.x[8], q_lo.y[8], q_lo.z[8], q_hi.x[8], q_hi.y[8], q_hi.z[8]             48 B
meta of an inner child in slot s: 0b001 << 5 | (24 + s), its node at row x + 5 popc(imask below s);
of a leaf child: (unary triangle count 0b1, 0b11, 0b111) << 5 | offset (0-21), its triangles at rows
y + 3 (offset + k); an empty slot: 0. A node holds at most 24 triangles. Child box in slot s, axis a:
[p_a + q_lo[a][s] 2^e_a, p_a + q_hi[a][s] 2^e_a]. The root is node 0 and always inner (an empty
mesh: no children).

Quantisation slack. The kernel computes a plane distance as one fma, (2^15 + q) s + P', from
s = 2^e / d and P' = (p - o) / d - 2^15 s per node and axis (rt_bvh8.h); that errs by a few ulps of
the distance (the 1 + RT_T_PAD exit scale covers those, as in rt_bvh.h) plus up to ~2^-9 of one
step's distance, whatever the distance. Every quantised plane therefore lies SLACK_STEPS = 2^-6 of
a step outside the exact child box: eight times that bound, so no box the exact test keeps is
culled. The same slack covers a zero direction component, which the kernel gives the inverse
+-2^64 (rt_bvh.h's bvh_inverse): a ray lying in a slab is then inside it by at least the slack and
its interval there spans +-2^64 x slack, at least 2^17 scene extents since no step is below
MIN_STEP_EXP (2^-40 of the scene's extent). The kernel's numbers stay finite for coordinates up to
MAX_COORD (2^50).
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from .. import paths
from ..errors import RtlabError, SceneError
from ..kernel_constants import kernel_constant
from .bvh import LEAF_BITS, MAX_LEAF, Bvh, BvhBuildParams, _usable_boxes, load_or_build_bvh
from .bvh_stats import _clip, _moller
from .cache import atomic_savez, cache_key, load_or_build

FORMAT_VERSION = "cwbvh8-v1"    # bump when the builder's output for the same inputs changes
WIDTH = 8
NODE_ROWS = int(kernel_constant("BVH8_NODE_ROWS"))       # float4 rows a node (80 B)
TRI_ROWS = int(kernel_constant("BVH8_TRI_ROWS"))         # float4 rows a triangle (48 B)
LEAF_MAX = 3                    # triangles a leaf child: the 3-bit unary count of the meta byte
NODE_TRIS = 24                  # triangles a node: the low 24 bits of the traversal's hit mask
SLACK_STEPS = 2.0 ** -6         # quantised planes lie this many steps outside the exact box
MIN_STEP_EXP = -40              # no step below 2^-40 of the scene's extent (zero-direction rays)
MAX_COORD = 2.0 ** 50           # coordinates beyond this could overflow the kernel's box test
SPLIT_MIN_GAIN = 0.02           # the spatial-split tree is taken where its cost is this much lower
PLAIN_BUILD = BvhBuildParams()
SPLIT_BUILD = BvhBuildParams(spatial_alpha=1e-5)

NODE_DTYPE = np.dtype([("p", "<f4", 3), ("e", "u1", 3), ("imask", "u1"), ("child_row", "<i4"),
                       ("tri_row", "<i4"), ("meta", "u1", 8), ("qlo", "u1", (3, 8)), ("qhi", "u1", (3, 8))])
assert NODE_DTYPE.itemsize == 16 * NODE_ROWS


@dataclass(frozen=True)
class Bvh8BuildParams:
    """Ylitie et al.'s collapse costs (their c_node = 1, c_prim = 0.3: one 8-wide node test costs
    about three triangle tests) and which binary tree to collapse: "auto" (both; the spatial-split
    one where it is SPLIT_MIN_GAIN cheaper), "plain" or "split"."""
    cost_node: float = 1.0
    cost_prim: float = 0.3
    binary: str = "auto"

    def __post_init__(self):
        if self.binary not in ("auto", "plain", "split"):
            raise RtlabError(f"Bvh8BuildParams.binary must be 'auto', 'plain' or 'split', got {self.binary!r}")
        if not (self.cost_node > 0.0 and self.cost_prim > 0.0):
            raise RtlabError(f"BVH8 costs must be positive, got {self.cost_node}, {self.cost_prim}")

    def key(self) -> str:
        return f"{FORMAT_VERSION}-cn{self.cost_node}-cp{self.cost_prim}-{self.binary}-{PLAIN_BUILD.key()}-{SPLIT_BUILD.key()}"


@dataclass
class Bvh8:
    rows: np.ndarray         # (R, 4) float32: nodes, then triangles (module docstring)
    n_nodes: int
    tri_ids: np.ndarray      # (T,) int32 triangle ids in leaf order (also the w of each triangle's first row)
    bounds: np.ndarray       # (2, 3) float32 root box
    depth: int               # nodes on the longest root-to-leaf path: the stack needs at most depth entries
    cost: float              # the collapse's SAH cost (C(root) / area(root))
    binary: str              # "plain" or "split": the binary tree it was collapsed from
    params: Bvh8BuildParams
    build_seconds: float = 0.0

    def nodes(self) -> np.ndarray:
        """The node rows as NODE_DTYPE records (a view)."""
        return self.rows[:NODE_ROWS * self.n_nodes].reshape(self.n_nodes, 4 * NODE_ROWS).view(NODE_DTYPE).reshape(-1)

    @property
    def tri_row0(self) -> int:
        return NODE_ROWS * self.n_nodes


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


# ---- 2. optimal collapse (Ylitie et al. 2017, §3.1) --------------------------------------------------
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


# ---- 3. wide nodes, slots ordered by octant (Ylitie et al. §3.2) ---------------------------------------
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


# ---- 4. quantisation ---------------------------------------------------------------------------------
def _round_down_f32(x: np.ndarray) -> np.ndarray:
    """The largest float32 <= x (float64 in)."""
    f = x.astype(np.float32)
    return np.where(f.astype(np.float64) > x, np.nextafter(f, np.float32(-np.inf)), f)


def quantise(node_lo, node_hi, child_lo, child_hi, valid, scene_extent: float):
    """Per node and axis the origin p (float32), exponent e and per slot q_lo, q_hi (0..255) with
    p + q_lo 2^e <= child lo - SLACK_STEPS 2^e and p + q_hi 2^e >= child hi + SLACK_STEPS 2^e,
    computed in float64 (module docstring). Empty slots get q_lo = q_hi = 0."""
    finite = np.isfinite(node_lo).all(axis=1) & np.isfinite(node_hi).all(axis=1)   # an empty mesh's root is not
    lo = np.where(finite[:, None], node_lo, 0.0).astype(np.float64)
    hi = np.where(finite[:, None], node_hi, 0.0).astype(np.float64)
    ext = np.maximum(hi - lo, 0.0)
    e_min = np.floor(np.log2(scene_extent)) + MIN_STEP_EXP if scene_extent > 0 else -100.0
    e_min = max(e_min, -100.0)
    with np.errstate(divide="ignore"):
        e = np.ceil(np.log2(np.where(ext > 0, ext / 253.0, 0.0)))
    e = np.maximum(np.where(np.isfinite(e), e, e_min), e_min)
    clo, chi = child_lo.astype(np.float64), child_hi.astype(np.float64)   # (W, 8, 3)
    for _ in range(200):
        step = np.exp2(e)
        p = _round_down_f32(lo - 0.5 * step)
        q_lo = np.floor((clo - p[:, None, :]) / step[:, None, :] - SLACK_STEPS)
        q_hi = np.ceil((chi - p[:, None, :]) / step[:, None, :] + SLACK_STEPS)
        ok = ~valid[:, :, None] | ((q_lo >= 0) & (q_hi <= 255))
        bad = ~ok.all(axis=1)                                  # (W, 3)
        if not bad.any():
            break
        e = np.where(bad, e + 1, e)
    else:
        raise SceneError("BVH8 quantisation did not converge (coordinates beyond float range?)")
    if e.max(initial=0) > 126 or e.min(initial=0) < -126:
        raise SceneError(f"BVH8 quantisation: a step of 2^{int(e.max())} or 2^{int(e.min())} is outside float range")
    q_lo = np.where(valid[:, :, None], q_lo, 0).astype(np.uint8)
    q_hi = np.where(valid[:, :, None], q_hi, 0).astype(np.uint8)
    return p.astype(np.float32), e.astype(np.int64), q_lo, q_hi


def decoded_boxes(bvh8: Bvh8) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) of every slot's quantised box, (W, 8, 3) float64, exactly as the node encodes them."""
    nodes = bvh8.nodes()
    step = np.exp2(nodes["e"].astype(np.float64) - 127.0)                       # (W, 3)
    p = nodes["p"].astype(np.float64)
    lo = p[:, None, :] + nodes["qlo"].transpose(0, 2, 1).astype(np.float64) * step[:, None, :]
    hi = p[:, None, :] + nodes["qhi"].transpose(0, 2, 1).astype(np.float64) * step[:, None, :]
    return lo, hi


# ---- 5. the device rows --------------------------------------------------------------------------------
def _pack(vertices, faces, wide, scene_extent: float) -> tuple[np.ndarray, int, np.ndarray]:
    (n_lo, n_hi, kind, c_lo, c_hi, c_node, c_count, c_offset, child_base, tri_base, tris, _) = wide
    w = len(n_lo)
    p, e, q_lo, q_hi = quantise(n_lo, n_hi, c_lo, c_hi, kind > 0, scene_extent)
    tri_row0 = NODE_ROWS * w
    rows = np.zeros((tri_row0 + TRI_ROWS * len(tris), 4), np.float32)
    nodes = rows[:tri_row0].reshape(w, 4 * NODE_ROWS).view(NODE_DTYPE).reshape(-1)
    nodes["p"] = p
    nodes["e"] = (e + 127).astype(np.uint8)
    slots = np.arange(WIDTH)
    inner = kind == 1
    nodes["imask"] = (inner.astype(np.int64) << slots).sum(axis=1).astype(np.uint8)
    nodes["child_row"] = NODE_ROWS * child_base
    nodes["tri_row"] = tri_row0 + TRI_ROWS * tri_base
    unary = np.array([0, 0b001, 0b011, 0b111])
    meta = np.where(inner, (1 << 5) | (24 + slots), 0)
    meta = np.where(kind == 2, (unary[np.minimum(c_count, 3)] << 5) | c_offset, meta)
    nodes["meta"] = meta.astype(np.uint8)
    nodes["qlo"] = q_lo.transpose(0, 2, 1)
    nodes["qhi"] = q_hi.transpose(0, 2, 1)
    # The inner children of a node are consecutive, in slot order (rt_bvh8.h finds them by popcount)
    order = np.cumsum(inner, axis=1) - 1
    assert np.all(np.where(inner, c_node == child_base[:, None] + order, True)), "inner children not consecutive"
    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.int64)[tris]
    t = rows[tri_row0:].reshape(len(tris), TRI_ROWS, 4)
    for k in range(3):
        t[:, k, :3] = v[f[:, k]]
    t.view(np.int32)[:, 0, 3] = tris.astype(np.int32)
    return rows, w, tris.astype(np.int32)


def _scene_extent(bounds) -> float:
    b = np.asarray(bounds, np.float64)
    return float((b[1] - b[0]).max()) if b.size else 0.0


def collapse(bvh: Bvh, vertices, faces, params: Bvh8BuildParams = Bvh8BuildParams()):
    """(wide-tree arrays of _wide_nodes, cost) of the binary BVH collapsed to 8 children a node."""
    vertices = np.ascontiguousarray(vertices, np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, np.int64).reshape(-1, 3)
    tri_lo, tri_hi, _ = _usable_boxes(vertices, faces)
    lo, hi, left, right, tri, count = _full_tree(bvh.child_lo, bvh.child_hi, bvh.child_ref.astype(np.int64),
                                                 np.asarray(bvh.objects, np.int64), tri_lo, tri_hi, LEAF_BITS,
                                                 MAX_LEAF)
    cost, leaf, split, inner_k = _collapse_costs(lo, hi, left, right, count, float(params.cost_node),
                                                 float(params.cost_prim), LEAF_MAX, WIDTH)
    wide = _wide_nodes(lo, hi, left, right, tri, count, leaf, split, inner_k, WIDTH, int(count[0]) + 1)
    root_area = _half_area(lo[0].astype(np.float64), hi[0].astype(np.float64))
    # the root is always an inner node: its cost as one
    root_cost = root_area * params.cost_node + _root_dist(cost, left, right, inner_k)
    return wide, (root_cost / root_area if root_area > 0 else 0.0)


def _root_dist(cost, left, right, inner_k) -> float:
    if left[0] < 0:
        return float(cost[0, 1])
    k = int(inner_k[0])
    return float(cost[left[0], k] + cost[right[0], WIDTH - k])


def build_bvh8(vertices: np.ndarray, faces: np.ndarray, params: Bvh8BuildParams = Bvh8BuildParams(),
               cache_dir=None) -> Bvh8:
    """The compressed 8-wide BVH of a mesh (module docstring), from the binary trees in the disk cache."""
    t0 = time.perf_counter()
    vertices = np.ascontiguousarray(vertices, np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, np.int64).reshape(-1, 3)
    with np.errstate(invalid="ignore"):
        big = np.abs(vertices[np.isfinite(vertices)]).max(initial=0.0)
    candidates = []
    for name, bparams in (("plain", PLAIN_BUILD), ("split", SPLIT_BUILD)):
        if params.binary in ("auto", name):
            binary, _ = load_or_build_bvh(vertices, faces, bparams, cache_dir)
            candidates.append((name, binary) + collapse(binary, vertices, faces, params))
    if len(candidates) == 2 and not candidates[1][3] <= (1.0 - SPLIT_MIN_GAIN) * candidates[0][3]:
        candidates = candidates[:1]
    name, binary, wide, cost = candidates[-1]
    used = wide[-2]
    if len(used) and np.abs(vertices[np.asarray(faces)[used]]).max() > MAX_COORD:
        raise SceneError(f"BVH8: coordinates up to {big:.3g}, beyond the 2^50 its box test keeps finite: use the "
                         "bvh traversal")
    rows, n_nodes, tri_ids = _pack(vertices, faces, wide, _scene_extent(binary.bounds))
    return Bvh8(rows, n_nodes, tri_ids, binary.bounds.astype(np.float32), int(wide[-1]), float(cost), name, params,
                time.perf_counter() - t0)


def _save(path: Path, b: Bvh8) -> None:
    atomic_savez(path, rows=b.rows, n_nodes=np.int64(b.n_nodes), tri_ids=b.tri_ids, bounds=b.bounds,
                 depth=np.int64(b.depth), cost=np.float64(b.cost), binary=np.str_(b.binary),
                 build_seconds=np.float64(b.build_seconds), format=np.str_(FORMAT_VERSION))


def _load(path: Path, params: Bvh8BuildParams) -> Bvh8:
    with np.load(path, allow_pickle=False) as z:
        if str(z["format"]) != FORMAT_VERSION:
            raise ValueError(f"{path.name}: format {z['format']}, expected {FORMAT_VERSION}")
        rows, n_nodes, tri_ids = z["rows"], int(z["n_nodes"]), z["tri_ids"]
        if (rows.dtype != np.float32 or rows.ndim != 2 or rows.shape[1] != 4 or tri_ids.dtype != np.int32
                or rows.shape[0] != NODE_ROWS * n_nodes + TRI_ROWS * len(tri_ids)):
            raise ValueError(f"{path.name}: unexpected array shapes or types")
        return Bvh8(rows, n_nodes, tri_ids, z["bounds"], int(z["depth"]), float(z["cost"]), str(z["binary"]), params,
                    float(z["build_seconds"]))


def load_or_build_bvh8(vertices: np.ndarray, faces: np.ndarray, params: Bvh8BuildParams = Bvh8BuildParams(),
                       cache_dir: str | os.PathLike | None = None) -> tuple[Bvh8, bool]:
    """The mesh's BVH8 from the on-disk cache (keyed like the other structures: mesh content and build
    parameters; RTLAB_NO_CACHE=1 turns it off), else built and stored. Returns (bvh8, from_cache)."""
    if not paths.cache_enabled():
        return build_bvh8(vertices, faces, params, cache_dir), False
    directory = Path(cache_dir) if cache_dir is not None else paths.accel_cache_dir()
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{cache_key(vertices, faces, params, FORMAT_VERSION)}.npz"
    return load_or_build(path, lambda p: _load(p, params), lambda: build_bvh8(vertices, faces, params, cache_dir),
                         _save, "BVH8")


# ---- host mirror of the traversal: counts and hits (tests, benchmarks/bench_bvh8_quality.py) ----------
@njit(cache=True)
def _count_bvh8(box_lo, box_hi, meta, imask, child_row, tri_row, tri_ids, vertices, faces, scene_lo, scene_hi,
                depth, origins, directions, tmin, node_rows, tri_rows):
    """Per ray: (nodes visited, child boxes tested (non-empty slots), triangle tests, closest triangle
    or -1, its t), walking the decoded boxes in float64 in rt_bvh8.h's order (octant slots, groups on
    a stack, a node's triangles before its children) with Moller-Trumbore in float64."""
    n = origins.shape[0]
    n_nodes = np.zeros(n, np.int64)
    n_boxes = np.zeros(n, np.int64)
    n_tris = np.zeros(n, np.int64)
    hit_tri = np.full(n, -1, np.int64)
    hit_t = np.full(n, np.inf)
    for i in range(n):
        o, d = origins[i], directions[i]
        inv = np.empty(3)
        if not (np.all(np.isfinite(o)) and np.all(np.isfinite(d)) and d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > 0.0):
            continue
        for a in range(3):
            inv[a] = 1.0 / d[a] if d[a] != 0.0 else np.inf
        t0, t1 = _clip(o, inv, scene_lo, scene_hi, tmin, np.inf)
        if not t0 <= t1:
            continue
        octinv = 7 - ((4 if np.signbit(d[0]) else 0) + (2 if np.signbit(d[1]) else 0)
                      + (1 if np.signbit(d[2]) else 0))
        stack_base = np.empty(depth + 1, np.int64)
        stack_mask = np.empty(depth + 1, np.int64)
        sp = 0
        base, mask = 0, np.int64(0x80000000)
        best_t, best = np.inf, -1
        while True:
            bit = 63 - 32
            for b in range(31, 23, -1):
                if (mask >> b) & 1:
                    bit = b
                    break
            slot = (bit - 24) ^ octinv
            rel = 0
            for b in range(slot):
                rel += (mask >> b) & 1
            node = (base + node_rows * rel) // node_rows
            mask &= ~(np.int64(1) << bit)
            if mask & 0xFF000000:
                stack_base[sp], stack_mask[sp] = base, mask
                sp += 1
            n_nodes[i] += 1
            hits = np.int64(0)
            for s in range(8):
                m = meta[node, s]
                if m == 0:
                    continue
                n_boxes[i] += 1
                e0, x0 = _clip(o, inv, box_lo[node, s], box_hi[node, s], tmin, np.inf)
                if not (e0 <= x0 and e0 <= best_t):
                    continue
                if (imask[node] >> s) & 1:
                    hits |= np.int64(1) << (24 + (s ^ octinv))
                else:
                    hits |= np.int64(m >> 5) << (m & 31)
            base = child_row[node]
            mask = (hits & 0xFF000000) | imask[node]
            tb = tri_row[node]
            for b in range(23, -1, -1):
                if (hits >> b) & 1:
                    k = (tb + tri_rows * b) // tri_rows
                    tri = tri_ids[k]
                    n_tris[i] += 1
                    t = _moller(o, d, vertices, faces[tri])
                    if t > tmin and (t < best_t or (t == best_t and tri < best)):
                        best_t, best = t, tri
            if not (mask & 0xFF000000):
                if sp == 0:
                    break
                sp -= 1
                base, mask = stack_base[sp], stack_mask[sp]
        hit_tri[i], hit_t[i] = best, best_t
    return n_nodes, n_boxes, n_tris, hit_tri, hit_t


def traversal_counts_bvh8(b: Bvh8, vertices, faces, origins, directions, tmin: float = 0.0):
    """_count_bvh8 of ``b`` for rays (origins, directions): (nodes, boxes, tris, tri ids, t) per ray."""
    lo, hi = decoded_boxes(b)
    nodes = b.nodes()
    bounds = np.asarray(b.bounds, np.float64)          # grown as rtlab.device.scene.padded_bounds does
    pad = np.abs(bounds).max() * 2.0 ** -20 + (bounds[1] - bounds[0]).max() * 1e-6 + 1e-30
    tri_ids = np.asarray(b.tri_ids, np.int64)
    return _count_bvh8(lo, hi, nodes["meta"].astype(np.int64), nodes["imask"].astype(np.int64),
                       nodes["child_row"].astype(np.int64), (nodes["tri_row"] - b.tri_row0).astype(np.int64),
                       tri_ids, np.asarray(vertices, np.float32).astype(np.float64), np.asarray(faces, np.int64),
                       bounds[0] - pad, bounds[1] + pad, int(b.depth), np.asarray(origins, np.float32).astype(np.float64),
                       np.asarray(directions, np.float32).astype(np.float64), float(tmin), NODE_ROWS, TRI_ROWS)
