/* rt_entry_shadows.h - shadow rays one-pass and two-pass (§3.2.1, Table 5): the entry kernels of
 * rt_whitted.h's pixel shading, written once for CUDA and OpenCL (the library's library_shadows,
 * lab step 04). */
#ifndef RT_ENTRY_SHADOWS_H
#define RT_ENTRY_SHADOWS_H
#include "rt_whitted.h"

/* One-pass: primary ray, shadow rays and shading in one kernel (more registers, one launch). */
RT_KERNEL void render_shadows(RT_SCENE_PARAMS, RT_OUT(unsigned int) pixels, RT_OUT(float4) hits RT_WITH_SHADING)
{
    int x, y;
    launch_pixel(&x, &y);
    if (x >= rt_frame->width || y >= rt_frame->height)
        return;
    Hit hit;
    unsigned int rgba = render_pixel_shadows(RT_SCENE_ARGS, rt_frame, rt_lights, rt_materials, x, y, &hit);
    int i = y * rt_frame->width + x;
    pixels[i] = rgba;
#if RT_WRITE_HITS
    hits[i] = pack_hit(hit);
#endif
}

/* Two-pass, pass 1: primary rays only; each pixel's hit goes to the global buffer `hits`. */
RT_KERNEL void trace_primary_hits(RT_SCENE_PARAMS, RT_OUT(float4) hits RT_WITH_FRAME)
{
    int x, y;
    launch_pixel(&x, &y);
    if (x >= rt_frame->width || y >= rt_frame->height)
        return;
    hits[y * rt_frame->width + x] = pack_hit(trace_pixel(RT_SCENE_ARGS, rt_frame, x, y));
}

/* Two-pass, pass 2: shadow rays and shading from the stored hits. */
RT_KERNEL void shade_hits(RT_SCENE_PARAMS, RT_IN(float4) hits, RT_OUT(unsigned int) pixels RT_WITH_SHADING)
{
    int x, y;
    launch_pixel(&x, &y);
    if (x >= rt_frame->width || y >= rt_frame->height)
        return;
    int i = y * rt_frame->width + x;
    pixels[i] = shade_pixel(RT_SCENE_ARGS, rt_frame, rt_lights, rt_materials, x, y, hits[i]);
}

/* Test probe: whether the shadow ray from each stored hit (ray direction dirs[i]) to targets[i] is free. */
RT_KERNEL void probe_shadow(RT_SCENE_PARAMS, RT_IN(float4) dirs, RT_IN(float4) hits, RT_IN(float4) targets,
                            RT_OUT(int) visible, int n RT_WITH_FRAME)
{
    int i = rt_global_id(0);
    if (i >= n)
        return;
    visible[i] = probe_visible(RT_SCENE_ARGS, rt_frame, dirs[i], hits[i], targets[i]);
}

#endif /* RT_ENTRY_SHADOWS_H */
