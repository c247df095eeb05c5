// Grader harness (OpenCL): the ray camera_ray() builds for every pixel, written out for the host to
// check against rtlab.device.tracing.camera_rays. Not part of any lab step; students do not edit it.
#include "rt_types.h"

__kernel void camera_rays(__global float4 *restrict origins, __global float4 *restrict directions,
                          __global float4 *restrict inv_directions, __constant RtFrame *frame)
{
    int x = get_global_id(0);
    int y = get_global_id(1);
    if (x >= frame->width || y >= frame->height)
        return;
    Ray r = camera_ray(frame, x, y);
    int i = y * frame->width + x;
    origins[i] = f4(r.o.x, r.o.y, r.o.z, r.tmin);
    directions[i] = f4(r.d.x, r.d.y, r.d.z, r.tmax);
    inv_directions[i] = f4(r.inv_d.x, r.inv_d.y, r.inv_d.z, 0.0f);
}
