/* rt_intersect_lanes.h - the triangle tests of rt_intersect.h on RT_LANES ray/triangle pairs at once
 * (rt_lanes.h): the CPU traversals' inner loops. The packet traversal (rt_bvh_packet.h) pairs its
 * RT_LANES rays with one triangle, the wide BVH (rt_bvh_wide.h) one ray with a block of RT_LANES
 * triangles; either passes the side that is one value as a splat.
 *
 * Each function is the scalar test's arithmetic, expression for expression (rt_lanes.h's helpers
 * round and contract as the scalar code does), so a lane decides every ray/triangle pair as
 * intersect_ray_tri_moller or intersect_ray_tri_watertight decides it: every traversal returns the
 * same triangle and t (tests/test_cpu.py checks against the scalar traversals). What depends on the
 * closest hit so far (closer_hit's tie rule) stays with the caller.
 *
 * The watertight test's lane form would show lab 02's solution, so its bodies are the course's
 * regions (rtlab.course.kernel_sources.COURSE_REGIONS): stubbed in every student tree, where the library's CPU
 * default falls back to the scalar test (rtlab.device.tracing.default_variant).
 */
#ifndef RT_INTERSECT_LANES_H
#define RT_INTERSECT_LANES_H
#include "rt_intersect.h"
#include "rt_lanes.h"

/* Moller-Trumbore (intersect_ray_tri_moller) on the lanes: rays o + t d, triangles v0 with edges
 * e1 = v1 - v0, e2 = v2 - v0. Returns the lanes whose ray crosses the triangle (det != 0, u and v
 * inside), with u, v and t; the caller applies tmin and the closest hit. */
RT_FN lanei lanes_moller(lanef ox, lanef oy, lanef oz, lanef dx, lanef dy, lanef dz, lanef v0x, lanef v0y, lanef v0z,
                         lanef e1x, lanef e1y, lanef e1z, lanef e2x, lanef e2y, lanef e2z, lanef *u, lanef *v, lanef *t)
{
    lanef px = lf_diff_mul(dy, e2z, dz, e2y);
    lanef py = lf_diff_mul(dz, e2x, dx, e2z);
    lanef pz = lf_diff_mul(dx, e2y, dy, e2x);
    lanef det = lf_dot3(e1x, e1y, e1z, px, py, pz);
    lanef inv_det = lf_div(1.0f, det);
    lanef sx = lf_sub(ox, v0x), sy = lf_sub(oy, v0y), sz = lf_sub(oz, v0z);
    *u = lf_mul(lf_dot3(sx, sy, sz, px, py, pz), inv_det);
    lanef qx = lf_diff_mul(sy, e1z, sz, e1y);
    lanef qy = lf_diff_mul(sz, e1x, sx, e1z);
    lanef qz = lf_diff_mul(sx, e1y, sy, e1x);
    *v = lf_mul(lf_dot3(dx, dy, dz, qx, qy, qz), inv_det);
    *t = lf_mul(lf_dot3(e2x, e2y, e2z, qx, qy, qz), inv_det);
    lanef zero = lf_splat(0.0f), one = lf_splat(1.0f);
    lanei inside = li_and(li_and(lf_le(zero, *u), lf_le(*u, one)), li_and(lf_le(zero, *v), lf_le(lf_add(*u, *v), one)));
    return li_andnot(inside, lf_eq(det, zero));
}

/* The per-ray part of Woop et al.'s watertight test (intersect_ray_tri_watertight): the axes
 * (kx, ky, kz), kz the direction's largest, kx and ky swapped where d[kz] < 0 to keep the winding,
 * and the shear s = (d[kx] / d[kz], d[ky] / d[kz], 1 / d[kz]) with 1 / d[kz] as make_ray rounds it. */
typedef struct {
    int kx, ky, kz;
    float sx, sy, sz;
} WatertightAxes;

RT_FN WatertightAxes watertight_axes(float3 d)
{
    /* BEGIN SOLUTION */
    /* STUB: WatertightAxes w = {0, 1, 2, 0.0f, 0.0f, 1.0f}; return w; */
    WatertightAxes w;
    float ax = rt_abs(d.x), ay = rt_abs(d.y), az = rt_abs(d.z);
    w.kz = ax > ay ? (ax > az ? 0 : 2) : (ay > az ? 1 : 2);
    w.kx = w.kz == 2 ? 0 : w.kz + 1;
    w.ky = w.kx == 2 ? 0 : w.kx + 1;
    if (get3(d, w.kz) < 0.0f) {
        int swap = w.kx;
        w.kx = w.ky;
        w.ky = swap;
    }
    w.sz = 1.0f / get3(d, w.kz);
    w.sx = get3(d, w.kx) * w.sz;
    w.sy = get3(d, w.ky) * w.sz;
    return w;
    /* END SOLUTION */
}

/* Woop's edge functions on the lanes: a, b, c the triangle's vertices minus the ray origin, in the
 * ray's axis order (a = (v0 - o)[kx, ky, kz]), sheared by (sx, sy). Where an edge function is
 * zero or tiny it is recomputed in double, by the scalar test's watertight_edges_fp64 (RT_HAS_FP64). Returns
 * the lanes whose ray passes through the triangle (u, v, w of one sign, zeros included, and
 * det = u + v + w != 0), with u, v, w and det. */
RT_FN lanei lanes_watertight_edges(lanef ax, lanef ay, lanef az, lanef bx, lanef by, lanef bz, lanef cx, lanef cy,
                                   lanef cz, lanef sx, lanef sy, lanef *u, lanef *v, lanef *w, lanef *det)
{
    /* BEGIN SOLUTION */
    /* STUB: *u = *v = *w = *det = lf_splat(0.0f); return li_splat(0); */
    lanef ax2 = lf_sub_mul(ax, sx, az), ay2 = lf_sub_mul(ay, sy, az);
    lanef bx2 = lf_sub_mul(bx, sx, bz), by2 = lf_sub_mul(by, sy, bz);
    lanef cx2 = lf_sub_mul(cx, sx, cz), cy2 = lf_sub_mul(cy, sy, cz);
    lanef e0 = lf_diff_of_products_rn(cx2, by2, cy2, bx2);
    lanef e1 = lf_diff_of_products_rn(ax2, cy2, ay2, cx2);
    lanef e2 = lf_diff_of_products_rn(bx2, ay2, by2, ax2);
    lanef zero = lf_splat(0.0f);
#if RT_HAS_FP64
    lanef tiny = lf_splat(RT_EDGE_TINY);
    lanei at_edge = li_or(li_or(lf_lt(lf_abs(e0), tiny), lf_lt(lf_abs(e1), tiny)), lf_lt(lf_abs(e2), tiny));
    if (lane_any(at_edge)) {
        /* rare (a ray through an edge, a tiny triangle): the scalar test's fallback, a lane at a time */
        for (int k = 0; k < RT_LANES; ++k) {
            if (!li_get(at_edge, k))
                continue;
            float u0 = lf_get(e0, k), v0 = lf_get(e1, k), w0 = lf_get(e2, k);
            watertight_edges_fp64(lf_get(ax2, k), lf_get(ay2, k), lf_get(bx2, k), lf_get(by2, k), lf_get(cx2, k),
                                  lf_get(cy2, k), &u0, &v0, &w0);
            lf_set(&e0, k, u0);
            lf_set(&e1, k, v0);
            lf_set(&e2, k, w0);
        }
    }
#endif
    /* one sign, zeros included; a NaN (an overflowing product) has none, so it misses */
    lanei nonnegative = li_and(li_and(lf_le(zero, e0), lf_le(zero, e1)), lf_le(zero, e2));
    lanei nonpositive = li_and(li_and(lf_le(e0, zero), lf_le(e1, zero)), lf_le(e2, zero));
    *u = e0;
    *v = e1;
    *w = e2;
    *det = lf_add(lf_add(e0, e1), e2);
    return li_andnot(li_or(nonnegative, nonpositive), lf_eq(*det, zero));
    /* END SOLUTION */
}

#endif /* RT_INTERSECT_LANES_H */
