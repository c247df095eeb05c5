/* rt_kd_ropes.h - stackless kd traversal with ropes (Popov, Guenther, Seidel & Slusallek 2007; the
 * paper's §3.1.2, Table 4). Each leaf knows its box and, per face, a rope: the node on the other
 * side whose box covers that face (rtlab/accel/ropes.py builds them, pushed down the tree as far
 * as the face stays covered: Popov's rope optimisation). After a leaf the ray leaves through the
 * face of its exit distance, follows that face's rope and descends from there to the leaf holding
 * the exit point. A flat cell (touched at one distance only) is entered and left through its faces
 * like any other cell.
 *
 * Hazard - leaving through an edge or a corner: the exit point lies in cells across several faces
 * and one rope reaches only some of them (a diagonal cell touched only at the point is skipped, and
 * with it a triangle through that point: rays through mesh vertices leak). The exit point lies on an
 * edge of the exit face also where the ray entered the leaf through that edge (a leaf touched at the
 * exit point alone, e.g. where the ray enters the scene box through an edge: the descent's segment
 * starts in the box's padding, before the leaf's box, and the rope, pushed down past splits on the
 * box's faces, misses the flat cells there); exit_leaf_box reports both. There, and where the ray
 * starts, the leaves touching that distance come from the root in tree order as in kd-restart
 * (rt_kd_restart.h, KdSegment), up to the last of the face distances tied with it (with
 * RT_CONSERVATIVE they may differ by an ulp or so, and the cell across both faces is met at the
 * later one); the first leaf beyond goes on by rope. Rays lying in split planes take
 * the side passes of rt_kd_restart.h.
 *
 * Leaf record in node_data, 4 float4 = 64 B per leaf (sync with rtlab/accel/ropes.py). In the rope
 * tree a leaf node's y is its record index instead of its first object (the only change to the kd
 * node encoding); ropes are int bits: a node index, or -1 on the scene boundary.
 *   [4 L + 0] = (box min x, y, z, rope -x)
 *   [4 L + 1] = (box max x, y, z, rope +x)
 *   [4 L + 2] = (rope -y, rope +y, rope -z, rope +z)
 *   [4 L + 3] = (first object index, 0, 0, 0)
 */
#ifndef RT_KD_ROPES_H
#define RT_KD_ROPES_H
#include "rt_kd_restart.h"

#define KD_ROPES_LEAF_STRIDE 4

/* Child of interior node n holding the point at tmin (the descent after following a rope): the
 * near child of kd_children, so cells touched only at tmin (flat cells) are entered and left
 * through their faces like any other; a ray lying in the split plane takes this pass's side. */
RT_FN int kd_child_rope(int2 n, const Ray *ray, float tmin, float tmax, int side, int *planes)
{
    int first, second;
    float t_split;
    if (kd_children(n, ray, tmin, tmax, &first, &second, &t_split) == 3) {
        int axis = n.x & 3;
        *planes |= 1 << axis;
        return ((side >> axis) & 1) ? second : first;
    }
    return first;
}

/* The kd leaf (count word, first object) that intersect_leaf() reads */
RT_FN int2 kd_leaf_objects(int word, int first)
{
    int2 leaf;
    leaf.x = word;
    leaf.y = first;
    return leaf;
}

/* Largest exit distance that ties with the exit distance t: t exactly, or with RT_CONSERVATIVE up
 * to the rounding bound of two plane distances (rt_intersect.h) */
RT_FN float exit_tie_bound(float t)
{
#if RT_CONSERVATIVE
    return t + rt_abs(t) * (2.0f * RT_T_PAD);
#else
    return t;
#endif
}

/* Smallest entry distance that ties with the exit distance t: t exactly, or with RT_CONSERVATIVE
 * down to the rounding bound of two plane distances (the mirror of exit_tie_bound) */
RT_FN float entry_tie_bound(float t)
{
#if RT_CONSERVATIVE
    return t - rt_abs(t) * (2.0f * RT_T_PAD);
#else
    return t;
#endif
}

/* Distance at which the ray leaves the box [lo, hi], the face it leaves through as a rope slot
 * (2 axis for the lower face, 2 axis + 1 for the upper), and in *t_corner, when the exit point
 * lies on an edge or corner of the box, the largest distance of the tie, else -inf. The exit point
 * is on an edge when another face's exit distance ties with t (the ray leaves through the edge), or
 * when another axis's entry distance does (the ray enters that axis's slab only at t: the box is
 * touched at the exit point alone, e.g. entered through an edge; in the padding around the scene
 * box, where the descent's segments start before the leaf's box, an entry after t: the box is
 * not touched at all). Either way cells the exit face's rope does not reach hold the exit point.
 * Axes along which the ray does not move are never entered or left (their slab distance would be
 * 0 * inf = NaN on the face).
 * Hazard: tied distances need not be equal (tx one ulp before ty): the ray may cross the edge
 * anywhere in [t, *t_corner], so the cells across it touch that range, not t alone. */
RT_FN float exit_leaf_box(const Ray *ray, float4 lo, float4 hi, int *face, float *t_corner)
{
    float tx = ray->d.x != 0.0f ? ((ray->d.x > 0.0f ? hi.x : lo.x) - ray->o.x) * ray->inv_d.x : RT_INF;
    float ty = ray->d.y != 0.0f ? ((ray->d.y > 0.0f ? hi.y : lo.y) - ray->o.y) * ray->inv_d.y : RT_INF;
    float tz = ray->d.z != 0.0f ? ((ray->d.z > 0.0f ? hi.z : lo.z) - ray->o.z) * ray->inv_d.z : RT_INF;
    float t = rt_min(tx, rt_min(ty, tz));
    int axis = tx == t ? 0 : (ty == t ? 1 : 2);
    *face = 2 * axis + (get3(ray->d, axis) > 0.0f);
    float bound = exit_tie_bound(t);
    int tied = (tx <= bound) + (ty <= bound) + (tz <= bound);
    float t_far = rt_max(tx <= bound ? tx : t, rt_max(ty <= bound ? ty : t, tz <= bound ? tz : t));
    /* Latest entry distance of the other axes (the exit axis's own entry ties with t only in a
     * flat cell, left through its face like any other) */
    float ex = ray->d.x != 0.0f && axis != 0 ? ((ray->d.x > 0.0f ? lo.x : hi.x) - ray->o.x) * ray->inv_d.x : -RT_INF;
    float ey = ray->d.y != 0.0f && axis != 1 ? ((ray->d.y > 0.0f ? lo.y : hi.y) - ray->o.y) * ray->inv_d.y : -RT_INF;
    float ez = ray->d.z != 0.0f && axis != 2 ? ((ray->d.z > 0.0f ? lo.z : hi.z) - ray->o.z) * ray->inv_d.z : -RT_INF;
    float t_entry = rt_max(ex, rt_max(ey, ez));
    int entered_at_edge = t_entry >= entry_tie_bound(t);
    *t_corner = tied > 1 || entered_at_edge ? rt_max(t_far, t_entry) : -RT_INF;
    return t;
}

/* The rope of face slot `face` of a leaf record (words laid out as above) */
RT_FN int rope_of_face(float4 lo, float4 hi, float4 ropes, int face)
{
    float bits = face == 0 ? lo.w : face == 1 ? hi.w : face == 2 ? ropes.x
               : face == 3 ? ropes.y : face == 4 ? ropes.z : ropes.w;
    return face < 0 ? -1 : rt_as_int(bits);
}

/* Ropes traversal. Closest hit, or with any_hit the first hit found. */
RT_FN void traverse_kd_ropes(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray,
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
        /* Start with the leaves at t_enter, from the root */
        KdSegment seg = kd_segment(t_enter, t_exit);
        float tmin = t_enter, t_root = t_enter;
        int node = 0, from_root = 1;
        while (tmin <= t_cull(hit->t)) {
            /* Descend: from the root in kd-restart order, or from a rope's node to the exit point */
            int2 n = load_node(nodes, node);
            while (!kd_is_leaf(n)) {
                int far;
                KdSegment far_seg;
                node = from_root ? kd_child_restart(n, ray, &seg, side, &planes, &far, &far_seg)
                                 : kd_child_rope(n, ray, tmin, t_exit, side, &planes);
                n = load_node(nodes, node);
            }
            int record = KD_ROPES_LEAF_STRIDE * n.y;
            float4 lo = load_node_data(node_data, record);
            float4 hi = load_node_data(node_data, record + 1);
            float4 first = load_node_data(node_data, record + 3);
            intersect_leaf(RT_SCENE_ARGS, kd_leaf_objects(n.x, rt_as_int(first.x)), ray, hit, any_hit);
            if (any_hit && hit->tri >= 0)
                return;
            if (from_root && seg.tmax <= t_root) {
                /* A leaf ending by t_root (touched only at tmin, or inside an edge's tie range):
                 * the next leaf, from the root as in kd-restart */
                if (t_cull(hit->t) < seg.tmax || !kd_next_restart(&seg, t_exit))
                    break;
                node = 0;
                continue;
            }
            /* Leave through the exit face and follow its rope; through an edge or corner, take
             * the leaves touching its tie range [t_leave, t_corner] from the root (once per
             * range, so the walk moves on) */
            int face;
            float t_corner;
            float t_leave = exit_leaf_box(ray, lo, hi, &face, &t_corner);
            if (t_cull(hit->t) < t_leave || t_leave >= t_exit)
                break;
            tmin = rt_max(tmin, t_leave);
            from_root = t_corner >= t_leave && tmin > t_root;
            if (from_root) {
                seg = kd_segment(tmin, t_exit);
                t_root = rt_max(t_corner, tmin);
                node = 0;
            } else {
                node = rope_of_face(lo, hi, load_node_data(node_data, record + 2), face);
                if (node < 0)
                    break;
            }
        }
    }
    /* END SOLUTION */
}

#endif /* RT_KD_ROPES_H */
