/* rt_primary.h - per-ray work of lab step 00 (primary rays, simple shading: the paper's Table 4
 * setting). Entry kernels in cuda/00_primary.cu and opencl/00_primary.cl only find their ray index
 * and call these. */
#ifndef RT_PRIMARY_H
#define RT_PRIMARY_H
#include "rt_traverse.h"
#include "rt_shade.h"

/* Recompute the closest hit's distance from the triangle's plane, t = n.(v0 - o) / n.d with
 * n = e1 x e2. Moller-Trumbore's t = e2.(s x e1) / det cancels badly when the origin is far from a
 * small triangle seen at a grazing angle (1.8e-5 relative on SPONZA); the plane form stays near
 * float32 rounding. Done once per ray, so the intersection loop is unchanged. */
RT_FN void refine_hit_t(RT_SCENE_PARAMS, const Ray *ray, Hit *hit)
{
    if (hit->tri < 0)
        return;
    float3 v0 = xyz(load_tri_vertex(hit->tri, 0));
    float3 n = cross3(sub3(xyz(load_tri_vertex(hit->tri, 1)), v0), sub3(xyz(load_tri_vertex(hit->tri, 2)), v0));
    float t = dot3(n, sub3(v0, ray->o)) / dot3(n, ray->d);
    if (t > ray->tmin && t < ray->tmax)
        hit->t = t;
}

/* Closest hit of one ray: the work of trace_rays. origin.w = tmin, direction.w = tmax. */
RT_FN Hit trace_one(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, float4 origin, float4 direction)
{
    Ray ray = make_ray(xyz(origin), xyz(direction), origin.w, direction.w);
    Hit hit = make_miss(ray.tmax);
    trace_closest(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, &ray, &hit);
    refine_hit_t(RT_SCENE_ARGS, &ray, &hit);
    return hit;
}

/* Shaded colour of pixel (x, y); its hit record in *hit. */
RT_FN unsigned int render_pixel(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame,
                                RT_CONST const RtLight *lights, RT_CONST const RtMaterial *materials,
                                int x, int y, Hit *hit)
{
    Ray ray = camera_ray(frame, x, y);
    *hit = make_miss(ray.tmax);
    trace_closest(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, &ray, hit);
    refine_hit_t(RT_SCENE_ARGS, &ray, hit);
    return pack_rgba8(shade_lambert(RT_SCENE_ARGS, frame, lights, materials, &ray, hit));
}

/* The host reads a hit as float4 (t, u, v, tri bits); a miss has tri = -1 and t = tmax. */
RT_FN float4 pack_hit(Hit h) { return f4(h.t, h.u, h.v, rt_as_float(h.tri)); }

#endif /* RT_PRIMARY_H */
