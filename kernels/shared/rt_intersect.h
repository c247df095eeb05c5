/* rt_intersect.h - ray/triangle tests (§3.1.2, Table 3), the ray/box clip, and the Table 3 loop.
 *
 *   RT_ISECT_MOLLER      Moller & Trumbore 1997: reads the three vertices (tris)
 *   RT_ISECT_WALD        Wald 2004 projection test: reads only its precomputed TriWald (tri_data)
 *   RT_ISECT_PLUCKER     Plucker coordinates of the edges: reads only its TriPlucker (tri_data)
 *   RT_ISECT_WATERTIGHT  Woop, Benthin & Wald 2013: reads the vertices; with RT_CONSERVATIVE on
 *                        (its default, rt_port.h) the box clip here and the kd split choice in
 *                        rt_kdtree.h cannot cull what it finds
 * The precomputed layouts are built by rtlab/accel/tri_data.py (sync with that file).
 *
 * Each test updates *hit only for a hit that closer_hit() accepts (beyond ray->tmin, nearer than
 * hit->t, or at exactly hit->t on a lower triangle id: rt_types.h), and says whether it did. Edges
 * are inclusive and triangles two-sided, as in the float64 reference. A NaN t, a zero-area
 * triangle or a ray parallel to the plane never hits: closer_hit() fails for a NaN t. */
#ifndef RT_INTERSECT_H
#define RT_INTERSECT_H
#include "rt_memory.h"
#include "rt_types.h"

/* Relative rounding bound of a plane distance (p - o) * inv_d: three roundings (subtract, reciprocal,
 * multiply) give gamma(3) = 3u/(1-3u), u = 2^-24; comparing two such distances needs twice that
 * (Ize 2013, "Robust BVH Ray Traversal", JCGT 2(2): pad the far distance; pbrt-v3 multiplies it by
 * 1 + 2 gamma(3)). We take 16u: that bound with room for a reciprocal that is not correctly rounded
 * (NVIDIA OpenCL's 1/x may be off by 2.5 ulp without -cl-fp32-correctly-rounded-divide-sqrt). */
#define RT_T_PAD (16.0f * 5.9604645e-8f)

/* Relative error bound of a triangle distance the closest-hit choice compares: 2 ulps (4u) for the
 * watertight test's plane_t_fp64 (RT_REFINE_T). The tests without that bound (Moller, Wald, Plucker,
 * the watertight test's float-only form) can err by more on small triangles far away or slivers at
 * grazing angles; there the tie rule below holds only as far as their t is right. */
#define RT_T_ERR (4.0f * 5.9604645e-8f)

/* The tie rule's reach (closer_hit, rt_types.h): a cell or box whose entry distance lies beyond
 * t_cull(hit->t) holds no triangle that could beat the hit, one at the same t on a lower id included.
 * An entry distance errs by up to ~7u (three roundings, a reciprocal good to 2.5 ulps) and a triangle's
 * t by RT_T_ERR, so the hit's t is widened by RT_T_PAD (16u) before a cell or box is culled against
 * it, in every traversal and for every test: culling at the unpadded t gave a tie at equal t to
 * different triangles in different traversals (a vertex on a kd split plane, a box entered at the
 * hit's t). max() of the two products widens t of either sign and keeps +-inf. */
RT_FN float t_cull(float t_hit) { return rt_max(t_hit * (1.0f + RT_T_PAD), t_hit * (1.0f - RT_T_PAD)); }

/* Precomputed triangle data in tri_data, float4 rows per triangle (sync with rtlab/accel/tri_data.py). */
#define RT_WALD_ROWS 3
#define RT_PLUCKER_ROWS 6

/* Wald's TriAccel (Wald 2004, §7.1.3), 48 bytes. k: dominant axis of the normal N; (ku, kv) the
 * two others in cyclic order. The plane is p_k + n_u p_ku + n_v p_kv = n_d (N scaled by 1/N_k);
 * the barycentrics of a hit (hu, hv) projected along k are u = hu*eu.x + hv*eu.y + eu.z (weight of
 * v1) and v likewise with ev (weight of v2). Degenerate triangles are stored as NaN (never hit). */
typedef struct {
    float4 plane;   /* n_u, n_v, n_d, k (int bits) */
    float4 eu, ev;  /* w unused */
} TriWald;

/* Plucker coordinates (direction, moment = a x b) of the edges v0->v1, v1->v2, v2->v0, and the
 * plane n . p = n . v0 for t; 96 bytes (88 used). Degenerate triangles are stored as NaN. */
typedef struct {
    float4 d0, m0, d1, m1, d2, m2;   /* w of d0, m0, d1: n.x, n.y, n.z; w of m1: n . v0 */
} TriPlucker;

/* Moller & Trumbore, "Fast, minimum storage ray/triangle intersection", JGT 1997.
 * No epsilon on the determinant (det == 0 only rejects parallel rays and zero-area triangles):
 * an epsilon there drops grazing hits. Edges are inclusive, so a ray through a shared edge hits
 * unless rounding pushes u or v just outside in both triangles (not watertight). Given, not a lab
 * task: it is the default test of the pipeline labs 00 and 01 build on, and lab 02's worked example. */
RT_FN int intersect_ray_tri_moller(const Ray *ray, float3 v0, float3 v1, float3 v2, int tri, Hit *hit)
{
    float3 e1 = sub3(v1, v0);
    float3 e2 = sub3(v2, v0);
    float3 p = cross3(ray->d, e2);
    float det = dot3(e1, p);
    if (det == 0.0f)
        return 0;
    float inv_det = 1.0f / det;
    float3 s = sub3(ray->o, v0);
    float u = dot3(s, p) * inv_det;
    if (u < 0.0f || u > 1.0f)
        return 0;
    float3 q = cross3(s, e1);
    float v = dot3(ray->d, q) * inv_det;
    if (v < 0.0f || u + v > 1.0f)
        return 0;
    float t = dot3(e2, q) * inv_det;
    if (!closer_hit(ray, t, tri, hit))
        return 0;
    hit->t = t;
    hit->u = u;
    hit->v = v;
    hit->tri = tri;
    return 1;
}

/* Wald's projection test (Wald 2004, PhD thesis, §7.1.3; the paper's "Projection [17]"): plane
 * distance first, then the hit point projected along the normal's dominant axis k, barycentrics
 * from two precomputed edge equations. Scalar work, no vertex reads; the price is precision far
 * from the origin, where n_d and the edge offsets are large and cancel. */
RT_FN int intersect_ray_tri_wald(const Ray *ray, const TriWald *acc, int tri, Hit *hit)
{
    /* BEGIN SOLUTION */
    int k = rt_as_int(acc->plane.w);
    int ku = k == 2 ? 0 : k + 1;
    int kv = ku == 2 ? 0 : ku + 1;
    float dk = get3(ray->d, k), du = get3(ray->d, ku), dv = get3(ray->d, kv);
    float ok = get3(ray->o, k), ou = get3(ray->o, ku), ov = get3(ray->o, kv);
    /* A ray parallel to the plane gives inf or NaN here; the t test rejects both */
    float inv_nd = 1.0f / (dk + acc->plane.x * du + acc->plane.y * dv);
    float t = (acc->plane.z - ok - acc->plane.x * ou - acc->plane.y * ov) * inv_nd;
    if (!closer_hit(ray, t, tri, hit))
        return 0;
    float hu = ou + t * du;
    float hv = ov + t * dv;
    float u = hu * acc->eu.x + hv * acc->eu.y + acc->eu.z;
    if (u < 0.0f)
        return 0;
    float v = hu * acc->ev.x + hv * acc->ev.y + acc->ev.z;
    if (v < 0.0f || u + v > 1.0f)
        return 0;
    hit->t = t;
    hit->u = u;
    hit->v = v;
    hit->tri = tri;
    return 1;
    /* END SOLUTION */
}

/* Plucker test (Erickson 1997, Shoemake 1998; the paper's [3, 14, 1]): the ray L = (d, o x d)
 * passes through the triangle when its permuted inner products with the three edges,
 * side(L, E) = d . m_E + d_E . (o x d), share a sign (zero included: inclusive edges). The two
 * triangles of a shared edge store exactly negated coordinates, so they disagree on no ray; but
 * o x d and the moments grow with the distance from the origin and cancel in each sum.
 * Each side product is the barycentric weight of the opposite vertex times a common factor. */
RT_FN int intersect_ray_tri_plucker(const Ray *ray, const TriPlucker *acc, int tri, Hit *hit)
{
    /* BEGIN SOLUTION */
    float3 m = cross3(ray->o, ray->d);
    float s0 = dot3(ray->d, xyz(acc->m0)) + dot3(xyz(acc->d0), m);   /* weight of v2 */
    float s1 = dot3(ray->d, xyz(acc->m1)) + dot3(xyz(acc->d1), m);   /* weight of v0 */
    float s2 = dot3(ray->d, xyz(acc->m2)) + dot3(xyz(acc->d2), m);   /* weight of v1 */
    if ((s0 < 0.0f || s1 < 0.0f || s2 < 0.0f) && (s0 > 0.0f || s1 > 0.0f || s2 > 0.0f))
        return 0;
    float sum = s0 + s1 + s2;
    if (!(sum < 0.0f || sum > 0.0f))       /* zero, or NaN (an overflowing product): a miss */
        return 0;
    float3 n = f3(acc->d0.w, acc->m0.w, acc->d1.w);
    float t = (acc->m1.w - dot3(n, ray->o)) / dot3(n, ray->d);
    if (!closer_hit(ray, t, tri, hit))
        return 0;
    float inv_sum = 1.0f / sum;
    hit->t = t;
    hit->u = s2 * inv_sum;
    hit->v = s0 * inv_sum;
    hit->tri = tri;
    return 1;
    /* END SOLUTION */
}

/* Components of a in the order (kx, ky, kz). */
RT_FN float3 permute3(float3 a, int kx, int ky, int kz) { return f3(get3(a, kx), get3(a, ky), get3(a, kz)); }

/* The watertight test's distance: RT_REFINE_T 1 (the default where the device has doubles) takes
 * plane_t_fp64's, 0 Woop et al.'s scaled-barycentric t (kept to measure what the refinement costs). */
#ifndef RT_REFINE_T
#define RT_REFINE_T RT_HAS_FP64
#endif
#if RT_REFINE_T && !RT_HAS_FP64
#error "RT_REFINE_T needs double precision (RT_HAS_FP64)"
#endif

#if RT_HAS_FP64
/* Distance along the ray o + t d to the plane of (v0, v1, v2): t = n.(v0 - o) / n.d with
 * n = (v1 - v0) x (v2 - v0), in double. Woop et al.'s t, sum of the scaled barycentrics times the
 * vertices' depths, is off by the barycentrics' rounding times the triangle's depth range: -0.6 %
 * on a 3.3 x 0.013 sliver seen at |cos| = 0.002. Here the float differences are exact in double
 * and so are the cross product's products (24-bit by 24-bit), so n is exact but for one rounding
 * a component, and the two dot products err by a few double ulps over the cosine of the angle the
 * ray (and v0 - o) make with the plane: t lands within an ulp of float of the exact distance down
 * to |cos| ~ 1e-7 (RT_T_ERR), on triangles of any shape. (An origin nearer the plane than ~2^-30
 * |v0 - o|, one on the triangle above all, gets a t whose sign is rounding's: spawned rays start off
 * the surface.) Pure and branch-free, so a lane version is
 * the same expressions on double lanes. A ray parallel to the plane gives an inf or NaN t, which
 * closer_hit() rejects. */
RT_FN void plane_normal_fp64(float3 v0, float3 v1, float3 v2, double *nx, double *ny, double *nz)
{
    double ax = (double)v1.x - (double)v0.x, ay = (double)v1.y - (double)v0.y, az = (double)v1.z - (double)v0.z;
    double bx = (double)v2.x - (double)v0.x, by = (double)v2.y - (double)v0.y, bz = (double)v2.z - (double)v0.z;
    *nx = ay * bz - az * by;
    *ny = az * bx - ax * bz;
    *nz = ax * by - ay * bx;
}

/* plane_t_fp64 for a normal n from plane_normal_fp64 (the lane tests share n between their lanes:
 * rt_lanes.h's lf_plane_t_fp64 is this expression on each lane) */
RT_FN float plane_t_fp64_n(float3 o, float3 d, float3 v0, double nx, double ny, double nz)
{
    double num = nx * ((double)v0.x - (double)o.x) + ny * ((double)v0.y - (double)o.y) + nz * ((double)v0.z - (double)o.z);
    double den = nx * (double)d.x + ny * (double)d.y + nz * (double)d.z;
    return (float)(num / den);
}

/* RT_REFINE_CALL (rt_port.h's default by language): 1 makes plane_t_fp64 a call, its doubles off the
 * traversal's registers */
#if RT_REFINE_CALL
RT_FN_NOINLINE
#else
RT_FN
#endif
float plane_t_fp64(float3 o, float3 d, float3 v0, float3 v1, float3 v2)
{
    double nx, ny, nz;
    plane_normal_fp64(v0, v1, v2, &nx, &ny, &nz);
    return plane_t_fp64_n(o, d, v0, nx, ny, nz);
}
#endif

#if RT_HAS_FP64
/* Below this magnitude a float edge function of the watertight test may have lost its sign: it is zero
 * (a ray through the edge, where the rounded products came out equal) or its products underflowed (a
 * triangle whose sheared coordinates are under ~1e-19, as small triangles are anywhere). At or above
 * 2^-100 the two products err by no more than a normal rounding each. */
#define RT_EDGE_TINY 7.8886091e-31f

/* The watertight test's edge functions whose float values (*u, *v, *w) are below RT_EDGE_TINY, recomputed
 * in double from the same sheared coordinates: a product of two floats is exact in double, so the sign
 * is right. Each edge function takes this path on its own value alone, and the two triangles of a shared
 * edge compute exactly negated values, so both decide it alike: no ray slips between them. When all
 * three are that small they are scaled by 2^200 before they are rounded back to float, so that none
 * underflows (det = u + v + w then cannot vanish, nor 1 / det overflow): a nonzero difference of
 * products of floats is at least 2^-298 and these are below 2^-99, so all land in float's normal range;
 * signs and the barycentrics' ratios stay, and no division enters the traversal's code.
 * The lane test (rt_intersect_lanes.h) calls this too. */
RT_FN void watertight_edges_fp64(float ax2, float ay2, float bx2, float by2, float cx2, float cy2,
                                 float *u, float *v, float *w)
{
    double eu = (double)cx2 * (double)by2 - (double)cy2 * (double)bx2;
    double ev = (double)ax2 * (double)cy2 - (double)ay2 * (double)cx2;
    double ew = (double)bx2 * (double)ay2 - (double)by2 * (double)ax2;
    int tiny_u = rt_abs(*u) < RT_EDGE_TINY, tiny_v = rt_abs(*v) < RT_EDGE_TINY, tiny_w = rt_abs(*w) < RT_EDGE_TINY;
    double scale = tiny_u && tiny_v && tiny_w ? 1.6069380442589903e60 : 1.0;     /* 2^200 */
    if (tiny_u)
        *u = (float)(eu * scale);
    if (tiny_v)
        *v = (float)(ev * scale);
    if (tiny_w)
        *w = (float)(ew * scale);
}
#endif

/* Woop, Benthin & Wald, "Watertight Ray/Triangle Intersection", JCGT 2(1), 2013. Vertices are
 * moved to the ray origin and sheared so that the ray runs along +z; the 2D edge functions U, V, W
 * of the sheared vertices then depend on the edge's two corners only, so the triangles of a shared
 * edge compute exactly negated values and no ray slips between them. Where an edge function is
 * zero or tiny it is recomputed in double (watertight_edges_fp64; RT_HAS_FP64, rt_port.h). The shear is
 * recomputed per triangle (Ray has no spare fields); the compiler hoists it out of Table 3's loop. */
RT_FN int intersect_ray_tri_watertight(const Ray *ray, float3 v0, float3 v1, float3 v2, int tri, Hit *hit)
{
    /* BEGIN SOLUTION */
    /* Permute so that kz is the direction's largest component; swap kx, ky to keep the winding */
    float ax = rt_abs(ray->d.x), ay = rt_abs(ray->d.y), az = rt_abs(ray->d.z);
    int kz = ax > ay ? (ax > az ? 0 : 2) : (ay > az ? 1 : 2);
    int kx = kz == 2 ? 0 : kz + 1;
    int ky = kx == 2 ? 0 : kx + 1;
    if (get3(ray->d, kz) < 0.0f) {
        int swap = kx;
        kx = ky;
        ky = swap;
    }
    float sz = get3(ray->inv_d, kz);
    float sx = get3(ray->d, kx) * sz;
    float sy = get3(ray->d, ky) * sz;
    /* Translate to the origin, then shear: each vertex is transformed on its own */
    float3 a = permute3(sub3(v0, ray->o), kx, ky, kz);
    float3 b = permute3(sub3(v1, ray->o), kx, ky, kz);
    float3 c = permute3(sub3(v2, ray->o), kx, ky, kz);
    float ax2 = a.x - sx * a.z, ay2 = a.y - sy * a.z;
    float bx2 = b.x - sx * b.z, by2 = b.y - sy * b.z;
    float cx2 = c.x - sx * c.z, cy2 = c.y - sy * c.z;
    float u = diff_of_products_rn(cx2, by2, cy2, bx2);
    float v = diff_of_products_rn(ax2, cy2, ay2, cx2);
    float w = diff_of_products_rn(bx2, ay2, by2, ax2);
#if RT_HAS_FP64
    /* Fall back to double at an edge (the float products may have rounded to equal values) and where
     * they may have underflowed: one compare each, as the test for zero was */
    if (rt_abs(u) < RT_EDGE_TINY || rt_abs(v) < RT_EDGE_TINY || rt_abs(w) < RT_EDGE_TINY)
        watertight_edges_fp64(ax2, ay2, bx2, by2, cx2, cy2, &u, &v, &w);
#endif
    /* Without double a zero stays zero: an inclusive edge, so both neighbours hit (conservative) */
    if ((u < 0.0f || v < 0.0f || w < 0.0f) && (u > 0.0f || v > 0.0f || w > 0.0f))
        return 0;
    float det = u + v + w;
    /* Zero, or NaN: products overflowing far beyond the scene scales rtlab accepts pass the sign
     * test above as NaN, and miss here rather than hit (an ordered compare, no dearer than == 0) */
    if (!(det < 0.0f || det > 0.0f))
        return 0;
#if RT_REFINE_T
    /* The edge functions decide whether; the plane decides where (plane_t_fp64) */
    float t = plane_t_fp64(ray->o, ray->d, v0, v1, v2);
    float inv_det = 1.0f / det;
#else
    float tz = u * (sz * a.z) + v * (sz * b.z) + w * (sz * c.z);
    float inv_det = 1.0f / det;
    float t = tz * inv_det;
#endif
    if (!closer_hit(ray, t, tri, hit))
        return 0;
    hit->t = t;
    hit->u = v * inv_det;
    hit->v = w * inv_det;
    hit->tri = tri;
    return 1;
    /* END SOLUTION */
}

/* The test chosen by RT_ISECT among those that read the vertices (Moller, watertight), on vertices
 * already loaded (from tris, or from a BVH's leaf-ordered copy: rt_bvh.h's RT_BVH_LEAF_TRIS). */
RT_FN int intersect_tri_vertices(const Ray *ray, float3 v0, float3 v1, float3 v2, int tri, Hit *hit)
{
#if RT_ISECT == RT_ISECT_WATERTIGHT
    return intersect_ray_tri_watertight(ray, v0, v1, v2, tri, hit);
#else
    return intersect_ray_tri_moller(ray, v0, v1, v2, tri, hit);
#endif
}

/* The test chosen by RT_ISECT, on triangle tri of the scene (the paper's Table 3 variable). */
RT_FN int intersect_tri(RT_SCENE_PARAMS, const Ray *ray, int tri, Hit *hit)
{
#if RT_ISECT == RT_ISECT_WALD
    TriWald acc;
    acc.plane = load_tri_data(tri_data, RT_WALD_ROWS * tri);
    acc.eu = load_tri_data(tri_data, RT_WALD_ROWS * tri + 1);
    acc.ev = load_tri_data(tri_data, RT_WALD_ROWS * tri + 2);
    return intersect_ray_tri_wald(ray, &acc, tri, hit);
#elif RT_ISECT == RT_ISECT_PLUCKER
    TriPlucker acc;
    acc.d0 = load_tri_data(tri_data, RT_PLUCKER_ROWS * tri);
    acc.m0 = load_tri_data(tri_data, RT_PLUCKER_ROWS * tri + 1);
    acc.d1 = load_tri_data(tri_data, RT_PLUCKER_ROWS * tri + 2);
    acc.m1 = load_tri_data(tri_data, RT_PLUCKER_ROWS * tri + 3);
    acc.d2 = load_tri_data(tri_data, RT_PLUCKER_ROWS * tri + 4);
    acc.m2 = load_tri_data(tri_data, RT_PLUCKER_ROWS * tri + 5);
    return intersect_ray_tri_plucker(ray, &acc, tri, hit);
#else
    return intersect_tri_vertices(ray, xyz(load_tri_vertex(tris, tri, 0)), xyz(load_tri_vertex(tris, tri, 1)),
                                  xyz(load_tri_vertex(tris, tri, 2)), tri, hit);
#endif
}

/* The paper's Table 3 kernel body: "the first 1000 triangles of the scene in a for-loop", no
 * acceleration structure; closest hit over triangles [0, n_tris). */
RT_FN void intersect_first_tris(RT_SCENE_PARAMS, const Ray *ray, int n_tris, Hit *hit)
{
    for (int tri = 0; tri < n_tris; ++tri)
        intersect_tri(RT_SCENE_ARGS, ray, tri, hit);
}

/* One slab of the box test: near and far plane by the sign of the direction, distances in the
 * (b - o) * inv_d form. inv_far is inv_d, or with RT_CONSERVATIVE inv_d padded by RT_T_PAD (Ize 2013),
 * so rounding cannot cull a box the exact ray enters. A zero direction component gives +-inf; the
 * NaN of 0 * inf (origin exactly on the plane) is dropped by fmin/fmax, which keeps the ray. */
RT_FN void clip_slab(float lo, float hi, float o, float inv_d, float inv_far, float *t0, float *t1)
{
    int forward = inv_d >= 0.0f;
    *t0 = rt_max(*t0, ((forward ? lo : hi) - o) * inv_d);
    *t1 = rt_min(*t1, ((forward ? hi : lo) - o) * inv_far);
}

/* Recompute the closest hit's distance from the triangle's plane, t = n.(v0 - o) / n.d with
 * n = e1 x e2. Moller-Trumbore's t = e2.(s x e1) / det cancels badly when the origin is far from a
 * small triangle seen at a grazing angle (1.8e-5 relative on SPONZA); the plane form stays near
 * float32 rounding. Done once per ray, so the intersection loop is unchanged. The watertight test
 * with RT_REFINE_T compares plane_t_fp64's distance already, which this float form would only
 * degrade: left as it is. */
RT_FN void refine_hit_t(RT_SCENE_PARAMS, const Ray *ray, Hit *hit)
{
#if !(RT_ISECT == RT_ISECT_WATERTIGHT && RT_REFINE_T)
    if (hit->tri < 0)
        return;
    float3 v0 = xyz(load_hit_vertex(tris, hit->tri, 0));
    float3 n = cross3(sub3(xyz(load_hit_vertex(tris, hit->tri, 1)), v0), sub3(xyz(load_hit_vertex(tris, hit->tri, 2)), v0));
    float t = dot3(n, sub3(v0, ray->o)) / dot3(n, ray->d);
    if (t > ray->tmin && t < ray->tmax)
        hit->t = t;
#endif
}

/* Whether the ray can enter any box: finite origin and direction, a non-zero direction. */
RT_FN int ray_can_enter(const Ray *ray)
{
    return finite3(ray->o) && finite3(ray->d) && dot3(ray->d, ray->d) > 0.0f;
}

/* Clip a ray that can enter boxes (ray_can_enter) to an axis-aligned box: slab test (Kay &
 * Kajiya). Traversals that test many boxes check the ray once, then call this per box. */
RT_FN int clip_entering_ray_box(const Ray *ray, float4 bmin, float4 bmax, float *t_enter, float *t_exit)
{
#if RT_CONSERVATIVE
    float3 inv_far = mul3(ray->inv_d, 1.0f + RT_T_PAD);
#else
    float3 inv_far = ray->inv_d;
#endif
    float t0 = ray->tmin, t1 = ray->tmax;
    clip_slab(bmin.x, bmax.x, ray->o.x, ray->inv_d.x, inv_far.x, &t0, &t1);
    clip_slab(bmin.y, bmax.y, ray->o.y, ray->inv_d.y, inv_far.y, &t0, &t1);
    clip_slab(bmin.z, bmax.z, ray->o.z, ray->inv_d.z, inv_far.z, &t0, &t1);
    *t_enter = t0;
    *t_exit = t1;
    return t0 <= t1;
}

/* Clip the ray to an axis-aligned box. Rays with NaN/Inf origin or direction, or a zero
 * direction, never enter. */
RT_FN int clip_ray_box(const Ray *ray, float4 bmin, float4 bmax, float *t_enter, float *t_exit)
{
    return ray_can_enter(ray) && clip_entering_ray_box(ray, bmin, bmax, t_enter, t_exit);
}

#endif /* RT_INTERSECT_H */
