"""Quality figures of a BVH from rtlab.accel.bvh, measured on the host: its SAH cost and a counting
traversal that mirrors kernels/shared/rt_bvh.h (experiments/bench_bvh_quality.py, tests); and the
choice, by SAH cost, between the plain build and the spatial-split one for the "bvh" traversal
(traversal_bvh).

The counting traversal walks the tree as traverse_bvh does: the ray is clipped to the scene box
first; a while-while loop tests both child boxes of an inner node against the segment
[tmin, closest hit so far] (inclusive), descends into the nearer child hit (child 0 on a tie) and
pushes the farther; a popped entry is entered without a new box test; a leaf tests all its
triangles (Möller–Trumbore, here in float64 on the float32 data, closest hit, the lower id at an equal t). It counts
inner-node visits and triangle tests per ray.

Why many parameters: numba's compiled functions take arrays and scalars one by one (no objects in
nopython mode), so a step's inputs are its parameters.
"""
from __future__ import annotations

import numpy as np

from ..jit import njit, prange
from ..geometry import moller_trumbore_t, ray_scene_interval, slab_interval
from .bvh import LEAF_BITS, MAX_LEAF, Bvh, BvhBuildParams, load_or_build_bvh

# Instructions a CUDA thread spends per inner-node visit and per triangle test (rt_bvh.h, SASS
# counts): the GPU cost proxy is NODE_COST nodes + TRI_COST triangles a ray
NODE_COST, TRI_COST = 65.0, 45.0


# The "bvh" traversal's tree: spatial splits (SBVH, alpha 1e-5, 16 bins) where they lower the SAH
# cost by at least SPLIT_MIN_GAIN, else the plain binned-SAH build. The SAH cost predicts the GPU
# here: with splits SPONZA, CONFERENCE and DRAGON trace faster on the H100, while KITCHEN, whose SAH
# cost the splits raise (13.4 -> 13.7: big walls chopped into pieces that sit deeper), traces primary
# rays a fifth to a quarter slower, so it keeps the plain tree; BUNNY gains nothing either way (the
# A/B is in CHANGELOG.md, the current figures in docs/results.md).
SPLIT_BUILD = BvhBuildParams(spatial_alpha=1e-5)
SPLIT_MIN_GAIN = 0.02


def traversal_bvh(vertices, faces, cache_dir=None) -> Bvh:
    """The BVH the "bvh" traversal reads (rtlab.device.device_scene.bvh_accel): both builds from the
    on-disk cache or built, the spatial-split one kept where its SAH cost is SPLIT_MIN_GAIN lower."""
    plain, _ = load_or_build_bvh(vertices, faces, BvhBuildParams(), cache_dir)
    split, _ = load_or_build_bvh(vertices, faces, SPLIT_BUILD, cache_dir)
    return split if sah_cost(split) <= (1.0 - SPLIT_MIN_GAIN) * sah_cost(plain) else plain


def sah_cost(bvh: Bvh, cost_traversal: float = 1.0, cost_intersect: float = 1.0) -> float:
    """(C_trav sum of inner-node areas + C_isect sum of leaf area x count) / root area, with the
    same constants for every tree, so that trees of different builds compare."""
    lo, hi, ref = bvh.child_lo.astype(np.float64), bvh.child_hi.astype(np.float64), bvh.child_ref

    def half_area(lo, hi):
        e = np.maximum(hi - lo, 0.0)
        return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]

    node_area = half_area(lo.min(axis=1), hi.max(axis=1))
    child_area = half_area(lo, hi)
    count = np.where(ref < 0, (~ref.astype(np.int64)) & MAX_LEAF, 0)
    root = node_area[0] if len(node_area) else 0.0
    if not root > 0.0:
        return 0.0
    return float((cost_traversal * node_area.sum() + cost_intersect * (child_area * count).sum()) / root)


@njit(parallel=True, cache=True)
def count_traversal(child_lo, child_hi, child_ref, objects, scene_lo, scene_hi, depth, vertices, faces,
                    origins, directions, tmin, tmax, any_hit):
    """Per ray, hits in (tmin, tmax): (inner-node visits, triangle tests, closest triangle id or -1, its t);
    with any_hit the walk stops at the first hit (a shadow ray's), which it returns."""
    n = origins.shape[0]
    nodes = np.zeros(n, np.int64)
    tris = np.zeros(n, np.int64)
    hit_tri = np.full(n, -1, np.int64)
    hit_t = np.full(n, np.inf)
    for i in prange(n):
        o, d = origins[i], directions[i]
        inv, t0, t1 = ray_scene_interval(o, d, scene_lo, scene_hi, tmin)
        if not t0 <= t1:
            continue
        stack = np.empty(depth + 1, np.int64)
        sp = 0
        ref = 0
        best_t, best = np.inf, -1
        n_nodes = n_tris = 0
        while True:
            while ref >= 0:
                n_nodes += 1
                e0, x0 = slab_interval(o, inv, child_lo[ref, 0], child_hi[ref, 0], tmin, tmax)
                e1, x1 = slab_interval(o, inv, child_lo[ref, 1], child_hi[ref, 1], tmin, tmax)
                hit0 = e0 <= x0 and e0 <= best_t
                hit1 = e1 <= x1 and e1 <= best_t
                c0, c1 = child_ref[ref, 0], child_ref[ref, 1]
                if hit0 and hit1:
                    near0 = e0 <= e1
                    stack[sp] = c1 if near0 else c0
                    sp += 1
                    ref = c0 if near0 else c1
                elif hit0 or hit1:
                    ref = c0 if hit0 else c1
                else:
                    if sp == 0:
                        break
                    sp -= 1
                    ref = stack[sp]
            if ref >= 0:
                break                          # popped the last entry of an empty stack
            bits = ~ref
            first, count = bits >> LEAF_BITS, bits & MAX_LEAF
            for j in range(first, first + count):
                tri = objects[j]
                n_tris += 1
                f = faces[tri]
                t = moller_trumbore_t(o, d, vertices[f[0]], vertices[f[1]], vertices[f[2]])
                if t > tmin and t < tmax and (t < best_t or (t == best_t and tri < best)):
                    best_t, best = t, tri
                    if any_hit:
                        break
            if sp == 0 or (any_hit and best >= 0):
                break
            sp -= 1
            ref = stack[sp]
        nodes[i], tris[i], hit_tri[i], hit_t[i] = n_nodes, n_tris, best, best_t
    return nodes, tris, hit_tri, hit_t


def traversal_counts(bvh: Bvh, vertices, faces, origins, directions, tmin: float = 0.0, tmax: float = np.inf,
                     any_hit: bool = False):
    """count_traversal of ``bvh`` for rays (origins, directions): (nodes, tris, tri ids, t) per ray."""
    b = np.asarray(bvh.bounds, np.float64)           # grown as rtlab.device.device_scene.padded_bounds does
    pad = np.abs(b).max() * 2.0 ** -20 + (b[1] - b[0]).max() * 1e-6 + 1e-30
    box = np.stack([b[0] - pad, b[1] + pad])
    return count_traversal(bvh.child_lo.astype(np.float64), bvh.child_hi.astype(np.float64),
                           bvh.child_ref.astype(np.int64), np.asarray(bvh.objects, np.int64), box[0], box[1],
                           int(bvh.depth), np.asarray(vertices, np.float32).astype(np.float64),
                           np.asarray(faces, np.int64), np.asarray(origins, np.float32).astype(np.float64),
                           np.asarray(directions, np.float32).astype(np.float64), float(tmin),
                           float(tmax), bool(any_hit))
