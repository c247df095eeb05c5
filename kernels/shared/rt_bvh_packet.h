/* rt_bvh_packet.h - BVH traversal of a packet of RT_LANES rays in one work-item: the traversal
 * that suits a CPU (Wald, Boulos & Shirley, "Ray tracing deformable scenes using dynamic bounding
 * volume hierarchies", ACM TOG 2007: a packet walks the BVH together, a node is entered when any
 * of its rays hits the node's box).
 *
 * Why a packet on a CPU: PoCL runs a work-group's work-items one after another and can vectorise
 * across them only in straight-line code, which a traversal loop is not. One ray a work-item
 * therefore runs in scalar registers (a quarter or an eighth of an AVX register). Here each box
 * and triangle test runs on all rays of the packet at once in lane vectors (rt_lanes.h), which
 * PoCL's compiler keeps as SIMD instructions; neighbouring camera rays visit nearly the same nodes,
 * so the packet costs little more than one ray. The kernels choose it with
 * RT_TRAVERSAL_BVH_PACKET (rtlab's "bvh-packet"); on a GPU one thread a ray (rt_bvh.h) is the
 * better choice, but the code compiles and runs there too.
 *
 * The BVH is rt_bvh.h's, collapsed to RT_PACKET_WIDTH (W) children a node on the host: a node's
 * children are box-tested one after another on the whole packet, the ones some lane hits entered
 * nearest first (by the smallest entry distance of a lane), the others pushed.
 *
 * Layout in node_data, float4 rows (sync with rtlab/accel/bvh_packet.py), nodes first:
 *   node i, child c < W: rows 2 W i + 2 c, 2 W i + 2 c + 1 = (lo.xyz, ref), (hi.xyz, 0)
 *   then each leaf's triangles, 3 rows each: (v0.xyz, triangle id), (v1 - v0, 0), (v2 - v0, 0)
 * A child ref >= 0 is an inner node; a leaf is ~((row << 4) | count): count triangles from node_data
 * row `row`, so a leaf reads its triangles without the object list's indirection. Used slots come
 * first; an unused one has ref PBVH_EMPTY. The root is node 0 and inner. RT_STACK_SIZE is what a
 * walk down the deepest path can push, (W - 1) x depth + 1 (AccelArrays.stack_size).
 *
 * Boxes are clipped with min/max, which have no NaN rule, so no lane may make a NaN: the inverse
 * direction is bvh_inverse's (finite), and the slabs are (b - o) inv, or b inv - o inv where the
 * loader allows the fused form (RT_BVH_BOX_FMA); lanes without a ray are parked (RayPacket). With
 * RT_CONSERVATIVE the inverse is the exact 1/d, a 0 * inf of a ray in a box's plane is taken as the
 * slab's unbounded side (clip_slab's fmin/fmax rule), and the far distance is widened by its
 * rounding bound RT_T_PAD (Ize 2013), as clip_entering_ray_box does. Boxes are culled against t_cull
 * of each lane's closest hit (lf_t_cull), the pad every traversal uses, so a tie at equal t is kept.
 * Moller-Trumbore runs on the lanes; the other triangle tests run lane by lane through the shared
 * intersect_tri.
 */
#ifndef RT_BVH_PACKET_H
#define RT_BVH_PACKET_H
#include "rt_bvh.h"
#include "rt_intersect.h"
#include "rt_lanes.h"
#include "rt_memory.h"

#define PBVH_LEAF_BITS 4           /* at most 15 triangles a leaf (sync with rtlab/accel/bvh_packet.py) */
#ifndef RT_PACKET_WIDTH            /* children a node; the loader sets it (rtlab.device.kernels.PACKET_WIDTH) */
#define RT_PACKET_WIDTH 4
#endif
#define PBVH_NODE_ROWS (2 * RT_PACKET_WIDTH)
#define PBVH_TRI_ROWS 3
#define PBVH_EMPTY (-1)            /* an unused child slot: a leaf of no triangles */

/* The fused slab form b inv - o inv (rt_bvh.h's RT_BVH_BOX_FMA; the loader sets that for scenes
 * near the origin whose coordinates times 2^64 stay finite, so no lane can make inf - inf) */
#if defined(RT_BVH_BOX_FMA) && RT_BVH_BOX_FMA && !RT_CONSERVATIVE
#define RT_PACKET_BOX_FMA 1
#else
#define RT_PACKET_BOX_FMA 0
#endif

/* The rays of a packet. A lane without a ray (past the end, a NaN/Inf or zero direction) has o = 0,
 * d = 0, inv = 1 and tmin = +inf: it enters no box and hits nothing. */
typedef struct {
    lanef ox, oy, oz;
    lanef dx, dy, dz;
    lanef ix, iy, iz;              /* bvh_inverse(d), finite; with RT_CONSERVATIVE 1/d */
    lanei zx, zy, zz;              /* lanes whose direction component is zero (|d| <= RT_BVH_MIN_DIR) */
#if RT_PACKET_BOX_FMA
    lanef onx, ony, onz;           /* o * inv plus its rounding bound (the fused form's near planes) */
    lanef ofx, ofy, ofz;           /* o * inv minus it (far planes): rt_bvh.h's bvh_ray, lane by lane */
#endif
    lanef tmin;
} RayPacket;

/* Closest hits so far, never NaN; a lane without a ray keeps t = -inf. */
typedef struct {
    lanef t, u, v;
    lanei tri;
} HitPacket;

#if RT_PACKET_BOX_FMA
/* o inv of one axis moved by its rounding bound (rt_bvh.h, hazard 1 of the fused box test): the
 * near planes' distances come out no larger, the far planes' no smaller than the exact ones */
RT_FN void packet_origin_pads(lanef o, lanef inv, lanef *o_near, lanef *o_far)
{
    lanef oi = lf_mul(o, inv);
    lanef pad = lf_mul(lf_abs(oi), lf_splat(RT_BVH_ULP_PAD));
    *o_near = lf_add(oi, pad);
    *o_far = lf_sub(oi, pad);
}
#endif

/* The packet of rays o + t d, t in (tmin, tmax), lane by lane (all lanes vector operations);
 * returns the lanes that hold a ray that can enter a box (ray_can_enter's rule). */
RT_FN lanei packet_init(RayPacket *p, HitPacket *h, lanef ox, lanef oy, lanef oz, lanef dx, lanef dy, lanef dz,
                        lanef tmin, lanef tmax)
{
    lanef zero = lf_splat(0.0f), one = lf_splat(1.0f);
    lanei live = li_and(li_and(lf_finite(ox), lf_finite(oy)), li_and(lf_finite(oz), lf_finite(dx)));
    live = li_and(live, li_and(li_and(lf_finite(dy), lf_finite(dz)), lf_lt(zero, lf_dot3(dx, dy, dz, dx, dy, dz))));
    p->ox = lf_select(zero, ox, live);
    p->oy = lf_select(zero, oy, live);
    p->oz = lf_select(zero, oz, live);
    p->dx = lf_select(zero, dx, live);
    p->dy = lf_select(zero, dy, live);
    p->dz = lf_select(zero, dz, live);
#if RT_CONSERVATIVE
    p->ix = lf_select(one, lf_div(1.0f, dx), live);
    p->iy = lf_select(one, lf_div(1.0f, dy), live);
    p->iz = lf_select(one, lf_div(1.0f, dz), live);
#else
    p->ix = lf_select(one, lf_div(1.0f, lf_away_from_zero(dx, RT_BVH_MIN_DIR)), live);
    p->iy = lf_select(one, lf_div(1.0f, lf_away_from_zero(dy, RT_BVH_MIN_DIR)), live);
    p->iz = lf_select(one, lf_div(1.0f, lf_away_from_zero(dz, RT_BVH_MIN_DIR)), live);
#endif
    p->zx = lf_tiny(p->dx, RT_BVH_MIN_DIR);
    p->zy = lf_tiny(p->dy, RT_BVH_MIN_DIR);
    p->zz = lf_tiny(p->dz, RT_BVH_MIN_DIR);
#if RT_PACKET_BOX_FMA
    packet_origin_pads(p->ox, p->ix, &p->onx, &p->ofx);
    packet_origin_pads(p->oy, p->iy, &p->ony, &p->ofy);
    packet_origin_pads(p->oz, p->iz, &p->onz, &p->ofz);
#endif
    p->tmin = lf_select(lf_splat(RT_INF), tmin, live);
    h->t = lf_select(lf_splat(-RT_INF), tmax, live);
    h->u = zero;
    h->v = zero;
    h->tri = li_splat(-1);
    return live;
}

/* The packet of rays[0 .. count - 1] (count <= RT_LANES). */
RT_FN lanei packet_of_rays(RayPacket *p, HitPacket *h, const Ray *rays, int count)
{
    lanef zero = lf_splat(0.0f);
    lanef ox = zero, oy = zero, oz = zero, dx = zero, dy = zero, dz = zero, tmin = zero, tmax = zero;
    for (int k = 0; k < count; ++k) {
        lf_set(&ox, k, rays[k].o.x);
        lf_set(&oy, k, rays[k].o.y);
        lf_set(&oz, k, rays[k].o.z);
        lf_set(&dx, k, rays[k].d.x);
        lf_set(&dy, k, rays[k].d.y);
        lf_set(&dz, k, rays[k].d.z);
        lf_set(&tmin, k, rays[k].tmin);
        lf_set(&tmax, k, rays[k].tmax);
    }
    return packet_init(p, h, ox, oy, oz, dx, dy, dz, tmin, tmax);
}

/* The hit record of lane k. */
RT_FN void packet_get_hit(const HitPacket *h, int k, Hit *hit)
{
    hit->t = lf_get(h->t, k);
    hit->u = lf_get(h->u, k);
    hit->v = lf_get(h->v, k);
    hit->tri = li_get(h->tri, k);
}

/* One slab: distances of the planes lo and hi, near in *t0 and far in *t1 (min/max, so the sign
 * of the direction needs no test); the fused form takes o inv padded for each (o_near, o_far). A lane whose direction has no
 * component along the axis (z) is decided exactly: inside [lo, hi] the slab does not bound it, a ray
 * lying in the plane of lo or hi included (whichever sign its zero has), outside it misses the box. */
RT_FN void packet_slab(float lo, float hi, lanef o, lanef inv, lanef o_near, lanef o_far, lanei z, lanef *t0,
                       lanef *t1)
{
#if RT_PACKET_BOX_FMA
    lanef near = lf_min(lf_fms(lo, inv, o_near), lf_fms(hi, inv, o_near));
    lanef far = lf_max(lf_fms(lo, inv, o_far), lf_fms(hi, inv, o_far));
#else
    lanef ta = lf_mul(lf_sub(lf_splat(lo), o), inv);
    lanef tb = lf_mul(lf_sub(lf_splat(hi), o), inv);
    lanef near = lf_min(ta, tb), far = lf_max(ta, tb);
#endif
    lanei inside = li_and(lf_le(lf_splat(lo), o), lf_le(o, lf_splat(hi)));
    lanef inf = lf_splat(RT_INF), minus_inf = lf_splat(-RT_INF);
    *t0 = lf_select(near, lf_select(inf, minus_inf, inside), z);
    *t1 = lf_select(far, lf_select(minus_inf, inf, inside), z);
}

/* t_cull (rt_intersect.h) lane by lane: the closest hit's t widened by its rounding pad, -inf kept */
RT_FN lanef lf_t_cull(lanef t)
{
    return lf_max(lf_mul(t, lf_splat(1.0f + RT_T_PAD)), lf_mul(t, lf_splat(1.0f - RT_T_PAD)));
}

/* Lanes whose segment [tmin, t_cut] meets the box [lo, hi] (inclusive at t_cut, as rt_bvh.h);
 * their entry distances in *t_near. */
RT_FN lanei packet_hits_box(const RayPacket *p, lanef t_cut, float4 lo, float4 hi, lanef *t_near)
{
    lanef nx, fx, ny, fy, nz, fz;
#if RT_PACKET_BOX_FMA
    packet_slab(lo.x, hi.x, p->ox, p->ix, p->onx, p->ofx, p->zx, &nx, &fx);
    packet_slab(lo.y, hi.y, p->oy, p->iy, p->ony, p->ofy, p->zy, &ny, &fy);
    packet_slab(lo.z, hi.z, p->oz, p->iz, p->onz, p->ofz, p->zz, &nz, &fz);
#else
    packet_slab(lo.x, hi.x, p->ox, p->ix, p->ox, p->ox, p->zx, &nx, &fx);
    packet_slab(lo.y, hi.y, p->oy, p->iy, p->oy, p->oy, p->zy, &ny, &fy);
    packet_slab(lo.z, hi.z, p->oz, p->iz, p->oz, p->oz, p->zz, &nz, &fz);
#endif
    lanef t0 = lf_max(lf_max(nx, ny), lf_max(nz, p->tmin));
    lanef t1 = lf_min(lf_min(fx, fy), fz);
#if RT_CONSERVATIVE
    /* widen the far distance by its rounding bound, whichever its sign */
    t1 = lf_max(lf_mul(t1, lf_splat(1.0f + RT_T_PAD)), lf_mul(t1, lf_splat(1.0f - RT_T_PAD)));
#endif
    *t_near = t0;
    return lf_le(t0, lf_min(t1, t_cut));
}

/* Moller-Trumbore (intersect_ray_tri_moller's arithmetic) on every lane against one triangle:
 * v0 and its edges e1 = v1 - v0, e2 = v2 - v0 as the layout stores them. Updates the lanes that
 * hit nearer than their hit so far and beyond tmin; returns those lanes. */
RT_FN lanei packet_tri_moller(const RayPacket *p, HitPacket *h, float3 v0, float3 e1, float3 e2, int tri)
{
    lanef px = lf_cross1(p->dy, e2.z, p->dz, e2.y);
    lanef py = lf_cross1(p->dz, e2.x, p->dx, e2.z);
    lanef pz = lf_cross1(p->dx, e2.y, p->dy, e2.x);
    lanef det = lf_dot3s(px, py, pz, e1.x, e1.y, e1.z);
    lanef inv_det = lf_div(1.0f, det);
    lanef sx = lf_sub(p->ox, lf_splat(v0.x));
    lanef sy = lf_sub(p->oy, lf_splat(v0.y));
    lanef sz = lf_sub(p->oz, lf_splat(v0.z));
    lanef u = lf_mul(lf_dot3(sx, sy, sz, px, py, pz), inv_det);
    lanef qx = lf_cross1(sy, e1.z, sz, e1.y);
    lanef qy = lf_cross1(sz, e1.x, sx, e1.z);
    lanef qz = lf_cross1(sx, e1.y, sy, e1.x);
    lanef v = lf_mul(lf_dot3(p->dx, p->dy, p->dz, qx, qy, qz), inv_det);
    lanef t = lf_mul(lf_dot3s(qx, qy, qz, e2.x, e2.y, e2.z), inv_det);
    lanef zero = lf_splat(0.0f), one = lf_splat(1.0f);
    lanei m = li_and(li_and(lf_le(zero, u), lf_le(u, one)), li_and(lf_le(zero, v), lf_le(lf_add(u, v), one)));
    /* closer_hit's rule, lane by lane: nearer, or as near on a lower triangle id */
    lanei closer = li_or(lf_lt(t, h->t), li_and(lf_eq(t, h->t), li_lt(li_splat(tri), h->tri)));
    m = li_and(m, li_and(lf_lt(p->tmin, t), closer));
    m = li_andnot(m, lf_eq(det, zero));
    h->t = lf_select(h->t, t, m);
    h->u = lf_select(h->u, u, m);
    h->v = lf_select(h->v, v, m);
    h->tri = li_select(h->tri, li_splat(tri), m);
    return m;
}

#if RT_ISECT != RT_ISECT_MOLLER
/* The other tests, lane by lane: the lane's ray rebuilt as make_ray builds it, the shared test on
 * triangle `tri`, the lane updated where it hit. */
RT_FN lanei packet_tri_lanewise(RT_SCENE_PARAMS, const RayPacket *p, HitPacket *h, lanei live, int tri)
{
    lanei m = li_splat(0);
    for (int k = 0; k < RT_LANES; ++k) {
        if (!li_get(live, k))
            continue;
        Ray ray = make_ray(f3(lf_get(p->ox, k), lf_get(p->oy, k), lf_get(p->oz, k)),
                           f3(lf_get(p->dx, k), lf_get(p->dy, k), lf_get(p->dz, k)), lf_get(p->tmin, k), RT_INF);
        Hit hit;
        packet_get_hit(h, k, &hit);
        if (intersect_tri(RT_SCENE_ARGS, &ray, tri, &hit)) {
            lf_set(&h->t, k, hit.t);
            lf_set(&h->u, k, hit.u);
            lf_set(&h->v, k, hit.v);
            li_set(&h->tri, k, hit.tri);
            li_set(&m, k, -1);
        }
    }
    return m;
}
#endif

/* Test the triangles of leaf `leaf` on the lanes in `live`; returns the lanes that hit one. */
RT_FN lanei packet_leaf(RT_SCENE_PARAMS, int leaf, const RayPacket *p, HitPacket *h, lanei live)
{
    int bits = ~leaf;
    int row = bits >> PBVH_LEAF_BITS;
    int count = bits & ((1 << PBVH_LEAF_BITS) - 1);
    lanei found = li_splat(0);
    for (int i = 0; i < count; ++i, row += PBVH_TRI_ROWS) {
        float4 a = load_node_data(node_data, row);
#if RT_ISECT == RT_ISECT_MOLLER
        float4 e1 = load_node_data(node_data, row + 1);
        float4 e2 = load_node_data(node_data, row + 2);
        found = li_or(found, packet_tri_moller(p, h, xyz(a), xyz(e1), xyz(e2), rt_as_int(a.w)));
#else
        found = li_or(found, packet_tri_lanewise(RT_SCENE_ARGS, p, h, live, rt_as_int(a.w)));
#endif
    }
    return found;
}

/* Closest hits of the packet's rays (any_hit: each lane's first hit, stopping when every lane has
 * one). `live`: the lanes that hold a ray. *h holds each lane's hit so far on entry. */
RT_FN void traverse_bvh_packet(RT_SCENE_PARAMS, const RayPacket *p, HitPacket *h, lanei live, int any_hit)
{
    int stack[RT_STACK_SIZE];
    int sp = 0;
    int ref = 0;
    /* Box tests cull beyond t_cut: t_cull of the closest hit so far (the scalar traversals' pad),
     * or -inf for a lane that is done */
    lanef t_cut = lf_t_cull(h->t);
    lanef inf = lf_splat(RT_INF);
    for (;;) {
        /* Inner nodes: enter the children some lane hits, the one a lane enters first first; the
         * others go on the stack, nearer ones on top */
        while (ref >= 0) {
            int base = PBVH_NODE_ROWS * ref;
            int hit_ref[RT_PACKET_WIDTH];
            float hit_t[RT_PACKET_WIDTH];
            int n = 0;
#pragma unroll
            for (int c = 0; c < RT_PACKET_WIDTH; ++c) {
                float4 lo = load_node_data(node_data, base + 2 * c);
                float4 hi = load_node_data(node_data, base + 2 * c + 1);
                int child = rt_as_int(lo.w);
                if (c >= 2 && child == PBVH_EMPTY)
                    break;
                lanef t_near;
                lanei m = packet_hits_box(p, t_cut, lo, hi, &t_near);
                if (!lane_any(m))
                    continue;
                /* insertion by entry distance, farthest first */
                float e = lf_hmin(lf_select(inf, t_near, m));
                int j = n++;
                while (j > 0 && hit_t[j - 1] < e) {
                    hit_t[j] = hit_t[j - 1];
                    hit_ref[j] = hit_ref[j - 1];
                    --j;
                }
                hit_t[j] = e;
                hit_ref[j] = child;
            }
            if (n == 0) {
                if (sp == 0)
                    return;
                ref = stack[--sp];
                continue;
            }
            for (int j = 0; j < n - 1; ++j)
                stack[sp++] = hit_ref[j];
            ref = hit_ref[n - 1];
        }
        lanei found = packet_leaf(RT_SCENE_ARGS, ref, p, h, live);
        if (any_hit) {
            live = li_andnot(live, found);
            if (!lane_any(live))
                return;
            t_cut = lf_select(lf_splat(-RT_INF), lf_t_cull(h->t), live);
        } else {
            t_cut = lf_t_cull(h->t);
        }
        if (sp == 0)
            return;
        ref = stack[--sp];
    }
}

/* One ray through the packet traversal (lane 0; the others empty): what trace_closest and
 * trace_any use with this traversal (shading, shadow and secondary rays). *hit holds the hit so
 * far; it changes only where the traversal finds a nearer one. */
RT_FN void traverse_bvh_packet_ray(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray, Hit *hit,
                                   int any_hit)
{
    Ray cut = *ray;
    cut.tmax = hit->t;
    RayPacket p;
    HitPacket h;
    lanei live = packet_of_rays(&p, &h, &cut, 1);
    if (!lane_any(live))
        return;
    traverse_bvh_packet(RT_SCENE_ARGS, &p, &h, live, any_hit);
    if (li_get(h.tri, 0) >= 0)
        packet_get_hit(&h, 0, hit);
}

#endif /* RT_BVH_PACKET_H */
