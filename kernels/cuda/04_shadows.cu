// Lab step 04: shadow rays, one-pass and two-pass (§3.2.1, Table 5) (CUDA). The per-ray work is
// shared with OpenCL in kernels/shared/rt_whitted.h; this file holds only what CUDA spells its own
// way: constant-memory symbols and the thread index.
#include "rt_whitted.h"

__constant__ RtFrame c_frame;
__constant__ RtLight c_lights[RT_MAX_LIGHTS];
__constant__ RtMaterial c_materials[RT_MAX_MATERIALS];

// One-pass: primary ray, shadow rays and shading in one kernel (more registers, one launch).
RT_KERNEL void render_shadows(RT_SCENE_PARAMS, unsigned int *__restrict__ pixels, float4 *__restrict__ hits)
{
    int x = blockIdx.x * blockDim.x + threadIdx.x;
    int y = blockIdx.y * blockDim.y + threadIdx.y;
    if (x >= c_frame.width || y >= c_frame.height)
        return;
    Hit hit;
    unsigned int rgba = render_pixel_shadows(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, x, y, &hit);
    int i = y * c_frame.width + x;
    pixels[i] = rgba;
#if RT_WRITE_HITS
    hits[i] = pack_hit(hit);
#endif
}

// Two-pass, pass 1: primary rays only; each pixel's hit goes to the global buffer `hits`.
RT_KERNEL void trace_primary_hits(RT_SCENE_PARAMS, float4 *__restrict__ hits)
{
    int x = blockIdx.x * blockDim.x + threadIdx.x;
    int y = blockIdx.y * blockDim.y + threadIdx.y;
    if (x >= c_frame.width || y >= c_frame.height)
        return;
    hits[y * c_frame.width + x] = pack_hit(trace_pixel(RT_SCENE_ARGS, &c_frame, x, y));
}

// Two-pass, pass 2: shadow rays and shading from the stored hits.
RT_KERNEL void shade_hits(RT_SCENE_PARAMS, const float4 *__restrict__ hits, unsigned int *__restrict__ pixels)
{
    int x = blockIdx.x * blockDim.x + threadIdx.x;
    int y = blockIdx.y * blockDim.y + threadIdx.y;
    if (x >= c_frame.width || y >= c_frame.height)
        return;
    int i = y * c_frame.width + x;
    pixels[i] = shade_pixel(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, x, y, hits[i]);
}

// Test probe: whether the shadow ray from each stored hit (ray direction dirs[i]) to targets[i] is free.
RT_KERNEL void probe_shadow(RT_SCENE_PARAMS, const float4 *__restrict__ dirs, const float4 *__restrict__ hits,
                            const float4 *__restrict__ targets, int *__restrict__ visible, int n)
{
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n)
        return;
    visible[i] = probe_visible(RT_SCENE_ARGS, &c_frame, dirs[i], hits[i], targets[i]);
}
