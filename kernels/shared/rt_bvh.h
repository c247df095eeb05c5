/* rt_bvh.h - BVH traversal (the paper's future work, §5): a binned-SAH BVH (rtlab/accel/bvh.py)
 * walked in the style of Aila & Laine, "Understanding the efficiency of ray traversal on GPUs"
 * (HPG 2009): both child boxes in one node, the nearer child first, the farther on a per-thread
 * stack, a while-while loop (descend through inner nodes until a leaf, then test its triangles).
 *
 * Node layout in node_data, 4 float4 = 64 B per node (Aila & Laine's; sync with rtlab/accel/bvh.py):
 *   [4 i + 0] = (c0.lo.x, c0.hi.x, c0.lo.y, c0.hi.y)
 *   [4 i + 1] = (c1.lo.x, c1.hi.x, c1.lo.y, c1.hi.y)
 *   [4 i + 2] = (c0.lo.z, c0.hi.z, c1.lo.z, c1.hi.z)
 *   [4 i + 3] = (ref c0, ref c1, 0, 0)   int bits
 * A child ref >= 0 is an inner node index; a leaf is ~((first << BVH_LEAF_BITS) | count): count
 * triangles from objects[first]. The root is node 0 and always inner (the builder gives a
 * one-leaf tree a second, duplicate leaf). RT_STACK_SIZE is the BVH depth + 1 (set by the loader
 * from AccelArrays.stack_size), so the stack cannot overflow.
 */
#ifndef RT_BVH_H
#define RT_BVH_H
#include "rt_intersect.h"
#include "rt_memory.h"

#define BVH_LEAF_BITS 4            /* at most 15 triangles a leaf (sync with rtlab/accel/bvh.py) */
#define BVH_NODE_STRIDE 4

/* Whether the ray's segment meets the child box [lo, hi] before the closest hit so far; its entry
 * distance in *t_enter. Inclusive at hit->t: rounding of the box test must not cut a tie. */
RT_FN int hit_bvh_child(const Ray *ray, float4 lo, float4 hi, float t_hit, float *t_enter)
{
    float t_exit;
    return clip_ray_box(ray, lo, hi, t_enter, &t_exit) && *t_enter <= t_hit;
}

/* Test the triangles of leaf ref `leaf`; returns 1 when an any-hit query may stop. */
RT_FN int intersect_bvh_leaf(RT_SCENE_PARAMS, int leaf, const Ray *ray, Hit *hit, int any_hit)
{
    int bits = ~leaf;
    int first = bits >> BVH_LEAF_BITS;
    int count = bits & ((1 << BVH_LEAF_BITS) - 1);
    for (int i = 0; i < count; ++i) {
        if (intersect_tri(RT_SCENE_ARGS, ray, load_object(first + i), hit) && any_hit)
            return 1;
    }
    return 0;
}

/* BVH traversal. Closest hit, or with any_hit the first hit found. */
RT_FN void traverse_bvh(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray, Hit *hit,
                        int any_hit)
{
    /* BEGIN SOLUTION */
    float t_enter, t_exit;
    if (!clip_ray_box(ray, scene_min, scene_max, &t_enter, &t_exit))
        return;
    int stack[RT_STACK_SIZE];
    int sp = 0;
    int ref = 0;
    for (;;) {
        /* Inner nodes: take the nearer child hit, push the farther; pop when neither is hit */
        while (ref >= 0) {
            int base = BVH_NODE_STRIDE * ref;
            float4 a = load_node_data(base);
            float4 b = load_node_data(base + 1);
            float4 z = load_node_data(base + 2);
            float4 c = load_node_data(base + 3);
            float e0, e1;
            int hit0 = hit_bvh_child(ray, f4(a.x, a.z, z.x, 0.0f), f4(a.y, a.w, z.y, 0.0f), hit->t, &e0);
            int hit1 = hit_bvh_child(ray, f4(b.x, b.z, z.z, 0.0f), f4(b.y, b.w, z.w, 0.0f), hit->t, &e1);
            int c0 = rt_as_int(c.x), c1 = rt_as_int(c.y);
            if (hit0 && hit1) {
                int near0 = e0 <= e1;
                stack[sp++] = near0 ? c1 : c0;
                ref = near0 ? c0 : c1;
            } else if (hit0 || hit1) {
                ref = hit0 ? c0 : c1;
            } else {
                if (sp == 0)
                    return;
                ref = stack[--sp];
            }
        }
        /* A leaf */
        if (intersect_bvh_leaf(RT_SCENE_ARGS, ref, ray, hit, any_hit))
            return;
        if (sp == 0)
            return;
        ref = stack[--sp];
    }
    /* END SOLUTION */
}

#endif /* RT_BVH_H */
