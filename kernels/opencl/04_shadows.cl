// Lab step 04: shadow rays, one-pass and two-pass (§3.2.1, Table 5) (OpenCL). The per-ray work is
// shared with CUDA in kernels/shared/rt_whitted.h; this file holds only what OpenCL spells its own
// way: constant-memory arguments (last, in the order frame, lights, materials) and the work-item index.
#include "rt_whitted.h"

// One-pass: primary ray, shadow rays and shading in one kernel (more registers, one launch).
__kernel void render_shadows(RT_SCENE_PARAMS, __global unsigned int *restrict pixels,
                             __global float4 *restrict hits, __constant RtFrame *frame,
                             __constant RtLight *lights, __constant RtMaterial *materials)
{
    int x = get_global_id(0);
    int y = get_global_id(1);
    if (x >= frame->width || y >= frame->height)
        return;
    Hit hit;
    unsigned int rgba = render_pixel_shadows(RT_SCENE_ARGS, frame, lights, materials, x, y, &hit);
    int i = y * frame->width + x;
    pixels[i] = rgba;
#if RT_WRITE_HITS
    hits[i] = pack_hit(hit);
#endif
}

// Two-pass, pass 1: primary rays only; each pixel's hit goes to the global buffer `hits`.
__kernel void trace_primary_hits(RT_SCENE_PARAMS, __global float4 *restrict hits, __constant RtFrame *frame)
{
    int x = get_global_id(0);
    int y = get_global_id(1);
    if (x >= frame->width || y >= frame->height)
        return;
    hits[y * frame->width + x] = pack_hit(trace_pixel(RT_SCENE_ARGS, frame, x, y));
}

// Two-pass, pass 2: shadow rays and shading from the stored hits.
__kernel void shade_hits(RT_SCENE_PARAMS, __global const float4 *restrict hits, __global unsigned int *restrict pixels,
                         __constant RtFrame *frame, __constant RtLight *lights, __constant RtMaterial *materials)
{
    int x = get_global_id(0);
    int y = get_global_id(1);
    if (x >= frame->width || y >= frame->height)
        return;
    int i = y * frame->width + x;
    pixels[i] = shade_pixel(RT_SCENE_ARGS, frame, lights, materials, x, y, hits[i]);
}

// Test probe: whether the shadow ray from each stored hit (ray direction dirs[i]) to targets[i] is free.
__kernel void probe_shadow(RT_SCENE_PARAMS, __global const float4 *restrict dirs, __global const float4 *restrict hits,
                           __global const float4 *restrict targets, __global int *restrict visible, int n,
                           __constant RtFrame *frame)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    visible[i] = probe_visible(RT_SCENE_ARGS, frame, dirs[i], hits[i], targets[i]);
}
