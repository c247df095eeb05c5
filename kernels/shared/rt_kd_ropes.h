/* rt_kd_ropes.h - stackless kd traversal with ropes (Popov, Guenther, Seidel & Slusallek 2007; the
 * paper's §3.1.2, Table 4). Each leaf knows its box and, per face, a rope: the node on the other
 * side whose box covers that face (rtlab/accel/ropes.py builds them, pushed down the tree as far
 * as the face stays covered: Popov's rope optimisation). After a leaf the ray leaves through the
 * face of its exit distance, follows that face's rope and descends from there to the leaf holding
 * the exit point. Rays lying in split planes take the side passes of rt_kd_restart.h; a flat cell
 * (touched at one distance only) is entered and left through its faces like any other cell.
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

/* Distance at which the ray leaves the box [lo, hi], and the face it leaves through as a rope
 * slot (2 axis for the lower face, 2 axis + 1 for the upper). Axes along which the ray does not
 * move are never left (their slab distance would be 0 * inf = NaN on the face). */
RT_FN float exit_leaf_box(const Ray *ray, float4 lo, float4 hi, int *face)
{
    float t = RT_INF;
    *face = -1;
    if (ray->d.x != 0.0f) {
        float tx = ((ray->d.x > 0.0f ? hi.x : lo.x) - ray->o.x) * ray->inv_d.x;
        if (tx < t) {
            t = tx;
            *face = ray->d.x > 0.0f ? 1 : 0;
        }
    }
    if (ray->d.y != 0.0f) {
        float ty = ((ray->d.y > 0.0f ? hi.y : lo.y) - ray->o.y) * ray->inv_d.y;
        if (ty < t) {
            t = ty;
            *face = ray->d.y > 0.0f ? 3 : 2;
        }
    }
    if (ray->d.z != 0.0f) {
        float tz = ((ray->d.z > 0.0f ? hi.z : lo.z) - ray->o.z) * ray->inv_d.z;
        if (tz < t) {
            t = tz;
            *face = ray->d.z > 0.0f ? 5 : 4;
        }
    }
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
        float tmin = t_enter;
        int node = 0;
        while (node >= 0 && tmin < hit->t) {
            /* Descend from the rope's node to the leaf holding the point at tmin */
            int2 n = load_node(node);
            while (!kd_is_leaf(n))
                n = load_node(kd_child_rope(n, ray, tmin, t_exit, side, &planes));
            int record = KD_ROPES_LEAF_STRIDE * n.y;
            float4 lo = load_node_data(record);
            float4 hi = load_node_data(record + 1);
            float4 first = load_node_data(record + 3);
            intersect_leaf(RT_SCENE_ARGS, kd_leaf_objects(n.x, rt_as_int(first.x)), ray, hit, any_hit);
            if (any_hit && hit->tri >= 0)
                return;
            /* Leave through the exit face and follow its rope */
            int face;
            float t_leave = exit_leaf_box(ray, lo, hi, &face);
            if (hit->t <= t_leave || t_leave >= t_exit)
                break;
            node = rope_of_face(lo, hi, load_node_data(record + 2), face);
            tmin = rt_max(tmin, t_leave);
        }
    }
    /* END SOLUTION */
}

#endif /* RT_KD_ROPES_H */
