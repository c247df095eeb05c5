/* rt_bvh_packet.h - BVH traversal of a packet of RT_LANES rays in one work-item: the traversal
 * that suits a CPU for coherent rays (Wald, Boulos & Shirley, "Ray tracing deformable scenes using
 * dynamic bounding volume hierarchies", ACM TOG 2007: a packet walks the BVH together, a node is
 * entered when any of its rays hits the node's box).
 *
 * Why a packet on a CPU: PoCL runs a work-group's work-items one after another and can vectorise
 * across them only in straight-line code, which a traversal loop is not. One ray a work-item
 * therefore runs in scalar registers (a quarter or an eighth of an AVX register). Here each box
 * and triangle test runs on all rays of the packet at once in lane vectors (rt_lanes.h), which
 * PoCL's compiler keeps as SIMD instructions; neighbouring camera rays visit nearly the same nodes,
 * so the packet costs little more than one ray. Rays that go their own ways (diffuse bounces) would
 * make a packet visit the union of their paths: packet_is_coherent tells them apart, and such a
 * packet's rays go one by one through the wide traversal of the same tree (rt_bvh_wide.h), whose
 * lanes test a node's children instead (rt_primary.h's trace_packet). The kernels choose this with
 * RT_TRAVERSAL_BVH_PACKET (rtlab's "bvh-packet"), which also takes rt_bvh_wide.h for single rays
 * (shadows, reflections); on a GPU one thread a ray (rt_bvh.h) is the better choice, but the code
 * compiles and runs there too.
 *
 * The tree is rt_bvh_wide.h's: RT_LANES children a node, their boxes as lane vectors, triangles in
 * blocks of RT_LANES. A packet reads a child's box and a triangle's vertices as scalars (one lane
 * of those vectors) and tests them on all its rays; a node's children are box-tested one after
 * another, the ones some lane hits entered nearest first (by the smallest entry distance of a
 * lane), the others pushed. Used slots come first, so the first unused one ends a node.
 *
 * A packet walks the tree only when its rays are coherent (packet_is_coherent), so every lane's
 * direction has the same signs: each slab's near and far plane are the same for all lanes and are
 * read as such (one fused multiply-add a plane and lane, no min/max), as the wide traversal reads
 * them. That fused form is rt_bvh.h's, lane by lane: b inv - o inv with inv = bvh_inverse(d) and
 * o inv padded by its rounding bound, a zero component's by the ray's length in the scene box too
 * (RT_BVH_BOX_FMA: scenes near the origin). Elsewhere the slabs are (b - o) inv with min/max, which
 * have no NaN rule, so no lane may make a NaN: the inverse is finite but for the exact 1/d of
 * RT_CONSERVATIVE, and a lane whose direction has no component along an axis is decided by whether
 * it lies inside the slab (clip_slab's fmin/fmax rule for the 0 * inf of a ray in a box's plane).
 * With RT_CONSERVATIVE the far distance is widened by its rounding bound RT_T_PAD (Ize 2013) in
 * either form, as clip_entering_ray_box and rt_bvh.h do. Lanes without a ray are parked
 * (RayPacket). Boxes are culled against t_cull of each lane's closest hit (lf_t_cull), the pad
 * every traversal uses, so a tie at equal t is kept.
 * Moller-Trumbore and the watertight test run on the lanes (rt_intersect_lanes.h, the scalar tests'
 * arithmetic: the same ids and t as every other traversal); Wald's and Plucker's tests run lane by
 * lane through the shared intersect_tri.
 */
#ifndef RT_BVH_PACKET_H
#define RT_BVH_PACKET_H
#include "rt_bvh.h"
#include "rt_bvh_wide.h"
#include "rt_intersect.h"
#include "rt_intersect_lanes.h"
#include "rt_lanes.h"
#include "rt_memory.h"

/* The fused slab form b inv - o inv (rt_bvh.h's RT_BVH_BOX_FMA; the loader sets that for scenes
 * near the origin whose coordinates times 2^64 stay finite, so no lane can make inf - inf) */
#if defined(RT_BVH_BOX_FMA) && RT_BVH_BOX_FMA
#define RT_PACKET_BOX_FMA 1
#else
#define RT_PACKET_BOX_FMA 0
#endif

/* The rays of a packet. A lane without a ray (past the end, a NaN/Inf or zero direction) has o = 0,
 * d = 0, inv = 1 and tmin = +inf: it enters no box and hits nothing. */
typedef struct {
    lanef ox, oy, oz;
    lanef dx, dy, dz;
    lanef ix, iy, iz;              /* bvh_inverse(d): finite, of d's sign (-0 negative); 1/d in the exact
                                      form with RT_CONSERVATIVE */
    int nx, ny, nz;                /* the near plane of each slab, 1 for hi (inv < 0): the first live lane's */
#if RT_PACKET_BOX_FMA
    lanef onx, ony, onz;           /* o inv padded for the near planes ... */
    lanef ofx, ofy, ofz;           /* ... and the far planes: rt_bvh.h's bvh_ray, lane by lane */
#else
    lanei zx, zy, zz;              /* lanes whose direction component is zero (|d| <= RT_BVH_MIN_DIR) */
#endif
    lanef tmin;
#if RT_ISECT == RT_ISECT_WATERTIGHT
    /* The watertight test's per-ray part (watertight_axes), lane by lane: axes as lane ints, the
     * shear, the origin in each lane's axis order; `uniform` when every live lane has the same
     * axes (camera rays nearly always), then also as scalars */
    lanei kx, ky, kz;
    lanef sx, sy, sz;
    lanef okx, oky, okz;
    int uniform, ukx, uky, ukz;
#endif
} RayPacket;

/* Closest hits so far, never NaN; a lane without a ray keeps t = -inf. */
typedef struct {
    lanef t, u, v;
    lanei tri;
} HitPacket;

#if RT_PACKET_BOX_FMA
/* o inv of one axis moved by its rounding bound, and for a zero component (|d| <= RT_BVH_MIN_DIR)
 * by t_pad as well (rt_bvh.h's bvh_origin_pad, hazards 1 and 2 of the fused box test): the near
 * planes' distances come out no larger, the far planes' no smaller than the exact ones */
RT_FN void packet_origin_pads(lanef o, lanef inv, lanef d, lanef t_pad, lanef *o_near, lanef *o_far)
{
    lanef oi = lf_mul(o, inv);
    lanef pad = lf_add(lf_mul(lf_abs(oi), lf_splat(RT_BVH_ULP_PAD)),
                       lf_select(lf_splat(0.0f), t_pad, lf_tiny(d, RT_BVH_MIN_DIR)));
    *o_near = lf_add(oi, pad);
    *o_far = lf_sub(oi, pad);
}
#endif

#if RT_ISECT == RT_ISECT_WATERTIGHT
/* Lane by lane, the component of (x, y, z) that axis k (0, 1, 2) names */
RT_FN lanef lf_axis(lanei k, lanef x, lanef y, lanef z)
{
    return lf_select(lf_select(z, y, li_eq(k, li_splat(1))), x, li_eq(k, li_splat(0)));
}

/* watertight_axes of each lane's ray, in lane vectors (the same comparisons and roundings) */
RT_FN void packet_watertight_axes(RayPacket *p, lanei live)
{
    /* BEGIN SOLUTION */
    /* STUB: p->uniform = 0; return; */
    lanef ax = lf_abs(p->dx), ay = lf_abs(p->dy), az = lf_abs(p->dz);
    lanei zero = li_splat(0), one = li_splat(1), two = li_splat(2);
    p->kz = li_select(li_select(two, one, lf_lt(az, ay)), li_select(two, zero, lf_lt(az, ax)), lf_lt(ay, ax));
    p->kx = li_select(li_add1(p->kz), zero, li_eq(p->kz, two));
    p->ky = li_select(li_add1(p->kx), zero, li_eq(p->kx, two));
    lanei swap = lf_lt(lf_axis(p->kz, p->dx, p->dy, p->dz), lf_splat(0.0f));
    lanei kx = p->kx;
    p->kx = li_select(p->kx, p->ky, swap);
    p->ky = li_select(p->ky, kx, swap);
    p->sz = lf_div(1.0f, lf_axis(p->kz, p->dx, p->dy, p->dz));
    p->sx = lf_mul(lf_axis(p->kx, p->dx, p->dy, p->dz), p->sz);
    p->sy = lf_mul(lf_axis(p->ky, p->dx, p->dy, p->dz), p->sz);
    p->okx = lf_axis(p->kx, p->ox, p->oy, p->oz);
    p->oky = lf_axis(p->ky, p->ox, p->oy, p->oz);
    p->okz = lf_axis(p->kz, p->ox, p->oy, p->oz);
    int bits = lane_bits(live);
    int first = bits ? rt_ctz(bits) : 0;
    p->ukx = li_get(p->kx, first);
    p->uky = li_get(p->ky, first);
    p->ukz = li_get(p->kz, first);
    lanei same = li_and(li_eq(p->kx, li_splat(p->ukx)), li_eq(p->ky, li_splat(p->uky)));
    p->uniform = lane_bits(li_and(same, live)) == bits;
    /* END SOLUTION */
}
#endif

/* The packet of rays o + t d, t in (tmin, tmax), lane by lane (all lanes vector operations);
 * returns the lanes that hold a ray that can enter a box (ray_can_enter's rule). */
RT_FN lanei packet_init(RayPacket *p, HitPacket *h, float4 scene_min, float4 scene_max, lanef ox, lanef oy, lanef oz,
                        lanef dx, lanef dy, lanef dz, lanef tmin, lanef tmax)
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
#if RT_CONSERVATIVE && !RT_PACKET_BOX_FMA
    p->ix = lf_select(one, lf_div(1.0f, dx), live);
    p->iy = lf_select(one, lf_div(1.0f, dy), live);
    p->iz = lf_select(one, lf_div(1.0f, dz), live);
#else
    p->ix = lf_select(one, lf_div(1.0f, lf_away_from_zero(dx, RT_BVH_MIN_DIR)), live);
    p->iy = lf_select(one, lf_div(1.0f, lf_away_from_zero(dy, RT_BVH_MIN_DIR)), live);
    p->iz = lf_select(one, lf_div(1.0f, lf_away_from_zero(dz, RT_BVH_MIN_DIR)), live);
#endif
    int bits = lane_bits(live);
    int first = bits ? rt_ctz(bits) : 0;
    p->nx = lf_get(p->ix, first) < 0.0f;
    p->ny = lf_get(p->iy, first) < 0.0f;
    p->nz = lf_get(p->iz, first) < 0.0f;
#if RT_PACKET_BOX_FMA
    /* Beyond where the ray leaves the scene box: twice (|o - centre| + the box's diagonal) / |d| */
    float3 c = mul3(add3(xyz(scene_min), xyz(scene_max)), 0.5f);
    float diag = rt_sqrt(dot3(sub3(xyz(scene_max), xyz(scene_min)), sub3(xyz(scene_max), xyz(scene_min))));
    lanef rx = lf_sub(p->ox, lf_splat(c.x)), ry = lf_sub(p->oy, lf_splat(c.y)), rz = lf_sub(p->oz, lf_splat(c.z));
    lanef t_pad = lf_mul(lf_splat(2.0f), lf_div_lanes(lf_add(lf_sqrt(lf_dot3(rx, ry, rz, rx, ry, rz)), lf_splat(diag)),
                                                      lf_sqrt(lf_dot3(p->dx, p->dy, p->dz, p->dx, p->dy, p->dz))));
    packet_origin_pads(p->ox, p->ix, p->dx, t_pad, &p->onx, &p->ofx);
    packet_origin_pads(p->oy, p->iy, p->dy, t_pad, &p->ony, &p->ofy);
    packet_origin_pads(p->oz, p->iz, p->dz, t_pad, &p->onz, &p->ofz);
#else
    p->zx = lf_tiny(p->dx, RT_BVH_MIN_DIR);
    p->zy = lf_tiny(p->dy, RT_BVH_MIN_DIR);
    p->zz = lf_tiny(p->dz, RT_BVH_MIN_DIR);
#endif
    p->tmin = lf_select(lf_splat(RT_INF), tmin, live);
    h->t = lf_select(lf_splat(-RT_INF), tmax, live);
    h->u = zero;
    h->v = zero;
    h->tri = li_splat(-1);
#if RT_ISECT == RT_ISECT_WATERTIGHT
    packet_watertight_axes(p, live);
#endif
    return live;
}

/* The packet of rays[0 .. count - 1] (count <= RT_LANES) in the scene box [scene_min, scene_max]. */
RT_FN lanei packet_of_rays(RayPacket *p, HitPacket *h, float4 scene_min, float4 scene_max, const Ray *rays, int count)
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
    return packet_init(p, h, scene_min, scene_max, ox, oy, oz, dx, dy, dz, tmin, tmax);
}

/* The hit record of lane k. */
RT_FN void packet_get_hit(const HitPacket *h, int k, Hit *hit)
{
    hit->t = lf_get(h->t, k);
    hit->u = lf_get(h->u, k);
    hit->v = lf_get(h->v, k);
    hit->tri = li_get(h->tri, k);
}

#if !RT_PACKET_BOX_FMA
/* One slab of the exact form: distances of the planes lo and hi, near in *t0 and far in *t1
 * (min/max, so the sign of the direction needs no test). A lane whose direction has no component
 * along the axis (z) is decided exactly: inside [lo, hi] the slab does not bound it, a ray lying in
 * the plane of lo or hi included (whichever sign its zero has), outside it misses the box. */
RT_FN void packet_slab(float lo, float hi, lanef o, lanef inv, lanei z, lanef *t0, lanef *t1)
{
    lanef ta = lf_mul(lf_sub(lf_splat(lo), o), inv);
    lanef tb = lf_mul(lf_sub(lf_splat(hi), o), inv);
    lanef near = lf_min(ta, tb), far = lf_max(ta, tb);
    lanei inside = li_and(lf_le(lf_splat(lo), o), lf_le(o, lf_splat(hi)));
    lanef inf = lf_splat(RT_INF), minus_inf = lf_splat(-RT_INF);
    *t0 = lf_select(near, lf_select(inf, minus_inf, inside), z);
    *t1 = lf_select(far, lf_select(minus_inf, inf, inside), z);
}
#endif

/* t_cull (rt_intersect.h) lane by lane: the closest hit's t widened by its rounding pad, -inf kept */
RT_FN lanef lf_t_cull(lanef t)
{
    return lf_max(lf_mul(t, lf_splat(1.0f + RT_T_PAD)), lf_mul(t, lf_splat(1.0f - RT_T_PAD)));
}

/* Lanes whose segment [tmin, t_cut] meets child c of the wide node at row `base` (inclusive at
 * t_cut, as rt_bvh.h); their entry distances in *t_near. */
RT_FN lanei packet_hits_child(RT_SCENE_PARAMS, const RayPacket *p, lanef t_cut, int base, int c, lanef *t_near)
{
#if RT_PACKET_BOX_FMA
    /* The planes by the packet's shared direction signs: lane vector 2 axis + near of the node */
    lanef t0 = lf_max(lf_max(lf_fms(wide_lane(base + p->nx * WBVH_Q, c), p->ix, p->onx),
                             lf_fms(wide_lane(base + (2 + p->ny) * WBVH_Q, c), p->iy, p->ony)),
                      lf_max(lf_fms(wide_lane(base + (4 + p->nz) * WBVH_Q, c), p->iz, p->onz), p->tmin));
    lanef t1 = lf_min(lf_min(lf_fms(wide_lane(base + (1 - p->nx) * WBVH_Q, c), p->ix, p->ofx),
                             lf_fms(wide_lane(base + (3 - p->ny) * WBVH_Q, c), p->iy, p->ofy)),
                      lf_min(lf_fms(wide_lane(base + (5 - p->nz) * WBVH_Q, c), p->iz, p->ofz), t_cut));
#if RT_CONSERVATIVE
    t1 = lf_mul(t1, lf_splat(RT_BVH_EXIT_SCALE));
#endif
#else
    lanef nx, fx, ny, fy, nz, fz;
    packet_slab(wide_lane(base, c), wide_lane(base + WBVH_Q, c), p->ox, p->ix, p->zx, &nx, &fx);
    packet_slab(wide_lane(base + 2 * WBVH_Q, c), wide_lane(base + 3 * WBVH_Q, c), p->oy, p->iy, p->zy, &ny, &fy);
    packet_slab(wide_lane(base + 4 * WBVH_Q, c), wide_lane(base + 5 * WBVH_Q, c), p->oz, p->iz, p->zz, &nz, &fz);
    lanef t0 = lf_max(lf_max(nx, ny), lf_max(nz, p->tmin));
    lanef t1 = lf_min(lf_min(fx, fy), fz);
#if RT_CONSERVATIVE
    /* widen the far distance by its rounding bound, whichever its sign */
    t1 = lf_max(lf_mul(t1, lf_splat(1.0f + RT_T_PAD)), lf_mul(t1, lf_splat(1.0f - RT_T_PAD)));
#endif
    t1 = lf_min(t1, t_cut);
#endif
    *t_near = t0;
    return lf_le(t0, t1);
}

/* Update the lanes in m whose hit (t, u, v) on triangle tri is closer_hit's: beyond tmin, nearer
 * than their hit so far, or as near on a lower triangle id; returns those lanes. */
RT_FN lanei packet_take_hits(const RayPacket *p, HitPacket *h, lanei m, lanef t, lanef u, lanef v, int tri)
{
    lanei closer = li_or(lf_lt(t, h->t), li_and(lf_eq(t, h->t), li_lt(li_splat(tri), h->tri)));
    m = li_and(m, li_and(lf_lt(p->tmin, t), closer));
    h->t = lf_select(h->t, t, m);
    h->u = lf_select(h->u, u, m);
    h->v = lf_select(h->v, v, m);
    h->tri = li_select(h->tri, li_splat(tri), m);
    return m;
}

/* Moller-Trumbore (lanes_moller) on every lane against triangle tri (v0, v1, v2); updates the
 * lanes it hits nearer than their hit so far and returns them. */
RT_FN lanei packet_tri_moller(const RayPacket *p, HitPacket *h, float3 v0, float3 v1, float3 v2, int tri)
{
    float3 e1 = sub3(v1, v0), e2 = sub3(v2, v0);
    lanef u, v, t;
    lanei m = lanes_moller(p->ox, p->oy, p->oz, p->dx, p->dy, p->dz, lf_splat(v0.x), lf_splat(v0.y), lf_splat(v0.z),
                           lf_splat(e1.x), lf_splat(e1.y), lf_splat(e1.z), lf_splat(e2.x), lf_splat(e2.y),
                           lf_splat(e2.z), &u, &v, &t);
    return packet_take_hits(p, h, m, t, u, v, tri);
}

#if RT_ISECT == RT_ISECT_WATERTIGHT
/* The watertight test (lanes_watertight_edges, then intersect_ray_tri_watertight's distance) on the
 * lanes in `live` against triangle tri; updates the lanes it hits nearer than their hit so far and
 * returns them. */
RT_FN lanei packet_tri_watertight(const RayPacket *p, HitPacket *h, lanei live, float3 v0, float3 v1, float3 v2,
                                  int tri)
{
    /* The vertices moved to each lane's origin in its axis order: by scalars where the axes agree */
    lanef ax, ay, az, bx, by, bz, cx, cy, cz;
    if (p->uniform) {
        ax = lf_sub(lf_splat(get3(v0, p->ukx)), p->okx);
        ay = lf_sub(lf_splat(get3(v0, p->uky)), p->oky);
        az = lf_sub(lf_splat(get3(v0, p->ukz)), p->okz);
        bx = lf_sub(lf_splat(get3(v1, p->ukx)), p->okx);
        by = lf_sub(lf_splat(get3(v1, p->uky)), p->oky);
        bz = lf_sub(lf_splat(get3(v1, p->ukz)), p->okz);
        cx = lf_sub(lf_splat(get3(v2, p->ukx)), p->okx);
        cy = lf_sub(lf_splat(get3(v2, p->uky)), p->oky);
        cz = lf_sub(lf_splat(get3(v2, p->ukz)), p->okz);
    } else {
        lanef x = lf_splat(v0.x), y = lf_splat(v0.y), z = lf_splat(v0.z);
        ax = lf_sub(lf_axis(p->kx, x, y, z), p->okx);
        ay = lf_sub(lf_axis(p->ky, x, y, z), p->oky);
        az = lf_sub(lf_axis(p->kz, x, y, z), p->okz);
        x = lf_splat(v1.x), y = lf_splat(v1.y), z = lf_splat(v1.z);
        bx = lf_sub(lf_axis(p->kx, x, y, z), p->okx);
        by = lf_sub(lf_axis(p->ky, x, y, z), p->oky);
        bz = lf_sub(lf_axis(p->kz, x, y, z), p->okz);
        x = lf_splat(v2.x), y = lf_splat(v2.y), z = lf_splat(v2.z);
        cx = lf_sub(lf_axis(p->kx, x, y, z), p->okx);
        cy = lf_sub(lf_axis(p->ky, x, y, z), p->oky);
        cz = lf_sub(lf_axis(p->kz, x, y, z), p->okz);
    }
    lanef u, v, w, det;
    lanei m = li_and(live, lanes_watertight_edges(ax, ay, az, bx, by, bz, cx, cy, cz, p->sx, p->sy, &u, &v, &w, &det));
    if (!lane_any(m))
        return m;
    lanef inv_det = lf_div(1.0f, det);
#if RT_REFINE_T
    /* The edge functions decide whether; the plane decides where: plane_t_fp64 on every lane (its
     * normal once), a lane's t used only where its edge test passed */
    double nx, ny, nz;
    plane_normal_fp64(v0, v1, v2, &nx, &ny, &nz);
    lanef t = lf_plane_t_fp64(p->ox, p->oy, p->oz, p->dx, p->dy, p->dz, (double)v0.x, (double)v0.y, (double)v0.z, nx,
                              ny, nz);
#else
    lanef t = lf_mul(lf_dot3_scaled(u, v, w, p->sz, az, bz, cz), inv_det);
#endif
    return packet_take_hits(p, h, m, t, lf_mul(v, inv_det), lf_mul(w, inv_det), tri);
}
#endif

#if RT_ISECT != RT_ISECT_MOLLER && RT_ISECT != RT_ISECT_WATERTIGHT
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
    int first = bits >> WBVH_LEAF_BITS;
    int count = bits & ((1 << WBVH_LEAF_BITS) - 1);
    lanei found = li_splat(0);
    for (int i = 0; i < count; ++i) {
        /* triangle i is lane i % RT_LANES of the leaf's block i / RT_LANES */
        int row = first + (i / RT_LANES) * WBVH_BLOCK_ROWS, k = i % RT_LANES;
        int tri = rt_as_int(wide_lane(row + 9 * WBVH_Q, k));
#if RT_ISECT == RT_ISECT_MOLLER || RT_ISECT == RT_ISECT_WATERTIGHT
        float3 v0 = wide_block_vertex(RT_SCENE_ARGS, row, 0, k);
        float3 v1 = wide_block_vertex(RT_SCENE_ARGS, row, 1, k);
        float3 v2 = wide_block_vertex(RT_SCENE_ARGS, row, 2, k);
#endif
#if RT_ISECT == RT_ISECT_MOLLER
        found = li_or(found, packet_tri_moller(p, h, v0, v1, v2, tri));
#elif RT_ISECT == RT_ISECT_WATERTIGHT
        found = li_or(found, packet_tri_watertight(p, h, live, v0, v1, v2, tri));
#else
        found = li_or(found, packet_tri_lanewise(RT_SCENE_ARGS, p, h, live, tri));
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
            int base = WBVH_NODE_ROWS * ref;
            int hit_ref[RT_LANES];
            float hit_t[RT_LANES];
            int n = 0;
            for (int c = 0; c < RT_LANES; ++c) {
                int child = rt_as_int(wide_lane(base + 6 * WBVH_Q, c));
                if (child == WBVH_EMPTY)
                    break;
                lanef t_near;
                lanei m = packet_hits_child(RT_SCENE_ARGS, p, t_cut, base, c, &t_near);
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

/* Whether the packet's live rays are alike enough to walk the tree together: directions of one
 * octant (the sign of each component) and within RT_PACKET_CONE of each other (the cosine of the
 * angle to the first live lane's direction). Camera rays of neighbouring pixels are; diffuse
 * bounces, which share their origin's neighbourhood but not their direction, are not. */
#ifndef RT_PACKET_CONE
#define RT_PACKET_CONE 0.9f
#endif
RT_FN int packet_is_coherent(const RayPacket *p, lanei live)
{
    int bits = lane_bits(live);
    if (bits == 0)
        return 1;
    int k = rt_ctz(bits);
    float x = lf_get(p->dx, k), y = lf_get(p->dy, k), z = lf_get(p->dz, k);
    /* the octant by the inverses' signs, which pick the near planes (-0 counts as negative) */
    lanef zero = lf_splat(0.0f);
    lanei same = li_and(li_and(li_eq(lf_lt(p->ix, zero), li_splat(-p->nx)), li_eq(lf_lt(p->iy, zero), li_splat(-p->ny))),
                        li_eq(lf_lt(p->iz, zero), li_splat(-p->nz)));
    /* d . d0 >= cone |d| |d0|, squared (both sides are >= 0 where the signs agree) */
    lanef dot = lf_dot3s(p->dx, p->dy, p->dz, x, y, z);
    lanef dd = lf_dot3(p->dx, p->dy, p->dz, p->dx, p->dy, p->dz);
    lanei close = lf_le(lf_mul(lf_splat(RT_PACKET_CONE * RT_PACKET_CONE * (x * x + y * y + z * z)), dd), lf_mul(dot, dot));
    return lane_bits(li_and(li_and(same, close), live)) == bits;
}

#endif /* RT_BVH_PACKET_H */
