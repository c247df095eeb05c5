// Lab step 03: kd-tree traversal variants (the paper's Table 4) and the BVH (CUDA). Same entry
// kernels and arguments as step 00. Built with RT_TRAVERSAL = packet, each block traces its rays
// as one packet with a stack in shared memory (kernels/shared/rt_packet.h); any other traversal
// runs one ray a thread through trace_closest, as in step 00.
#define RT_PACKET_KERNELS 1
#include "rt_primary.h"
#if RT_TRAVERSAL == RT_TRAVERSAL_PACKET
#include "rt_packet.h"
#endif

__constant__ RtFrame c_frame;
__constant__ RtLight c_lights[RT_MAX_LIGHTS];
__constant__ RtMaterial c_materials[RT_MAX_MATERIALS];

// Closest hit of arbitrary rays: origins (x, y, z, tmin), directions (x, y, z, tmax).
RT_KERNEL void trace_rays(RT_SCENE_PARAMS, const float4 *__restrict__ origins,
                          const float4 *__restrict__ directions, float4 *__restrict__ hits, int n_rays)
{
    int i = blockIdx.x * blockDim.x + threadIdx.x;
#if RT_TRAVERSAL == RT_TRAVERSAL_PACKET
    // Threads past the end still take part in the packet's barriers
    __shared__ KdPacketShared packet;
    int valid = i < n_rays;
    int j = valid ? i : 0;
    Hit hit = trace_one_packet(RT_SCENE_ARGS, &c_frame, origins[j], directions[j], valid, &packet,
                               threadIdx.x);
    if (valid)
        hits[i] = pack_hit(hit);
#else
    if (i >= n_rays)
        return;
    hits[i] = pack_hit(trace_one(RT_SCENE_ARGS, &c_frame, origins[i], directions[i]));
#endif
}

// One thread a pixel; with the packet traversal one block is one packet of rays.
RT_KERNEL void render_primary(RT_SCENE_PARAMS, unsigned int *__restrict__ pixels, float4 *__restrict__ hits)
{
    int x = blockIdx.x * blockDim.x + threadIdx.x;
    int y = blockIdx.y * blockDim.y + threadIdx.y;
    int valid = x < c_frame.width && y < c_frame.height;
    Hit hit;
#if RT_TRAVERSAL == RT_TRAVERSAL_PACKET
    __shared__ KdPacketShared packet;
    unsigned int rgba = render_pixel_packet(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, x, y, valid,
                                            &packet, threadIdx.y * blockDim.x + threadIdx.x, &hit);
    if (!valid)
        return;
#else
    if (!valid)
        return;
    unsigned int rgba = render_pixel(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, x, y, &hit);
#endif
    int i = y * c_frame.width + x;
    pixels[i] = rgba;
#if RT_WRITE_HITS
    hits[i] = pack_hit(hit);
#endif
}
