// Grader harness (CUDA): the ray camera_ray() builds for every pixel, written out for the host to
// check against rtlab.device.tracing.camera_rays. Not part of any lab step; students do not edit it.
#include "rt_types.h"

__constant__ RtFrame c_frame;

RT_KERNEL void camera_rays(float4 *__restrict__ origins, float4 *__restrict__ directions,
                           float4 *__restrict__ inv_directions)
{
    int x = blockIdx.x * blockDim.x + threadIdx.x;
    int y = blockIdx.y * blockDim.y + threadIdx.y;
    if (x >= c_frame.width || y >= c_frame.height)
        return;
    Ray r = camera_ray(&c_frame, x, y);
    int i = y * c_frame.width + x;
    origins[i] = f4(r.o.x, r.o.y, r.o.z, r.tmin);
    directions[i] = f4(r.d.x, r.d.y, r.d.z, r.tmax);
    inv_directions[i] = f4(r.inv_d.x, r.inv_d.y, r.inv_d.z, 0.0f);
}
