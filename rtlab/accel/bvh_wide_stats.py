"""Host mirrors of the wide BVH traversals (kernels/shared/rt_bvh8.h, rt_bvh4.h), as
rtlab.accel.bvh_stats mirrors rt_bvh.h: the same visiting order on the same trees (the BVH8's
quantised boxes decoded exactly, the BVH4's float boxes), boxes tested in float64 and triangles by
Moller-Trumbore in float64. Per ray: node visits, child boxes tested, triangle tests, the closest
triangle and its t (tests/test_wide_bvh.py, experiments/bench_wide_bvh_quality.py).

Why many parameters: numba's compiled functions take arrays and scalars one by one (no objects in
nopython mode), so a step's inputs are its parameters.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..jit import njit
from .bvh4 import LEAF_BITS as BVH4_LEAF_BITS, NODE_ROWS as BVH4_NODE_ROWS, Bvh4
from .bvh8 import NODE_ROWS, TRI_ROWS, Bvh8, decoded_boxes
from ..geometry import moller_trumbore_t, ray_scene_interval, slab_interval


# Why long: a float64 walk that follows rt_bvh8.h's traversal statement by statement, so the two read side by
# side.
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
        inv, t0, t1 = ray_scene_interval(o, d, scene_lo, scene_hi, tmin)
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
                e0, x0 = slab_interval(o, inv, box_lo[node, s], box_hi[node, s], tmin, np.inf)
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
                    f = faces[tri]
                    t = moller_trumbore_t(o, d, vertices[f[0]], vertices[f[1]], vertices[f[2]])
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
    bounds = np.asarray(b.bounds, np.float64)          # grown as rtlab.device.device_scene.padded_bounds does
    pad = np.abs(bounds).max() * 2.0 ** -20 + (bounds[1] - bounds[0]).max() * 1e-6 + 1e-30
    tri_ids = np.asarray(b.tri_ids, np.int64)
    return _count_bvh8(lo, hi, nodes["meta"].astype(np.int64), nodes["imask"].astype(np.int64),
                       nodes["child_row"].astype(np.int64), (nodes["tri_row"] - b.tri_row0).astype(np.int64),
                       tri_ids, np.asarray(vertices, np.float32).astype(np.float64), np.asarray(faces, np.int64),
                       bounds[0] - pad, bounds[1] + pad, int(b.depth), np.asarray(origins, np.float32).astype(np.float64),
                       np.asarray(directions, np.float32).astype(np.float64), float(tmin), NODE_ROWS, TRI_ROWS)


# Why long: a float64 walk that follows rt_bvh4.h's traversal statement by statement, so the two read side by
# side.
@njit(cache=True)
def _count_bvh4(planes, refs, tri_rows_ids, tri_row0, vertices, faces, scene_lo, scene_hi, depth, origins,
                directions, tmin, node_rows, tri_rows, leaf_bits, rounds):
    """Per ray: (nodes visited, child boxes tested (non-empty slots), triangle tests, closest triangle
    or -1, its t), in rt_bvh4.h's order (nearest child first, the others pushed farthest first with
    their entry distances, popped ones beyond the closest hit dropped), exact boxes in float64,
    Moller-Trumbore in float64. The node width is planes.shape[2] (4 for rt_bvh4.h). ``rounds`` (n, R,
    3), where R > 0: each ray's first R rounds of the walk's outer loop (inner nodes visited, triangles
    of the leaf reached or 0, stack entries popped), -1 past its last."""
    n = origins.shape[0]
    width = planes.shape[2]
    n_nodes = np.zeros(n, np.int64)
    n_boxes = np.zeros(n, np.int64)
    n_tris = np.zeros(n, np.int64)
    hit_tri = np.full(n, -1, np.int64)
    hit_t = np.full(n, np.inf)
    lo = np.empty(3)
    hi = np.empty(3)
    for i in range(n):
        o, d = origins[i], directions[i]
        inv, t0, t1 = ray_scene_interval(o, d, scene_lo, scene_hi, tmin)
        rounds[i, :, :] = -1
        if not t0 <= t1:
            continue
        stack_ref = np.empty((width - 1) * depth + width, np.int64)
        stack_t = np.empty((width - 1) * depth + width)
        sp = 0
        ref = 0
        best_t, best = np.inf, -1
        keys = np.empty(width)
        kref = np.empty(width, np.int64)
        r = 0
        while True:
            v, c, p = 0, 0, 0
            while ref >= 0:
                node = ref // node_rows
                n_nodes[i] += 1
                v += 1
                k = 0
                for s in range(width):
                    for a in range(3):
                        lo[a], hi[a] = planes[node, 2 * a, s], planes[node, 2 * a + 1, s]
                    if not lo[0] <= hi[0]:
                        continue
                    n_boxes[i] += 1
                    e0, x0 = slab_interval(o, inv, lo, hi, tmin, np.inf)
                    if e0 <= x0 and e0 <= best_t:
                        keys[k], kref[k] = e0, refs[node, s]
                        k += 1
                if k == 0:
                    ref = -(1 << 31)
                    break
                order = np.argsort(keys[:k])
                for j in range(k - 1, 0, -1):
                    stack_ref[sp], stack_t[sp] = kref[order[j]], keys[order[j]]
                    sp += 1
                ref = kref[order[0]]
            if ref != -(1 << 31):
                bits = ~ref
                first, count = bits >> leaf_bits, bits & ((1 << leaf_bits) - 1)
                c = count
                for j in range(count):
                    tri = tri_rows_ids[(first - tri_row0) // tri_rows + j]
                    n_tris[i] += 1
                    f = faces[tri]
                    t = moller_trumbore_t(o, d, vertices[f[0]], vertices[f[1]], vertices[f[2]])
                    if t > tmin and (t < best_t or (t == best_t and tri < best)):
                        best_t, best = t, tri
            ref = -(1 << 31)
            while sp > 0:
                sp -= 1
                p += 1
                if stack_t[sp] <= best_t:
                    ref = stack_ref[sp]
                    break
            if r < rounds.shape[1]:
                rounds[i, r, 0], rounds[i, r, 1], rounds[i, r, 2] = v, c, p
            r += 1
            if ref == -(1 << 31):
                break
        hit_tri[i], hit_t[i] = best, best_t
    return n_nodes, n_boxes, n_tris, hit_tri, hit_t


class WideWalkArrays(NamedTuple):
    """A wide tree of any width laid out as rt_bvh4.h lays its 4: planes (M, 6, width), refs (M, width)
    (inner refs node_rows x node, leaf refs of triangle rows from tri_row0), the leaf-ordered triangle
    ids, the tree's depth and root box."""
    planes: np.ndarray
    refs: np.ndarray
    tri_ids: np.ndarray
    tri_row0: int
    depth: int
    bounds: np.ndarray
    node_rows: int


def traversal_counts_wide(tree: WideWalkArrays, vertices, faces, origins, directions, tmin: float = 0.0,
                          rounds: np.ndarray | None = None):
    """_count_bvh4 of ``tree`` for rays (origins, directions): (nodes, boxes, tris, tri ids, t) per ray.
    ``rounds``: an (n, R, 3) int64 array to fill with each ray's rounds (_count_bvh4)."""
    bounds = np.asarray(tree.bounds, np.float64)       # grown as rtlab.device.device_scene.padded_bounds does
    pad = np.abs(bounds).max() * 2.0 ** -20 + (bounds[1] - bounds[0]).max() * 1e-6 + 1e-30
    o = np.asarray(origins, np.float32).astype(np.float64)
    d = np.asarray(directions, np.float32).astype(np.float64)
    return _count_bvh4(np.asarray(tree.planes, np.float64), np.asarray(tree.refs, np.int64),
                       np.asarray(tree.tri_ids, np.int64), int(tree.tri_row0),
                       np.asarray(vertices, np.float32).astype(np.float64), np.asarray(faces, np.int64),
                       bounds[0] - pad, bounds[1] + pad, int(tree.depth), o, d, float(tmin), int(tree.node_rows),
                       TRI_ROWS, BVH4_LEAF_BITS, np.zeros((len(o), 0, 3), np.int64) if rounds is None else rounds)


def traversal_counts_bvh4(b: Bvh4, vertices, faces, origins, directions, tmin: float = 0.0, planes=None,
                          rounds: np.ndarray | None = None):
    """traversal_counts_wide of ``b``: (nodes, boxes, tris, tri ids, t) per ray. ``planes``: other child
    boxes for the same tree, laid out as Bvh4.planes() (default: b's own); ``rounds``: as there."""
    tree = WideWalkArrays(b.planes() if planes is None else planes, b.refs(), b.tri_ids, b.tri_row0, b.depth,
                          b.bounds, BVH4_NODE_ROWS)
    return traversal_counts_wide(tree, vertices, faces, origins, directions, tmin, rounds)
