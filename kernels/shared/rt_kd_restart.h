/* rt_kd_restart.h - kd-restart (Foley & Sugerman 2005; the paper's §3.1.2, Table 4): no stack.
 * After each leaf the ray restarts at the root with tmin = the leaf's exit distance.
 *
 * Helpers here are shared by the stackless traversals (restart, short stack, ropes).
 *
 * Hazard 1 - cells the ray touches only at one distance T: flat cells (the builder cuts zero-width
 * slabs around planar triangles) and cells met exactly at an edge or corner. The textbook restart
 * ("a split at or before tmin: far child") steps over them and loses the triangles of flat cells;
 * "a split at tmin: near child" comes back to the leaf just done and loops forever. The leaves
 * touching T come in the tree's front-to-back order, and a descent at tmin = T reaches them
 * through the splits lying exactly at T ("ties"): near or far at each tie, in path order. So the
 * descent carries the choices as bits (KdSegment.ties, 0 = near) and the next restart takes the
 * successor, as an odometer does: the deepest near tie turns far, deeper ties go near again. A
 * leaf ending after T was reached near at every tie at its exit distance, so the restart there
 * starts at the successor of "all near" (KdSegment.n_exit counts those ties). Every leaf the
 * stack traversal visits is visited once, in the same order.
 *
 * Hazard 2 - rays lying in a split plane (kd_children's case 3, e.g. axis-aligned rays on a wall's
 * coordinate). Such a ray is in both children over its whole segment, and a triangle touching the
 * plane from one side only sits in that side's cell alone (rtlab/accel/kdtree.py), so the stack
 * traversal visits both. A stackless traversal cannot come back for the second child. Instead it
 * makes one pass per side: bit a of `side` says whether a ray lying in a split plane of axis a
 * takes the lower or the upper child in this pass; `planes` collects the axes where that choice
 * came up. A ray lies in split planes of at most two axes (d != 0), so at most 4 passes, and only
 * for those rays; every other ray makes exactly one pass.
 */
#ifndef RT_KD_RESTART_H
#define RT_KD_RESTART_H
#include "rt_kdtree.h"

typedef rt_u64 kd_ties_t;
/* One bit per tie on a root-to-leaf path: at most the tree depth, RT_STACK_SIZE - 1 */
#if RT_STACK_SIZE > 64 && (RT_TRAVERSAL == RT_TRAVERSAL_RESTART || RT_TRAVERSAL == RT_TRAVERSAL_SHORTSTACK \
                           || RT_TRAVERSAL == RT_TRAVERSAL_ROPES)
#error "the stackless kd traversals keep one bit per tree level in 64 bits: tree deeper than 63 levels"
#endif

/* Where a stackless descent is: the segment [tmin, tmax] of the current cell; ties: the choice at
 * the i-th split lying exactly at tmin on the path (bit i, 1 = far), n_ties of them so far;
 * n_exit: splits on the path lying exactly at tmax (each taken near); known: whether ties holds
 * every tie from the root (a short-stack entry may not know the ties above it, see below). */
typedef struct {
    float tmin, tmax;
    kd_ties_t ties;
    int n_ties, n_exit, known;
} KdSegment;

RT_FN KdSegment kd_segment(float tmin, float tmax)
{
    KdSegment s;
    s.tmin = tmin;
    s.tmax = tmax;
    s.ties = 0;
    s.n_ties = 0;
    s.n_exit = 0;
    s.known = 1;
    return s;
}

/* One descent step of a stackless kd traversal at interior node n. Returns the child to enter
 * and updates *seg to its segment. When the segment also goes on into the other child, *far is
 * that child and *far_seg its segment (a short stack pushes it), else *far = -1. */
RT_FN int kd_child_restart(int2 n, const Ray *ray, KdSegment *seg, int side, int *planes, int *far,
                           KdSegment *far_seg)
{
    int first, second;
    float t_split;
    int visit = kd_children(n, ray, seg->tmin, seg->tmax, &first, &second, &t_split);
    *far = -1;
    if (visit == 3) {
        /* Ray in the split plane: case 3 orders the lower child first; the pass picks the side */
        int axis = n.x & 3;
        *planes |= 1 << axis;
        return ((side >> axis) & 1) ? second : first;
    }
    if (visit == 1)
        return first;
    /* With RT_CONSERVATIVE kd_children also reports splits just outside the segment: they count
     * as lying on its end (exact mode: a no-op) */
    t_split = rt_min(rt_max(t_split, seg->tmin), seg->tmax);
    KdSegment rest = *seg;
    if (t_split == seg->tmin) {
        /* A tie: this restart's choice bit decides; the far side keeps the choices so far */
        kd_ties_t bit = (kd_ties_t)1 << seg->n_ties;
        int take_far = (seg->ties & bit) != 0;
        seg->n_ties += 1;
        rest.ties = (seg->ties & (bit - 1)) | bit;
        rest.n_ties = seg->n_ties;
        if (take_far)
            return second;
    } else {
        /* The far side starts at t_split: a tie there, after the n_exit ties at tmax == t_split.
         * Padded splits (RT_CONSERVATIVE) can make more ties for a restart at t_split than this
         * path met, so there the far side's ties are left unknown. */
        rest.tmin = t_split;
        rest.n_ties = (t_split == seg->tmax ? seg->n_exit : 0) + 1;
        rest.ties = (kd_ties_t)1 << (rest.n_ties - 1);
        rest.known = !RT_CONSERVATIVE;
    }
    if (t_split < seg->tmax) {
        seg->tmax = t_split;
        seg->n_exit = 1;
    } else {
        seg->n_exit += 1;
    }
    *far = second;
    *far_seg = rest;
    return first;
}

/* After a leaf: the segment the next restart from the root descends with, or 0 when the ray's
 * segment (up to t_exit) is used up. */
RT_FN int kd_next_restart(KdSegment *seg, float t_exit)
{
    if (seg->tmax >= t_exit)
        return 0;
    if (seg->tmax > seg->tmin) {
        /* Successor of "near at every tie at tmax": the deepest of them turns far. Padded splits
         * (RT_CONSERVATIVE) can add ties at tmax this path did not meet: start at the first. */
        seg->tmin = seg->tmax;
#if RT_CONSERVATIVE
        seg->ties = 0;
#else
        seg->ties = seg->n_exit > 0 ? (kd_ties_t)1 << (seg->n_exit - 1) : 0;
#endif
    } else if (!seg->known) {
        /* Ties above a short-stack entry unknown: walk the leaves at tmin again from the first */
        seg->ties = 0;
    } else {
        /* A cell touched only at tmin: the odometer's successor of this path's choices */
        int j = seg->n_ties - 1;
        while (j >= 0 && ((seg->ties >> j) & 1))
            --j;
        if (j < 0)
            return 0;   /* unreachable: a tie taken near made tmax == tmin */
        kd_ties_t bit = (kd_ties_t)1 << j;
        seg->ties = (seg->ties & (bit - 1)) | bit;
    }
    seg->tmax = t_exit;
    seg->n_ties = 0;
    seg->n_exit = 0;
    seg->known = 1;
    return 1;
}

/* Whether pass `side` is needed: only sides of split planes the ray was seen to lie in. Passes run
 * in increasing order, so a plane first met in a pass is still ahead for every side it adds. */
RT_FN int kd_pass_needed(int side, int planes) { return (side & ~planes) == 0; }

/* kd-restart: every leaf is reached by a fresh descent from the root over [tmin, t_exit], tmin
 * advancing to the previous leaf's exit. Closest hit, or with any_hit the first hit found. */
RT_FN void traverse_kd_restart(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray,
                               Hit *hit, int any_hit)
{
    /* BEGIN SOLUTION */
    float t_enter, t_exit;
    if (!clip_ray_box(ray, scene_min, scene_max, &t_enter, &t_exit))
        return;
    int planes = 0;
    for (int side = 0; side < 8; ++side) {
        if (!kd_pass_needed(side, planes))
            continue;
        KdSegment seg = kd_segment(t_enter, t_exit);
        /* Restart from the root until the segment is used up or a hit lies inside the current
         * cell, by more than the rounding pad t_cull (a hit on its exit face may tie with a
         * lower-id triangle in the next) */
        while (seg.tmin <= t_cull(hit->t)) {
            int2 n = load_node(nodes, 0);
            while (!kd_is_leaf(n)) {
                int far;
                KdSegment far_seg;
                n = load_node(nodes, kd_child_restart(n, ray, &seg, side, &planes, &far, &far_seg));
            }
            intersect_leaf(RT_SCENE_ARGS, n, ray, hit, any_hit);
            if (any_hit && hit->tri >= 0)
                return;
            if (t_cull(hit->t) < seg.tmax || !kd_next_restart(&seg, t_exit))
                break;
        }
    }
    /* END SOLUTION */
}

#endif /* RT_KD_RESTART_H */
