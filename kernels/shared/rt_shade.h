/* rt_shade.h - simple shading: the paper's Table 4 setting (primary rays, Lambert, no shadows),
 * and the surface record every shading model starts from (rt_whitted.h builds on it).
 * The float64 references (rtlab/reference/shading.py, rtlab/reference/whitted.py) implement the
 * same formulas. */
#ifndef RT_SHADE_H
#define RT_SHADE_H
#include "rt_intersect.h"
#include "rt_memory.h"
#include "rt_types.h"

/* The unit geometric normal of triangle (v0, v1, v2), (v1 - v0) x (v2 - v0) normalised. Where the device
 * has doubles the cross product is plane_normal_fp64's (the float differences and their products are
 * exact in double), normalised in double and rounded once to float: its direction lies within a few
 * ulps of the plane's on a triangle of any shape and size. The float cross product errs by about
 * u / sin of the triangle's sharpest corner, 1.7e-5 rad on a 10 x 0.01 sliver, and spawn_origin takes
 * its side from this normal: a ray leaving such a sliver at a grazing angle started on the wrong side
 * and came back into its own triangle. Normalised in float, the squared length underflows on a
 * triangle of legs under ~1e-11 (a NaN normal, an unlit face). rtlab.spawn_rays forms the same normal
 * (rtlab/device/spawn.py). */
RT_FN float3 geometric_normal(float3 v0, float3 v1, float3 v2)
{
#if RT_HAS_FP64
    double nx, ny, nz;
    plane_normal_fp64(v0, v1, v2, &nx, &ny, &nz);
    double inv_length = 1.0 / sqrt(nx * nx + ny * ny + nz * nz);
    return f3((float)(nx * inv_length), (float)(ny * inv_length), (float)(nz * inv_length));
#else
    return normalize3(cross3(sub3(v1, v0), sub3(v2, v0)));
#endif
}

/* Surface normal at a hit: interpolated vertex normals or the flat geometric normal, turned to
 * face the incoming ray. */
RT_FN float3 hit_normal(RT_SCENE_PARAMS, const Ray *ray, const Hit *hit)
{
#if RT_SMOOTH_NORMALS
    float w = 1.0f - hit->u - hit->v;
    float3 n = mul3(xyz(load_tri_normal(normals, hit->tri, 0)), w);
    n = madd3(n, xyz(load_tri_normal(normals, hit->tri, 1)), hit->u);
    n = madd3(n, xyz(load_tri_normal(normals, hit->tri, 2)), hit->v);
    float length2 = dot3(n, n);
    /* no direction (a file's "vn 0 0 0", or corners' normals that cancel): the flat normal */
    n = length2 > 0.0f ? mul3(n, 1.0f / rt_sqrt(length2))
                       : geometric_normal(xyz(load_hit_vertex(tris, hit->tri, 0)), xyz(load_hit_vertex(tris, hit->tri, 1)),
                                          xyz(load_hit_vertex(tris, hit->tri, 2)));
#else
    float3 n = geometric_normal(xyz(load_hit_vertex(tris, hit->tri, 0)), xyz(load_hit_vertex(tris, hit->tri, 1)),
                                xyz(load_hit_vertex(tris, hit->tri, 2)));
#endif
    return dot3(n, ray->d) > 0.0f ? mul3(n, -1.0f) : n;
}

/* Lambert from point lights plus a constant ambient term, no shadows:
 * c = kd * (ambient + sum_l max(0, n.l) * light_l). */
RT_FN float3 shade_lambert(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                           RT_CONST const RtMaterial *materials, const Ray *ray, const Hit *hit)
{
    if (hit->tri < 0)
        return xyz(frame->background);
    float3 p = madd3(ray->o, ray->d, hit->t);
    float3 n = hit_normal(RT_SCENE_ARGS, ray, hit);
    float3 kd = xyz(materials[load_tri_material(tri_materials, hit->tri)].diffuse);
    float ambient = frame->background.w;
    float3 c = mul3(kd, ambient);
    for (int i = 0; i < frame->n_lights; ++i) {
        float3 l = normalize3(sub3(xyz(lights[i].position), p));
        float lambert = rt_max(dot3(n, l), 0.0f);
        c = add3(c, mul3(hadamard3(kd, xyz(lights[i].color)), lambert));
    }
    return c;
}

/* Pack a linear colour clamped to [0, 1] into RGBA8 (alpha 255), rounding to nearest. */
RT_FN unsigned int pack_rgba8(float3 c)
{
    unsigned int r = (unsigned int)(rt_min(rt_max(c.x, 0.0f), 1.0f) * 255.0f + 0.5f);
    unsigned int g = (unsigned int)(rt_min(rt_max(c.y, 0.0f), 1.0f) * 255.0f + 0.5f);
    unsigned int b = (unsigned int)(rt_min(rt_max(c.z, 0.0f), 1.0f) * 255.0f + 0.5f);
    return r | (g << 8) | (b << 16) | (255u << 24);
}

/* What shading and secondary rays need to know about a hit. Normals face the incoming ray. */
typedef struct {
    float3 p;        /* hit point from the barycentrics (see hit_position) */
    float p_err;     /* bound on p's rounding error per coordinate (see position_error) */
    float3 ng;       /* unit geometric normal: the side rays leave from (spawn offsets, shadows) */
    float3 ns;       /* unit shading normal: interpolated vertex normals, or ng when flat */
    int front;       /* the ray hit the counter-clockwise side: it enters a transparent object */
    int material;
} Surface;

/* The hit point as b0 v0 + b1 v1 + b2 v2: its error is a few ulps of the vertex coordinates,
 * whereas o + t d carries the error of t times the ray length (Wachter & Binder, Ray Tracing
 * Gems ch. 6, sec. 6.2.1). Far from the origin only the former keeps spawn offsets small. */
RT_FN float3 hit_position(float3 v0, float3 v1, float3 v2, const Hit *hit)
{
    float3 p = mul3(v0, 1.0f - hit->u - hit->v);
    p = madd3(p, v1, hit->u);
    return madd3(p, v2, hit->v);
}

/* Rounding bound of a hit point's coordinates on triangle (v0, v1, v2): gamma(RT_SPAWN_ULPS) times
 * the triangle's largest |vertex coordinate| M. hit_position's three products and two sums, with
 * weights 1 - u - v, u, v that sum to 1 within two roundings, err by at most gamma(5) sum |b_i v_i|
 * <= gamma(5) M per coordinate; pbrt-v4 (4th ed., sec. 6.8, "Managing Rounding Error") bounds its
 * own interpolation by gamma(7) sum |b_i v_i|, which we take: the two ulps over ours cover the t error
 * a ray/triangle test makes for a ray leaving the triangle (measured: gamma(1) still shows acne on a
 * large floor at the origin, gamma(2) none). The watertight test's refined t (plane_t_fp64, within
 * RT_T_ERR of the exact distance) puts the triangle a spawned ray leaves at t < 0 for any origin on
 * the right side of its plane, which the offset guarantees; rtlab.spawn_rays reads RT_SPAWN_ULPS too. The bound follows the triangle's magnitude, so a spawned ray
 * clears its own surface at any distance from the origin, without the fixed 256 ulps that speckled a
 * glass sphere at 1e4 (the robustness suite's family 11). */
#ifndef RT_SPAWN_ULPS
#define RT_SPAWN_ULPS 7             /* n of gamma(n); an integer (-D) */
#endif
RT_FN float position_error(float3 v0, float3 v1, float3 v2)
{
    float3 a = f3(rt_max(rt_abs(v0.x), rt_max(rt_abs(v1.x), rt_abs(v2.x))),
                  rt_max(rt_abs(v0.y), rt_max(rt_abs(v1.y), rt_abs(v2.y))),
                  rt_max(rt_abs(v0.z), rt_max(rt_abs(v1.z), rt_abs(v2.z))));
    float u = (float)RT_SPAWN_ULPS * 5.9604645e-8f;     /* gamma(n) = n u / (1 - n u), u = 2^-24 */
    return rt_max(a.x, rt_max(a.y, a.z)) * (u / (1.0f - u));
}

/* Surface record of a hit (hit->tri >= 0) of a ray with direction d. */
RT_FN Surface surface_at(RT_SCENE_PARAMS, float3 d, const Hit *hit)
{
    Surface s;
    float3 v0 = xyz(load_hit_vertex(tris, hit->tri, 0));
    float3 v1 = xyz(load_hit_vertex(tris, hit->tri, 1));
    float3 v2 = xyz(load_hit_vertex(tris, hit->tri, 2));
    s.p = hit_position(v0, v1, v2, hit);
    s.p_err = position_error(v0, v1, v2);
    float3 ng = geometric_normal(v0, v1, v2);
    s.front = dot3(ng, d) < 0.0f;
    s.ng = s.front ? ng : mul3(ng, -1.0f);
#if RT_SMOOTH_NORMALS
    float3 ns = mul3(xyz(load_tri_normal(normals, hit->tri, 0)), 1.0f - hit->u - hit->v);
    ns = madd3(ns, xyz(load_tri_normal(normals, hit->tri, 1)), hit->u);
    ns = madd3(ns, xyz(load_tri_normal(normals, hit->tri, 2)), hit->v);
    float length2 = dot3(ns, ns);
    /* no direction (a file's "vn 0 0 0", or corners' normals that cancel): the flat normal */
    ns = length2 > 0.0f ? mul3(ns, 1.0f / rt_sqrt(length2)) : s.ng;
    s.ns = dot3(ns, d) > 0.0f ? mul3(ns, -1.0f) : ns;
#else
    s.ns = s.ng;
#endif
    s.material = load_tri_material(tri_materials, hit->tri);
    return s;
}

#endif /* RT_SHADE_H */
