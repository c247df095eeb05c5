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

/* The inverse direction the fused box test uses (Aila & Laine): a zero component is replaced by
 * 2^-64 of its sign, so the inverse stays finite and b inv - o inv keeps the sign of b - o (times
 * a power of two, exactly) for rays that lie in a box's plane; an infinite inverse would give
 * inf - inf there. Coordinates up to 1e19 keep o inv finite. */
#define RT_BVH_MIN_DIR 5.421010862e-20f    /* 2^-64 */

RT_FN float bvh_inverse(float d)
{
    return 1.0f / (rt_abs(d) > RT_BVH_MIN_DIR ? d : (d < 0.0f || 1.0f / d < 0.0f ? -RT_BVH_MIN_DIR : RT_BVH_MIN_DIR));
}

/* Whether the ray's segment meets the child box [lo, hi] before the closest hit so far; its entry
 * distance in *t_enter. Inclusive at hit->t: rounding of the box test must not cut a tie. The ray
 * passed the scene box's clip_ray_box, so it can enter boxes: no per-box check of that. With
 * RT_BVH_BOX_FMA (and not RT_CONSERVATIVE) the slabs take Aila & Laine's fused form, a quarter
 * fewer instructions a box, with inv = bvh_inverse(d) and o_inv = o * inv computed once a ray:
 * 11 % off a SPONZA Whitted frame on the H100. Its rounding grows with |o|, so scenes far from the
 * origin keep the exact form. */
#ifndef RT_BVH_BOX_FMA             /* 1: the fused slab form; the loader sets it for scenes near the */
#define RT_BVH_BOX_FMA 0           /* origin (rtlab.device_scene.near_origin), where it costs no leaks */
#endif
RT_FN int hit_bvh_child(const Ray *ray, float3 inv, float3 o_inv, float4 lo, float4 hi, float t_hit, float *t_enter)
{
#if RT_CONSERVATIVE || !RT_BVH_BOX_FMA
    float t_exit;
    return clip_entering_ray_box(ray, lo, hi, t_enter, &t_exit) && *t_enter <= t_hit;
#else
    float t0 = ray->tmin, t1 = ray->tmax;
    clip_slab_fma(lo.x, hi.x, o_inv.x, inv.x, &t0, &t1);
    clip_slab_fma(lo.y, hi.y, o_inv.y, inv.y, &t0, &t1);
    clip_slab_fma(lo.z, hi.z, o_inv.z, inv.z, &t0, &t1);
    *t_enter = t0;
    return t0 <= t1 && t0 <= t_hit;
#endif
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
    float3 inv = f3(bvh_inverse(ray->d.x), bvh_inverse(ray->d.y), bvh_inverse(ray->d.z));
    float3 o_inv = hadamard3(ray->o, inv);
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
            int hit0 = hit_bvh_child(ray, inv, o_inv, f4(a.x, a.z, z.x, 0.0f), f4(a.y, a.w, z.y, 0.0f), hit->t, &e0);
            int hit1 = hit_bvh_child(ray, inv, o_inv, f4(b.x, b.z, z.z, 0.0f), f4(b.y, b.w, z.w, 0.0f), hit->t, &e1);
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
