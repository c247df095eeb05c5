// Lab step 03: kd-tree traversal variants (the paper's Table 4) and the BVH (OpenCL). Same entry
// kernels and arguments as step 00. Built with RT_TRAVERSAL = packet, each work-group traces its
// rays as one packet with a stack in local memory (kernels/shared/rt_packet.h); any other
// traversal runs one ray a work-item through trace_closest, as in step 00.
#define RT_PACKET_KERNELS 1
#include "rt_primary.h"
#if RT_TRAVERSAL == RT_TRAVERSAL_PACKET
#include "rt_packet.h"
#endif

// Closest hit of arbitrary rays: origins (x, y, z, tmin), directions (x, y, z, tmax).
__kernel void trace_rays(RT_SCENE_PARAMS, __global const float4 *restrict origins,
                         __global const float4 *restrict directions, __global float4 *restrict hits,
                         int n_rays, __constant RtFrame *frame)
{
    int i = get_global_id(0);
#if RT_TRAVERSAL == RT_TRAVERSAL_PACKET
    // Work-items past the end still take part in the packet's barriers
    __local KdPacketShared packet;
    int valid = i < n_rays;
    int j = valid ? i : 0;
    Hit hit = trace_one_packet(RT_SCENE_ARGS, frame, origins[j], directions[j], valid, &packet,
                               (int)get_local_id(0));
    if (valid)
        hits[i] = pack_hit(hit);
#else
    if (i >= n_rays)
        return;
    hits[i] = pack_hit(trace_one(RT_SCENE_ARGS, frame, origins[i], directions[i]));
#endif
}

// One work-item a pixel; with the packet traversal one work-group is one packet of rays.
__kernel void render_primary(RT_SCENE_PARAMS, __global unsigned int *restrict pixels,
                             __global float4 *restrict hits, __constant RtFrame *frame,
                             __constant RtLight *lights, __constant RtMaterial *materials)
{
    int x = get_global_id(0);
    int y = get_global_id(1);
    int valid = x < frame->width && y < frame->height;
    Hit hit;
#if RT_TRAVERSAL == RT_TRAVERSAL_PACKET
    __local KdPacketShared packet;
    int lane = (int)(get_local_id(1) * get_local_size(0) + get_local_id(0));
    unsigned int rgba = render_pixel_packet(RT_SCENE_ARGS, frame, lights, materials, x, y, valid, &packet,
                                            lane, &hit);
    if (!valid)
        return;
#else
    if (!valid)
        return;
    unsigned int rgba = render_pixel(RT_SCENE_ARGS, frame, lights, materials, x, y, &hit);
#endif
    int i = y * frame->width + x;
    pixels[i] = rgba;
#if RT_WRITE_HITS
    hits[i] = pack_hit(hit);
#endif
}
