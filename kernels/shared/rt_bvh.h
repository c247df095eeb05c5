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

/* ---- The fused box test (RT_BVH_BOX_FMA; Aila & Laine 2009) ----------------------------------
 * A slab's plane distance (b - o) / d as one fused multiply-add, b inv - o inv, with inv = 1/d and
 * o inv computed once a ray: a quarter fewer instructions a box (its gain: docs/results.md). Three
 * hazards, all handled in the per-ray setup (bvh_ray) or once a box, so the box
 * test itself keeps one fma a plane:
 *  1. o inv is rounded (half an ulp of o / d), an error that grows with |o| and not with the
 *     distance: a box near an origin far from 0 (a 1e-3 sphere in a 1e5 room) could be culled.
 *     A near plane takes o inv rounded up by a bound of that error, a far plane rounded down, so
 *     the fused distances bracket the exact ones up to the rounding of inv and of the fma. Which of
 *     a slab's planes (lo, hi) is near depends on the sign of inv only, so the ray carries the
 *     offset of each (o_lo, o_hi) and the box test takes no per-plane select.
 *  2. A zero direction component (either sign) has no finite inverse. It gets 2^64 of its sign
 *     (RT_BVH_MIN_DIR), so b inv - o inv keeps the exact sign of b - o, and its pad is the ray's
 *     whole length in the scene box: a ray lying in the box's plane (b == o) or inside its slab is
 *     never cut, whichever sign its zero has; one outside the slab by more than a few ulps is.
 *  3. What is left is relative: inv's own rounding (up to 2.5 ulps in OpenCL C) and the fma's. With
 *     RT_CONSERVATIVE the exit distance is scaled by 1 + RT_T_PAD (16 ulps) before the comparison,
 *     so no box the exact test keeps is culled (the watertight default's guarantee, Ize 2013); one
 *     multiply a box where the exact form costs a subtraction a plane.
 * Coordinates up to 1e19 keep o inv finite. */
#define RT_BVH_MIN_DIR 5.421010862e-20f    /* 2^-64 */
#define RT_BVH_ULP_PAD 2.3841858e-7f       /* 2^-22: two ulps, o inv's rounding and the pad's own */

typedef struct {
    float3 inv;      /* 1/d, or +-2^64 where |d| <= RT_BVH_MIN_DIR */
    float3 o_lo;     /* o inv moved for the slab's lo plane: up where it is the near plane, down where far */
    float3 o_hi;     /* ... and for its hi plane */
    float tmin;      /* the ray's tmin, +0 for -0 (bvh_span_enter compares bit patterns) */
} BvhRay;

/* The inverse of direction component d for the fused form: 1/d, or 2^64 of d's sign (-0 too) */
RT_FN float bvh_inverse(float d)
{
    int negative = d < 0.0f || 1.0f / d < 0.0f;
    return rt_abs(d) > RT_BVH_MIN_DIR ? 1.0f / d : (negative ? -1.0f : 1.0f) / RT_BVH_MIN_DIR;
}

/* How far o inv = oi must move along one axis: its rounding bound, and for a zero component
 * (|d| <= RT_BVH_MIN_DIR) the ray's length t_pad as well */
RT_FN float bvh_origin_pad(float d, float oi, float t_pad)
{
    return rt_abs(oi) * RT_BVH_ULP_PAD + (rt_abs(d) > RT_BVH_MIN_DIR ? 0.0f : t_pad);
}

/* The per-ray constants of the fused box test for a ray whose segment in the scene box ends at
 * t_exit (the clip of the scene box, before the loop). */
RT_FN BvhRay bvh_ray(const Ray *ray, float t_exit)
{
    BvhRay r;
    float t_pad = 2.0f * t_exit;
    r.inv = f3(bvh_inverse(ray->d.x), bvh_inverse(ray->d.y), bvh_inverse(ray->d.z));
    float3 oi = hadamard3(ray->o, r.inv);
    float3 pad = f3(bvh_origin_pad(ray->d.x, oi.x, t_pad), bvh_origin_pad(ray->d.y, oi.y, t_pad),
                    bvh_origin_pad(ray->d.z, oi.z, t_pad));
    float3 o_near = add3(oi, pad), o_far = sub3(oi, pad);
    /* inv >= 0: lo is the near plane */
    r.o_lo = f3(r.inv.x >= 0.0f ? o_near.x : o_far.x, r.inv.y >= 0.0f ? o_near.y : o_far.y,
                r.inv.z >= 0.0f ? o_near.z : o_far.z);
    r.o_hi = f3(r.inv.x >= 0.0f ? o_far.x : o_near.x, r.inv.y >= 0.0f ? o_far.y : o_near.y,
                r.inv.z >= 0.0f ? o_far.z : o_near.z);
    r.tmin = ray->tmin > 0.0f ? ray->tmin : 0.0f;
    return r;
}

/* Entry and exit of the slabs by the float bit patterns as int32: one three-input integer
 * min/max instruction where the GPU has one (sm_90's VIMNMX3: ptxas fuses the pair) in place of two
 * float ones. The int order is the float order on values >= +0, and every negative float is below
 * every one of those. The entry includes tmin >= +0, so it is the true maximum. The exit is the
 * true minimum where that is >= +0, and negative where that is negative (the box is behind: culled
 * either way); -0 reads as below everything, which can only keep a box. */
RT_FN float bvh_max3(float a, float b, float c)
{
    return rt_as_float(rt_imax(rt_imax(rt_as_int(a), rt_as_int(b)), rt_as_int(c)));
}

RT_FN float bvh_min3(float a, float b, float c)
{
    return rt_as_float(rt_imin(rt_imin(rt_as_int(a), rt_as_int(b)), rt_as_int(c)));
}

RT_FN float bvh_span_enter(float a, float b, float c, float tmin)
{
    return rt_as_float(rt_imax(rt_as_int(bvh_max3(a, b, c)), rt_as_int(tmin)));
}

RT_FN float bvh_span_exit(float a, float b, float c, float t_hit)
{
    return rt_as_float(rt_imin(rt_as_int(bvh_min3(a, b, c)), rt_as_int(t_hit)));
}

/* Whether the ray's segment meets the child box [lo, hi] up to t_cut, t_cull of the closest hit so
 * far (inclusive: a box entered exactly at the hit may hold a lower-id triangle at the same t,
 * closer_hit, and both distances carry rounding); its entry distance in *t_enter. t_cut changes only
 * where a leaf finds a hit, so the walk pads it there, not at every node (hit_bvh_child pads it
 * itself). The ray passed the scene box's clip_ray_box, so it can enter boxes: no per-box check of
 * that. With RT_BVH_BOX_FMA the slabs take the fused form above, else the exact (b - o) * inv_d of
 * clip_entering_ray_box (scenes far from the origin). */
#ifndef RT_BVH_BOX_FMA             /* 1: the fused slab form; the loader sets it for scenes near the */
#define RT_BVH_BOX_FMA 0           /* origin (rtlab.device.device_scene.near_origin), where it costs no leaks */
#endif
#define RT_BVH_EXIT_SCALE (1.0f + RT_T_PAD)
RT_FN int hit_bvh_child_cut(const Ray *ray, const BvhRay *r, float4 lo, float4 hi, float t_cut, float *t_enter)
{
#if !RT_BVH_BOX_FMA
    float t_exit;
    return clip_entering_ray_box(ray, lo, hi, t_enter, &t_exit) && *t_enter <= t_cut;
#else
    float lx = rt_fma(lo.x, r->inv.x, -r->o_lo.x), hx = rt_fma(hi.x, r->inv.x, -r->o_hi.x);
    float ly = rt_fma(lo.y, r->inv.y, -r->o_lo.y), hy = rt_fma(hi.y, r->inv.y, -r->o_hi.y);
    float lz = rt_fma(lo.z, r->inv.z, -r->o_lo.z), hz = rt_fma(hi.z, r->inv.z, -r->o_hi.z);
    float t0 = bvh_span_enter(rt_min(lx, hx), rt_min(ly, hy), rt_min(lz, hz), r->tmin);
    float t1 = bvh_span_exit(rt_max(lx, hx), rt_max(ly, hy), rt_max(lz, hz), t_cut);
#if RT_CONSERVATIVE
    t1 *= RT_BVH_EXIT_SCALE;
#endif
    *t_enter = t0;
    return t0 <= t1;
#endif
}

/* The same, padding the closest hit's t itself (t_cull) */
RT_FN int hit_bvh_child(const Ray *ray, const BvhRay *r, float4 lo, float4 hi, float t_hit, float *t_enter)
{
    return hit_bvh_child_cut(ray, r, lo, hi, t_cull(t_hit), t_enter);
}

/* RT_BVH_LEAF_TRIS 1: tri_data holds the leaves' triangles in the order of objects, three float4 rows a
 * reference (v0 with the triangle id's bits in w, v1, v2; rtlab.accel.tri_data.leaf_tris), so a leaf
 * reads its vertices from consecutive rows, with no objects[] read between (a dependent load a
 * triangle, in a kernel bound by latency). The loader sets it for the tests that read vertices
 * (rtlab.device.kernels.leaf_tris); objects and tris stay valid for code that reads them. */
#ifndef RT_BVH_LEAF_TRIS
#define RT_BVH_LEAF_TRIS 0
#endif
#if RT_BVH_LEAF_TRIS && RT_ISECT != RT_ISECT_MOLLER && RT_ISECT != RT_ISECT_WATERTIGHT
#error "RT_BVH_LEAF_TRIS holds vertices: the Moller and watertight tests only"
#endif

/* Test the triangles of leaf ref `leaf`; returns 1 when an any-hit query may stop. */
RT_FN int intersect_bvh_leaf(RT_SCENE_PARAMS, int leaf, const Ray *ray, Hit *hit, int any_hit)
{
    int bits = ~leaf;
    int first = bits >> BVH_LEAF_BITS;
    int count = bits & ((1 << BVH_LEAF_BITS) - 1);
    for (int i = 0; i < count; ++i) {
#if RT_BVH_LEAF_TRIS
        int row = 3 * (first + i);
        float4 v0 = load_tri_data(tri_data, row);
        int hit_now = intersect_tri_vertices(ray, xyz(v0), xyz(load_tri_data(tri_data, row + 1)),
                                             xyz(load_tri_data(tri_data, row + 2)), rt_as_int(v0.w), hit);
#else
        int hit_now = intersect_tri(RT_SCENE_ARGS, ray, load_object(objects, first + i), hit);
#endif
        if (hit_now && any_hit)
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
    BvhRay fused = bvh_ray(ray, t_exit);
    int stack[RT_STACK_SIZE];
    int sp = 0;
    int ref = 0;
    float t_cut = t_cull(hit->t);      /* changes only where a leaf finds a hit */
    for (;;) {
        /* Inner nodes: take the nearer child hit, push the farther; pop when neither is hit */
        while (ref >= 0) {
            int base = BVH_NODE_STRIDE * ref;
            float4 a = load_node_data(node_data, base);
            float4 b = load_node_data(node_data, base + 1);
            float4 z = load_node_data(node_data, base + 2);
            float4 c = load_node_data(node_data, base + 3);
            float e0, e1;
            int hit0 = hit_bvh_child_cut(ray, &fused, f4(a.x, a.z, z.x, 0.0f), f4(a.y, a.w, z.y, 0.0f), t_cut, &e0);
            int hit1 = hit_bvh_child_cut(ray, &fused, f4(b.x, b.z, z.z, 0.0f), f4(b.y, b.w, z.w, 0.0f), t_cut, &e1);
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
        t_cut = t_cull(hit->t);
        if (sp == 0)
            return;
        ref = stack[--sp];
    }
    /* END SOLUTION */
}

/* ---- Rays fetched as lanes free up (Aila & Laine 2009, §4: persistent threads, "replacing
 * terminated rays") ----------------------------------------------------------------------------------
 * On incoherent rays a warp runs as long as its longest ray while the lanes of the short ones idle
 * (a quarter of the lanes busy on diffuse rays: docs/results.md, "Idle lanes"). Here a lane whose ray is done
 * takes the next ray of the launch from a counter (trace_rays_fetch, rt_entry_trace.h), and the
 * lanes still tracing stop after a leaf when fewer than RT_FETCH_THRESHOLD of them are left, so the
 * idle ones refill together. The walk is traverse_bvh's closest hit, its state kept across the
 * refills; the hits are trace_rays' bit for bit. It is traverse_bvh in another form, so a course
 * region (stubbed in student trees, where the library does not launch it). The host launches it for
 * rays in no image order on devices with warps (rtlab.device.tracing.fetches_rays); what it gains and
 * how the threshold was chosen: docs/results.md, "Rays fetched as lanes free up". */
#ifndef RT_FETCH_THRESHOLD
#define RT_FETCH_THRESHOLD 20
#endif
#define BVH_DONE 0x7fffffff                /* a lane's ref when its ray is done: above every inner node */

typedef struct {
    Ray ray;
    BvhRay fused;
    Hit hit;
    int ref;                               /* next node: inner >= 0, leaf < 0, BVH_DONE */
    int sp;
} BvhTrace;

/* Start a fetched walk (this one and rt_bvh4.h's): no hit, an empty stack, the root next, or ref
 * BVH_DONE at once where the ray misses the scene box; 1 and the scene box's exit in *t_exit where
 * the walk goes on (its per-ray constants are the caller's). */
RT_FN int bvh_walk_start(const Ray *ray, Hit *hit, int *ref, int *sp, float4 scene_min, float4 scene_max,
                         float *t_exit)
{
    float t_enter;
    *hit = make_miss(ray->tmax);
    *sp = 0;
    *ref = clip_ray_box(ray, scene_min, scene_max, &t_enter, t_exit) ? 0 : BVH_DONE;
    return *ref == 0;
}

RT_FN void bvh_trace_start(BvhTrace *s, float4 scene_min, float4 scene_max)
{
    float t_exit;
    if (bvh_walk_start(&s->ray, &s->hit, &s->ref, &s->sp, scene_min, scene_max, &t_exit))
        s->fused = bvh_ray(&s->ray, t_exit);
}

/* Trace until the ray is done (ref BVH_DONE) or the warp has fewer than RT_FETCH_THRESHOLD lanes
 * tracing: traverse_bvh's while-while loop over a state that survives the return. */
RT_FN void bvh_trace_steps(RT_SCENE_PARAMS, BvhTrace *s, int *stack)
{
    /* BEGIN SOLUTION */
    /* STUB: s->ref = BVH_DONE; return; */
    float t_cut = t_cull(s->hit.t);    /* changes only where a leaf finds a hit */
    for (;;) {
        while ((unsigned int)s->ref < (unsigned int)BVH_DONE) {
            int base = BVH_NODE_STRIDE * s->ref;
            float4 a = load_node_data(node_data, base);
            float4 b = load_node_data(node_data, base + 1);
            float4 z = load_node_data(node_data, base + 2);
            float4 c = load_node_data(node_data, base + 3);
            float e0, e1;
            int hit0 = hit_bvh_child_cut(&s->ray, &s->fused, f4(a.x, a.z, z.x, 0.0f), f4(a.y, a.w, z.y, 0.0f),
                                         t_cut, &e0);
            int hit1 = hit_bvh_child_cut(&s->ray, &s->fused, f4(b.x, b.z, z.z, 0.0f), f4(b.y, b.w, z.w, 0.0f),
                                         t_cut, &e1);
            int c0 = rt_as_int(c.x), c1 = rt_as_int(c.y);
            if (hit0 && hit1) {
                int near0 = e0 <= e1;
                stack[s->sp++] = near0 ? c1 : c0;
                s->ref = near0 ? c0 : c1;
            } else if (hit0 || hit1) {
                s->ref = hit0 ? c0 : c1;
            } else {
                s->ref = s->sp ? stack[--s->sp] : BVH_DONE;
            }
        }
        if (s->ref < 0) {
            intersect_bvh_leaf(RT_SCENE_ARGS, s->ref, &s->ray, &s->hit, 0);
            t_cut = t_cull(s->hit.t);
            s->ref = s->sp ? stack[--s->sp] : BVH_DONE;
        }
        if (s->ref == BVH_DONE || rt_warp_active() < RT_FETCH_THRESHOLD)
            return;
    }
    /* END SOLUTION */
}

#endif /* RT_BVH_H */
