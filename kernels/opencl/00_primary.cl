// Lab step 00: primary rays with simple shading (OpenCL). The per-ray work is shared with CUDA in
// kernels/shared/rt_primary.h; this file holds only what OpenCL spells its own way: constant-memory
// arguments (last, in the order frame, lights, materials) and the work-item index.
#include "rt_primary.h"

// Closest hit of arbitrary rays: origins (x, y, z, tmin), directions (x, y, z, tmax).
__kernel void trace_rays(RT_SCENE_PARAMS, __global const float4 *restrict origins,
                         __global const float4 *restrict directions, __global float4 *restrict hits,
                         int n_rays, __constant RtFrame *frame)
{
#if RT_TRAVERSAL == RT_TRAVERSAL_BVH_PACKET
    // RT_LANES rays a work-item, traced together in SIMD lanes
    trace_packet(RT_SCENE_ARGS, frame, origins, directions, hits, (int)get_global_id(0) * RT_LANES, n_rays);
#else
    int i = get_global_id(0);
    if (i >= n_rays)
        return;
    rt_store_once(&hits[i], pack_hit(trace_one(RT_SCENE_ARGS, frame, rt_load_once(&origins[i]), rt_load_once(&directions[i]))));
#endif
}

// Closest hit of rays laid out as an image, width x height row-major (rtlab.trace(..., width=)):
// a 2-D launch whose work-groups take tiles of it in block_pixel's order, as render_primary's do.
__kernel void trace_ray_grid(RT_SCENE_PARAMS, __global const float4 *restrict origins,
                             __global const float4 *restrict directions, __global float4 *restrict hits,
                             int width, int height, __constant RtFrame *frame)
{
    int x, y;
    block_pixel(get_group_id(0), get_group_id(1), get_local_size(0), get_local_size(1), get_local_id(0),
                get_local_id(1), &x, &y);
    if (x >= width || y >= height)
        return;
    int i = y * width + x;
    rt_store_once(&hits[i], pack_hit(trace_one(RT_SCENE_ARGS, frame, rt_load_once(&origins[i]), rt_load_once(&directions[i]))));
}

// One work-item a pixel; the work-group shape is the launch's (the paper's Fig. 4 studies it).
__kernel void render_primary(RT_SCENE_PARAMS, __global unsigned int *restrict pixels,
                             __global float4 *restrict hits, __constant RtFrame *frame,
                             __constant RtLight *lights, __constant RtMaterial *materials)
{
#if RT_TRAVERSAL == RT_TRAVERSAL_BVH_PACKET
    // RT_LANES pixels of a row a work-item, traced together in SIMD lanes
    render_packet(RT_SCENE_ARGS, frame, lights, materials, (int)get_global_id(0) * RT_LANES, (int)get_global_id(1),
                  pixels, hits);
    return;
#endif
    int x, y;
    block_pixel(get_group_id(0), get_group_id(1), get_local_size(0), get_local_size(1), get_local_id(0),
                get_local_id(1), &x, &y);
    if (x >= frame->width || y >= frame->height)
        return;
    Hit hit;
    unsigned int rgba = render_pixel(RT_SCENE_ARGS, frame, lights, materials, x, y, &hit);
    int i = y * frame->width + x;
    pixels[i] = rgba;
#if RT_WRITE_HITS
    hits[i] = pack_hit(hit);
#endif
}
