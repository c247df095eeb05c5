/* rt_kdtree.h - kd-tree traversal (§3.1.2, Table 4).
 * Node encoding (sync with rtlab/accel/kdtree.py): int2 per node;
 *   interior: x = (left_child << 2) | axis, right child = left_child + 1;  y = split (float bits)
 *   leaf:     x = (n_triangles << 2) | 3;                                   y = first object index
 * The builder puts a triangle touching a split plane into both children, so the traversal below
 * only needs inclusive [tmin, tmax] cell ranges. */
#ifndef RT_KDTREE_H
#define RT_KDTREE_H
#include "rt_intersect.h"
#include "rt_memory.h"

#define KD_LEAF 3

RT_FN int kd_is_leaf(int2 n) { return (n.x & 3) == KD_LEAF; }

/* Intersect the triangles of a leaf; keeps the nearest in *hit. An any-hit query (shadow rays)
 * stops at the first. */
RT_FN void intersect_leaf(RT_SCENE_PARAMS, int2 leaf, const Ray *ray, Hit *hit, int any_hit)
{
    int count = leaf.x >> 2;
    for (int i = 0; i < count; ++i) {
        if (intersect_tri(RT_SCENE_ARGS, ray, load_object(objects, leaf.y + i), hit) && any_hit)
            return;
    }
}

/* Choose the children of interior node n for the ray segment [tmin, tmax] (front-to-back order
 * as in pbrt). Returns 1: visit *first only; 2: *first on [tmin, *t_split], then *second on
 * [*t_split, tmax]; 3: the ray lies in the split plane, both children on [tmin, tmax].
 * With RT_CONSERVATIVE a child is skipped only when t_split is beyond the segment by more than the
 * rounding bound RT_T_PAD of the plane distances compared (Ize 2013 applied to kd split planes):
 * within the bound both children are visited, so rounding cannot cull a cell the exact ray crosses.
 * The sign of ts is exact (the subtraction is zero only when o == split), so ts <= 0 needs no pad. */
RT_FN int kd_children(int2 n, const Ray *ray, float tmin, float tmax, int *first, int *second,
                      float *t_split)
{
    int axis = n.x & 3;
    int left = n.x >> 2;
    float split = rt_as_float(n.y);
    float o = get3(ray->o, axis);
    float ts = (split - o) * get3(ray->inv_d, axis);
    int below_first = (o < split) || (o == split && get3(ray->d, axis) <= 0.0f);
    *first = below_first ? left : left + 1;
    *second = below_first ? left + 1 : left;
    if (ts != ts) {
        /* 0 * inf: the ray lies in the split plane, so in both cells over the whole segment */
        *t_split = tmax;
        return 3;
    }
    *t_split = ts;
#if RT_CONSERVATIVE
    float ts_lo = ts * (1.0f - RT_T_PAD), ts_hi = ts * (1.0f + RT_T_PAD);
#else
    float ts_lo = ts, ts_hi = ts;
#endif
    if (ts_lo > tmax || ts <= 0.0f)
        return 1;
    if (ts_hi < tmin) {
        *first = *second;
        return 1;
    }
    return 2;
}

/* t_stop: the smallest tmin of this entry and all below it. Entries pushed by a front-to-back split
 * get decreasing tmin toward the top, but a ray lying in a split plane pushes its sibling with the
 * current tmin, so the top is not always the nearest pending cell. */
typedef struct {
    int node;
    float tmin, tmax, t_stop;
} KdStackEntry;

/* Single ray with a per-thread stack of far children (the paper's fastest, Table 4). Closest hit,
 * or with any_hit (a compile-time constant after inlining) the first hit found, for shadow rays.
 * RT_STACK_SIZE is the tree depth + 1, set by the loader, so the stack cannot overflow. */
RT_FN void traverse_kd_stack(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray,
                             Hit *hit, int any_hit)
{
    /* BEGIN SOLUTION */
    float tmin, tmax;
    if (!clip_ray_box(ray, scene_min, scene_max, &tmin, &tmax))
        return;
    KdStackEntry stack[RT_STACK_SIZE];
    int sp = 0;
    int node = 0;
    for (;;) {
        int2 n = load_node(nodes, node);
        /* Descend to a leaf, pushing the far child when the segment crosses the split */
        while (!kd_is_leaf(n)) {
            int first, second;
            float t_split;
            int visit = kd_children(n, ray, tmin, tmax, &first, &second, &t_split);
            if (visit >= 2) {
                float entry_tmin = visit == 3 ? tmin : t_split;
                stack[sp].node = second;
                stack[sp].tmin = entry_tmin;
                stack[sp].tmax = tmax;
                stack[sp].t_stop = sp > 0 ? rt_min(entry_tmin, stack[sp - 1].t_stop) : entry_tmin;
                ++sp;
                tmax = t_split;
            }
            node = first;
            n = load_node(nodes, node);
        }
        intersect_leaf(RT_SCENE_ARGS, n, ray, hit, any_hit);
        /* Done when no pending cell starts before or at the hit, up to the rounding pad t_cull
         * (one starting at it may hold a lower-id triangle at the same t): the stack holds every
         * unvisited cell the ray crosses */
        if (sp == 0 || t_cull(hit->t) < stack[sp - 1].t_stop || (any_hit && hit->tri >= 0))
            return;
        --sp;
        node = stack[sp].node;
        tmin = stack[sp].tmin;
        tmax = stack[sp].tmax;
    }
    /* END SOLUTION */
}

#endif /* RT_KDTREE_H */
