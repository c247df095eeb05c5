/* rt_bvh_wide.h - 4-wide BVH traversal: the library's fast path beyond the paper (rtlab.trace and
 * renders with traversal "bvh4"). The binary BVH of rt_bvh.h collapsed to four children a node
 * (rtlab/accel/bvh_wide.py): one node fetch tests four boxes, so a ray's chain of dependent fetches
 * is about half as long. On a GPU without ray-tracing cores that chain's latency, not arithmetic,
 * bounds a closest-hit query (Ylitie, Karras & Laine, "Efficient incoherent ray traversal on GPUs
 * through compressed wide BVHs", HPG 2017, make the same argument for 8-wide nodes).
 *
 * Node layout in node_data, BVH_WIDE_ROWS float4 = 112 B per node (sync with rtlab/accel/bvh_wide.py):
 *   [7 i + 0..5] = lo.x, hi.x, lo.y, hi.y, lo.z, hi.z of children 0..3, one float4 a component
 *   [7 i + 6]    = child refs 0..3 (int bits): >= 0 an inner node, BVH_WIDE_EMPTY no child,
 *                  otherwise a leaf with its triangles inline, exactly as in rt_bvh.h
 * The hit children are sorted by entry distance (a five-step network in registers); the nearest is
 * taken, the others pushed farthest first with their distances, so a pop skips what lies behind
 * the closest hit. RT_STACK_SIZE is 3 x depth + 1 (AccelArrays.stack_size): it cannot overflow.
 */
#ifndef RT_BVH_WIDE_H
#define RT_BVH_WIDE_H
#include "rt_bvh.h"

#define BVH_WIDE_ROWS 7
#define BVH_WIDE_EMPTY (-2147483647 - 1)
#define BVH_WIDE_FAR 3.402823466e38f      /* FLT_MAX: a hit child's key stays below an empty one's */

/* Child slot k of a node: its entry distance *t (RT_INF when it is empty or missed), its ref. */
RT_FN void bvh_wide_child(const Ray *ray, float3 inv, float3 o_inv, float lx, float hx, float ly, float hy,
                          float lz, float hz, int r, float t_hit, float *t, int *ref)
{
    float e;
    *ref = r;
    *t = RT_INF;
    if (r != BVH_WIDE_EMPTY && hit_bvh_child(ray, inv, o_inv, f4(lx, ly, lz, 0.0f), f4(hx, hy, hz, 0.0f), t_hit, &e))
        *t = rt_min(e, BVH_WIDE_FAR);
}

/* Order two (distance, ref) pairs. */
RT_FN void bvh_wide_order(float *ta, int *ra, float *tb, int *rb)
{
    if (*tb < *ta) {
        float t = *ta;
        int r = *ra;
        *ta = *tb;
        *ra = *rb;
        *tb = t;
        *rb = r;
    }
}

/* 4-wide BVH traversal. Closest hit, or with any_hit the first hit found. */
RT_FN void traverse_bvh4(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray, Hit *hit,
                         int any_hit)
{
    float t_enter, t_exit;
    if (!clip_ray_box(ray, scene_min, scene_max, &t_enter, &t_exit))
        return;
    float3 inv = f3(bvh_inverse(ray->d.x), bvh_inverse(ray->d.y), bvh_inverse(ray->d.z));
    float3 o_inv = hadamard3(ray->o, inv);
    BvhStackEntry stack[RT_STACK_SIZE];
    int sp = 0;
    int ref = 0;
    for (;;) {
        /* Inner nodes: the nearest hit child next, the other hit children on the stack */
        while (ref >= 0) {
            int base = BVH_WIDE_ROWS * ref;
            float4 lx = load_node_data(base), hx = load_node_data(base + 1);
            float4 ly = load_node_data(base + 2), hy = load_node_data(base + 3);
            float4 lz = load_node_data(base + 4), hz = load_node_data(base + 5);
            float4 refs = load_node_data(base + 6);
            float t0, t1, t2, t3;
            int r0, r1, r2, r3;
            bvh_wide_child(ray, inv, o_inv, lx.x, hx.x, ly.x, hy.x, lz.x, hz.x, rt_as_int(refs.x), hit->t, &t0, &r0);
            bvh_wide_child(ray, inv, o_inv, lx.y, hx.y, ly.y, hy.y, lz.y, hz.y, rt_as_int(refs.y), hit->t, &t1, &r1);
            bvh_wide_child(ray, inv, o_inv, lx.z, hx.z, ly.z, hy.z, lz.z, hz.z, rt_as_int(refs.z), hit->t, &t2, &r2);
            bvh_wide_child(ray, inv, o_inv, lx.w, hx.w, ly.w, hy.w, lz.w, hz.w, rt_as_int(refs.w), hit->t, &t3, &r3);
            bvh_wide_order(&t0, &r0, &t1, &r1);
            bvh_wide_order(&t2, &r2, &t3, &r3);
            bvh_wide_order(&t0, &r0, &t2, &r2);
            bvh_wide_order(&t1, &r1, &t3, &r3);
            bvh_wide_order(&t1, &r1, &t2, &r2);
            if (t0 == RT_INF) {
                if (!bvh_pop(stack, &sp, hit->t, &ref))
                    return;
                continue;
            }
            if (t3 != RT_INF) {
                stack[sp].ref = r3;
                stack[sp].t = t3;
                ++sp;
            }
            if (t2 != RT_INF) {
                stack[sp].ref = r2;
                stack[sp].t = t2;
                ++sp;
            }
            if (t1 != RT_INF) {
                stack[sp].ref = r1;
                stack[sp].t = t1;
                ++sp;
            }
            ref = r0;
        }
        /* A leaf, then the next subtree not behind the closest hit */
        if (intersect_bvh_leaf(RT_SCENE_ARGS, ref, ray, hit, any_hit) || !bvh_pop(stack, &sp, hit->t, &ref))
            return;
    }
}

#endif /* RT_BVH_WIDE_H */
