/* rt_bvh_wide.h - one ray a work-item through a wide BVH: a node's RT_LANES children are box-tested
 * at once in SIMD lanes (rt_lanes.h), and a leaf's triangles RT_LANES at a time (Wald, Benthin &
 * Boulos 2008, "Getting rid of packets"; the single-ray kernels of Embree's BVH8 and tinybvh's
 * BVH8_CPU). The CPU's traversal for incoherent rays: rays that share little of their paths
 * (diffuse bounces) gain nothing from a packet (rt_bvh_packet.h), whose lanes then test boxes for
 * rays that miss them; here every lane works for the one ray. On a GPU the lanes are a loop (one
 * thread a ray, rt_bvh.h is the choice there); it compiles and runs.
 *
 * The tree is rtlab.accel.bvh's BVH collapsed to RT_LANES children a node on the host. Layout in
 * node_data, float4 rows (sync with rtlab/accel/bvh_wide.py); Q = RT_LANES / 4 rows hold one lane
 * vector (lf_load_rows):
 *   node i from row WBVH_NODE_ROWS i: lane vectors lo.x, hi.x, lo.y, hi.y, lo.z, hi.z of its
 *     children, then their refs (int bits); an unused slot has lo = +inf, hi = -inf, ref WBVH_EMPTY
 *   after the nodes, the leaves' triangles in blocks of RT_LANES, WBVH_BLOCK_ROWS rows a block:
 *     lane vectors v0.x, v0.y, v0.z, v1.x, ..., v2.z (vertex j's axis a is vector 3 j + a), then the
 *     triangle ids; a leaf's last block is filled up with copies of its first triangle (a copy
 *     ties with itself, which closer_hit rejects)
 * A ref >= 0 is an inner node; a leaf is ~((row << WBVH_LEAF_BITS) | count): count triangles in
 * blocks from row `row`. The root is node 0 and inner. RT_STACK_SIZE is (RT_LANES - 1) x depth + 1.
 *
 * Box test: each slab's near and far plane are picked by the sign of the ray's direction once a
 * ray (which lane vector to load), so a slab costs two fused multiply-adds and no min/max, and an
 * unused slot (an inverted box) misses on its own. The planes are rt_bvh.h's fused form with its
 * padded o inv (RT_BVH_BOX_FMA: scenes near the origin, zero components included through the pad),
 * else clip_entering_ray_box's exact (b - o) / d with its padded far plane and clip_slab's rule for
 * a zero component (the slab does not bound a ray inside it). Under RT_CONSERVATIVE the exit is
 * widened as rt_bvh.h widens it, and boxes are culled against t_cull of the closest hit, as in
 * every traversal (rt_intersect.h). Children are entered nearest first; the others are pushed with
 * their entry distance, and a popped one that now lies beyond t_cull of the closest hit is dropped.
 * Triangles: rt_intersect_lanes.h's tests on a block, the ray's watertight axes set up once;
 * Wald's and Plucker's tests run lane by lane through the shared intersect_tri.
 */
#ifndef RT_BVH_WIDE_H
#define RT_BVH_WIDE_H
#include "rt_bvh.h"
#include "rt_intersect_lanes.h"
#include "rt_memory.h"

#define WBVH_LEAF_BITS 4           /* at most 15 triangles a leaf (sync with rtlab/accel/bvh_wide.py) */
#define WBVH_EMPTY (-1)            /* an unused child slot */
#define WBVH_Q (RT_LANES / 4)      /* float4 rows a lane vector */
#define WBVH_NODE_VECTORS 7        /* lane vectors a node: lo and hi of each axis, refs */
#define WBVH_BLOCK_VECTORS 10      /* lane vectors a block: 3 vertices x 3 axes, ids */
#define WBVH_NODE_ROWS (WBVH_NODE_VECTORS * WBVH_Q)
#define WBVH_BLOCK_ROWS (WBVH_BLOCK_VECTORS * WBVH_Q)

/* The per-ray constants of the wide traversal */
typedef struct {
    float3 inv;                    /* bvh_inverse(d) (fused form) or 1/d (exact form) */
    float3 o_near, o_far;          /* fused form: o inv padded for the near and the far plane
                                      (rt_bvh.h's o_lo / o_hi by the sign of d); exact form: o */
    float3 inv_far;                /* exact form: the far plane's inverse, padded under RT_CONSERVATIVE */
    int near_x, near_y, near_z;    /* lane vector of each slab's near plane: 2 axis + (d < 0) */
    int zero_x, zero_y, zero_z;    /* exact form: a component that has no finite inverse */
    float tmin;                    /* tmin, +0 for -0 */
#if RT_ISECT == RT_ISECT_WATERTIGHT
    WatertightAxes axes;
#endif
} WideRay;

/* The constants of a ray whose segment in the scene box ends at t_exit (clip_ray_box). */
RT_FN WideRay wide_ray(const Ray *ray, float t_exit)
{
    WideRay w;
    BvhRay f = bvh_ray(ray, t_exit);
    int nx = f.inv.x < 0.0f, ny = f.inv.y < 0.0f, nz = f.inv.z < 0.0f;
    w.near_x = nx;
    w.near_y = 2 + ny;
    w.near_z = 4 + nz;
#if RT_BVH_BOX_FMA
    w.inv = f.inv;
    w.o_near = f3(nx ? f.o_hi.x : f.o_lo.x, ny ? f.o_hi.y : f.o_lo.y, nz ? f.o_hi.z : f.o_lo.z);
    w.o_far = f3(nx ? f.o_lo.x : f.o_hi.x, ny ? f.o_lo.y : f.o_hi.y, nz ? f.o_lo.z : f.o_hi.z);
    w.inv_far = w.inv;
    w.zero_x = w.zero_y = w.zero_z = 0;
#else
    w.inv = ray->inv_d;
    w.o_near = ray->o;
    w.o_far = ray->o;
#if RT_CONSERVATIVE
    w.inv_far = mul3(ray->inv_d, 1.0f + RT_T_PAD);
#else
    w.inv_far = ray->inv_d;
#endif
    w.zero_x = rt_abs(ray->d.x) <= RT_BVH_MIN_DIR;
    w.zero_y = rt_abs(ray->d.y) <= RT_BVH_MIN_DIR;
    w.zero_z = rt_abs(ray->d.z) <= RT_BVH_MIN_DIR;
#endif
    w.tmin = f.tmin;
#if RT_ISECT == RT_ISECT_WATERTIGHT
    w.axes = watertight_axes(ray->d);
#endif
    return w;
}

/* The lane vector v (0..6) of node `node` */
#define WBVH_NODE_VEC(node, v) lf_load_rows(load_node_data, node_data, WBVH_NODE_ROWS * (node) + (v) * WBVH_Q)

/* Lane k of the lane vector at row `row` (a scalar read; k need not be a constant) */
#define wide_lane(row, k) lane_load_row_float(load_node_data, node_data, (row), (k))

/* One slab of every child: entry and exit distances from its near and far plane (np, fp), o and
 * the inverses of that axis; `zero`: the exact form's rule for a component without an inverse. */
RT_FN void wide_slab(lanef np, lanef fp, float inv, float inv_far, float o_near, float o_far, int zero, lanef *t0,
                     lanef *t1)
{
#if RT_BVH_BOX_FMA
    *t0 = lf_fms(inv, np, lf_splat(o_near));
    *t1 = lf_fms(inv_far, fp, lf_splat(o_far));
#else
    lanef o = lf_splat(o_near);
    *t0 = lf_mul(lf_sub(np, o), lf_splat(inv));
    *t1 = lf_mul(lf_sub(fp, o), lf_splat(inv_far));
    if (zero) {
        /* inside [lo, hi] (the planes in either order), a ray lying in a plane included: unbounded */
        lanei inside = li_and(lf_le(lf_min(np, fp), o), lf_le(o, lf_max(np, fp)));
        lanef inf = lf_splat(RT_INF), minus_inf = lf_splat(-RT_INF);
        *t0 = lf_select(inf, minus_inf, inside);
        *t1 = lf_select(minus_inf, inf, inside);
    }
#endif
}

/* The children of inner node `node` whose box the ray enters before t_cut (a bit each), their
 * entry distances in *t_enter. */
RT_FN int wide_node_hits(RT_SCENE_PARAMS, const WideRay *w, int node, float t_cut, lanef *t_enter)
{
    lanef nx, fx, ny, fy, nz, fz;
    wide_slab(WBVH_NODE_VEC(node, w->near_x), WBVH_NODE_VEC(node, w->near_x ^ 1), w->inv.x, w->inv_far.x,
              w->o_near.x, w->o_far.x, w->zero_x, &nx, &fx);
    wide_slab(WBVH_NODE_VEC(node, w->near_y), WBVH_NODE_VEC(node, w->near_y ^ 1), w->inv.y, w->inv_far.y,
              w->o_near.y, w->o_far.y, w->zero_y, &ny, &fy);
    wide_slab(WBVH_NODE_VEC(node, w->near_z), WBVH_NODE_VEC(node, w->near_z ^ 1), w->inv.z, w->inv_far.z,
              w->o_near.z, w->o_far.z, w->zero_z, &nz, &fz);
    lanef t0 = lf_max(lf_max(nx, ny), lf_max(nz, lf_splat(w->tmin)));
    lanef t1 = lf_min(lf_min(fx, fy), lf_min(fz, lf_splat(t_cut)));
#if RT_CONSERVATIVE && RT_BVH_BOX_FMA
    t1 = lf_mul(t1, lf_splat(RT_BVH_EXIT_SCALE));
#endif
    *t_enter = t0;
    return lane_bits(lf_le(t0, t1));
}

/* The lane vector v (0..9) of the triangle block at row `row` */
#define WBVH_TRI_VEC(row, v) lf_load_rows(load_node_data, node_data, (row) + (v) * WBVH_Q)

/* Vertex j of lane k of the block at row `row` */
RT_FN float3 wide_block_vertex(RT_SCENE_PARAMS, int row, int j, int k)
{
    return f3(wide_lane(row + (3 * j) * WBVH_Q, k), wide_lane(row + (3 * j + 1) * WBVH_Q, k),
              wide_lane(row + (3 * j + 2) * WBVH_Q, k));
}

/* Ask the cache for what ref points to: an inner node's boxes or a leaf's first block */
RT_FN void wide_prefetch(RT_SCENE_PARAMS, int ref)
{
    int row = ref >= 0 ? WBVH_NODE_ROWS * ref : (~ref) >> WBVH_LEAF_BITS;
    for (int r = 0; r < WBVH_NODE_ROWS; r += 4)
        lane_prefetch_rows(node_data, row + r);
}

/* Test the block of triangles at row `row`; returns whether the closest hit changed. */
RT_FN int wide_block(RT_SCENE_PARAMS, const Ray *ray, const WideRay *w, int row, Hit *hit)
{
    int ids = row + 9 * WBVH_Q;
    int found = 0;
#if RT_ISECT == RT_ISECT_WATERTIGHT
    /* The vertices moved to the origin and permuted as the scalar test does, lane by lane */
    const WatertightAxes *k = &w->axes;
    lanef okx = lf_splat(get3(ray->o, k->kx)), oky = lf_splat(get3(ray->o, k->ky)), okz = lf_splat(get3(ray->o, k->kz));
    lanef u, v, e, det;
    lanef az = lf_sub(WBVH_TRI_VEC(row, k->kz), okz);
    lanef bz = lf_sub(WBVH_TRI_VEC(row, 3 + k->kz), okz);
    lanef cz = lf_sub(WBVH_TRI_VEC(row, 6 + k->kz), okz);
    lanei m = lanes_watertight_edges(lf_sub(WBVH_TRI_VEC(row, k->kx), okx), lf_sub(WBVH_TRI_VEC(row, k->ky), oky), az,
                                     lf_sub(WBVH_TRI_VEC(row, 3 + k->kx), okx), lf_sub(WBVH_TRI_VEC(row, 3 + k->ky), oky),
                                     bz, lf_sub(WBVH_TRI_VEC(row, 6 + k->kx), okx),
                                     lf_sub(WBVH_TRI_VEC(row, 6 + k->ky), oky), cz, lf_splat(k->sx), lf_splat(k->sy), &u,
                                     &v, &e, &det);
    int bits = lane_bits(m);
    if (bits == 0)
        return 0;
    lanef inv_det = lf_div(1.0f, det);
    lanef hu = lf_mul(v, inv_det), hv = lf_mul(e, inv_det);
#if !RT_REFINE_T
    lanef tw = lf_mul(lf_dot3_scaled(u, v, e, lf_splat(k->sz), az, bz, cz), inv_det);
#endif
    while (bits) {
        int lane = rt_ctz(bits);
        bits &= bits - 1;
        int tri = rt_as_int(wide_lane(ids, lane));
#if RT_REFINE_T
        /* The edge functions decide whether; the plane decides where (plane_t_fp64), as the scalar test */
        float t = plane_t_fp64(ray->o, ray->d, wide_block_vertex(RT_SCENE_ARGS, row, 0, lane),
                               wide_block_vertex(RT_SCENE_ARGS, row, 1, lane), wide_block_vertex(RT_SCENE_ARGS, row, 2, lane));
#else
        float t = lf_get(tw, lane);
#endif
        if (closer_hit(ray, t, tri, hit)) {
            hit->t = t;
            hit->u = lf_get(hu, lane);
            hit->v = lf_get(hv, lane);
            hit->tri = tri;
            found = 1;
        }
    }
#elif RT_ISECT == RT_ISECT_MOLLER
    lanef v0x = WBVH_TRI_VEC(row, 0), v0y = WBVH_TRI_VEC(row, 1), v0z = WBVH_TRI_VEC(row, 2);
    lanef u, v, t;
    lanei m = lanes_moller(lf_splat(ray->o.x), lf_splat(ray->o.y), lf_splat(ray->o.z), lf_splat(ray->d.x),
                           lf_splat(ray->d.y), lf_splat(ray->d.z), v0x, v0y, v0z, lf_sub(WBVH_TRI_VEC(row, 3), v0x),
                           lf_sub(WBVH_TRI_VEC(row, 4), v0y), lf_sub(WBVH_TRI_VEC(row, 5), v0z),
                           lf_sub(WBVH_TRI_VEC(row, 6), v0x), lf_sub(WBVH_TRI_VEC(row, 7), v0y),
                           lf_sub(WBVH_TRI_VEC(row, 8), v0z), &u, &v, &t);
    int bits = lane_bits(li_and(m, lf_lt(lf_splat(ray->tmin), t)));
    while (bits) {
        int lane = rt_ctz(bits);
        bits &= bits - 1;
        int tri = rt_as_int(wide_lane(ids, lane));
        float tl = lf_get(t, lane);
        if (closer_hit(ray, tl, tri, hit)) {
            hit->t = tl;
            hit->u = lf_get(u, lane);
            hit->v = lf_get(v, lane);
            hit->tri = tri;
            found = 1;
        }
    }
#else
    for (int lane = 0; lane < RT_LANES; ++lane)
        found |= intersect_tri(RT_SCENE_ARGS, ray, rt_as_int(wide_lane(ids, lane)), hit);
#endif
    return found;
}

/* Test the triangles of leaf `leaf`; returns 1 when an any-hit query may stop. */
RT_FN int wide_leaf(RT_SCENE_PARAMS, int leaf, const Ray *ray, const WideRay *w, Hit *hit, int any_hit)
{
    int bits = ~leaf;
    int row = bits >> WBVH_LEAF_BITS;
    int count = bits & ((1 << WBVH_LEAF_BITS) - 1);
    for (int i = 0; i < count; i += RT_LANES, row += WBVH_BLOCK_ROWS) {
        if (wide_block(RT_SCENE_ARGS, ray, w, row, hit) && any_hit)
            return 1;
    }
    return 0;
}

/* Wide BVH traversal of one ray. Closest hit, or with any_hit the first hit found. *hit holds the
 * hit so far (a miss at ray->tmax for a new ray). */
RT_FN void traverse_bvh_wide(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray, Hit *hit,
                             int any_hit)
{
    float t_enter, t_exit;
    if (!clip_ray_box(ray, scene_min, scene_max, &t_enter, &t_exit))
        return;
    WideRay w = wide_ray(ray, t_exit);
    int stack[RT_STACK_SIZE];
    float stack_t[RT_STACK_SIZE];
    int sp = 0;
    int ref = 0;
    float dist[RT_LANES];
    int kids[RT_LANES];
    for (;;) {
        /* Inner nodes: the nearest child entered next, the others pushed farthest first */
        while (ref >= 0) {
            lanef t_near;
            int bits = wide_node_hits(RT_SCENE_ARGS, &w, ref, t_cull(hit->t), &t_near);
            if (bits == 0)
                break;
            li_store(kids, li_load_rows(load_node_data, node_data, WBVH_NODE_ROWS * ref + 6 * WBVH_Q));
            int c = rt_ctz(bits);
            bits &= bits - 1;
            if (bits == 0) {
                ref = kids[c];
                continue;
            }
            lf_store(dist, t_near);
            int d = rt_ctz(bits);
            bits &= bits - 1;
            if (bits == 0) {
                /* two children: the far one pushed */
                int near_c = dist[c] <= dist[d];
                int far = near_c ? d : c;
                stack_t[sp] = dist[far];
                stack[sp++] = kids[far];
                wide_prefetch(RT_SCENE_ARGS, kids[far]);
                ref = kids[near_c ? c : d];
                continue;
            }
            /* three or more: insertion by entry distance into this node's entries, farthest deepest */
            int base = sp;
            bits |= 1 << d;
            for (;;) {
                float e = dist[c];
                int j = sp++;
                while (j > base && stack_t[j - 1] < e) {
                    stack_t[j] = stack_t[j - 1];
                    stack[j] = stack[j - 1];
                    --j;
                }
                stack_t[j] = e;
                stack[j] = kids[c];
                wide_prefetch(RT_SCENE_ARGS, kids[c]);
                if (bits == 0)
                    break;
                c = rt_ctz(bits);
                bits &= bits - 1;
            }
            ref = stack[--sp];
        }
        if (ref < 0 && wide_leaf(RT_SCENE_ARGS, ref, ray, &w, hit, any_hit))
            return;
        /* Pop the nearest entry still in front of the closest hit */
        float t_cut = t_cull(hit->t);
        while (sp > 0 && stack_t[sp - 1] > t_cut)
            --sp;
        if (sp == 0)
            return;
        ref = stack[--sp];
    }
}

#endif /* RT_BVH_WIDE_H */
