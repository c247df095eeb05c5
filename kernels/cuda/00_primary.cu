// Lab step 00: primary rays with simple shading (CUDA). The per-ray work is shared with OpenCL in
// kernels/shared/rt_primary.h; this file holds only what CUDA spells its own way: constant-memory
// symbols and the thread index.
#include "rt_primary.h"

__constant__ RtFrame c_frame;
__constant__ RtLight c_lights[RT_MAX_LIGHTS];
__constant__ RtMaterial c_materials[RT_MAX_MATERIALS];

// Closest hit of arbitrary rays: origins (x, y, z, tmin), directions (x, y, z, tmax).
RT_KERNEL void trace_rays(RT_SCENE_PARAMS, const float4 *__restrict__ origins,
                          const float4 *__restrict__ directions, float4 *__restrict__ hits, int n_rays)
{
    int i = blockIdx.x * blockDim.x + threadIdx.x;
#if RT_TRAVERSAL == RT_TRAVERSAL_BVH_PACKET
    // RT_LANES rays a thread, traced together (the CPU's traversal; it compiles and runs here too)
    trace_packet(RT_SCENE_ARGS, &c_frame, origins, directions, hits, i * RT_LANES, n_rays);
#else
    if (i >= n_rays)
        return;
    rt_store_once(&hits[i], pack_hit(trace_one(RT_SCENE_ARGS, &c_frame, rt_load_once(&origins[i]), rt_load_once(&directions[i]))));
#endif
}

// Closest hit of rays laid out as an image, width x height row-major (rtlab.trace(..., width=)):
// a 2-D launch whose blocks take tiles of it in block_pixel's order, as render_primary's do, so a
// warp traces neighbouring rays.
RT_KERNEL void trace_ray_grid(RT_SCENE_PARAMS, const float4 *__restrict__ origins,
                              const float4 *__restrict__ directions, float4 *__restrict__ hits, int width, int height)
{
    int x, y;
    block_pixel(blockIdx.x, blockIdx.y, blockDim.x, blockDim.y, threadIdx.x, threadIdx.y, &x, &y);
    if (x >= width || y >= height)
        return;
    int i = y * width + x;
    rt_store_once(&hits[i], pack_hit(trace_one(RT_SCENE_ARGS, &c_frame, rt_load_once(&origins[i]), rt_load_once(&directions[i]))));
}

// One thread a pixel; the block shape is the launch's (the paper's Fig. 4 studies it).
RT_KERNEL void render_primary(RT_SCENE_PARAMS, unsigned int *__restrict__ pixels, float4 *__restrict__ hits)
{
#if RT_TRAVERSAL == RT_TRAVERSAL_BVH_PACKET
    // RT_LANES pixels of a row a thread, traced together
    render_packet(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, (blockIdx.x * blockDim.x + threadIdx.x) * RT_LANES,
                  blockIdx.y * blockDim.y + threadIdx.y, pixels, hits);
    return;
#endif
    int x, y;
    block_pixel(blockIdx.x, blockIdx.y, blockDim.x, blockDim.y, threadIdx.x, threadIdx.y, &x, &y);
    if (x >= c_frame.width || y >= c_frame.height)
        return;
    Hit hit;
    unsigned int rgba = render_pixel(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, x, y, &hit);
    int i = y * c_frame.width + x;
    pixels[i] = rgba;
#if RT_WRITE_HITS
    hits[i] = pack_hit(hit);
#endif
}
