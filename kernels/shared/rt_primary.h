/* rt_primary.h - per-ray work of lab step 00 (primary rays, simple shading: the paper's Table 4
 * setting). Entry kernels in cuda/00_primary.cu and opencl/00_primary.cl only find their ray index
 * and call these. */
#ifndef RT_PRIMARY_H
#define RT_PRIMARY_H
#include "rt_traverse.h"
#include "rt_shade.h"

/* Closest hit of one ray: the work of trace_rays. origin.w = tmin, direction.w = tmax. */
RT_FN Hit trace_one(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, float4 origin, float4 direction)
{
    Ray ray = make_ray(xyz(origin), xyz(direction), origin.w, direction.w);
    Hit hit = make_miss(ray.tmax);
    trace_closest(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, &ray, &hit);
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
    return pack_rgba8(shade_lambert(RT_SCENE_ARGS, frame, lights, materials, &ray, hit));
}

/* The host reads a hit as float4 (t, u, v, tri bits); a miss has tri = -1 and t = tmax. */
RT_FN float4 pack_hit(Hit h) { return f4(h.t, h.u, h.v, rt_as_float(h.tri)); }

#endif /* RT_PRIMARY_H */
