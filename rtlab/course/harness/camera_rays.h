/* Grader harness: the ray camera_ray() builds for every pixel, written out for the host to check
 * against rtlab.device.tracing.camera_rays. Not part of any lab step; students do not edit it. The
 * kernel is written once here for both languages (rt_port.h's entry macros); camera_rays.cu and
 * camera_rays.cl declare only what their language keeps apart. */
#ifndef RT_HARNESS_CAMERA_RAYS_H
#define RT_HARNESS_CAMERA_RAYS_H
#include "rt_types.h"

RT_KERNEL void camera_rays(RT_OUT(float4) origins, RT_OUT(float4) directions, RT_OUT(float4) inv_directions RT_WITH_FRAME)
{
    int x = rt_global_id(0);
    int y = rt_global_id(1);
    if (x >= rt_frame->width || y >= rt_frame->height)
        return;
    Ray r = camera_ray(rt_frame, x, y);
    int i = y * rt_frame->width + x;
    origins[i] = f4(r.o.x, r.o.y, r.o.z, r.tmin);
    directions[i] = f4(r.d.x, r.d.y, r.d.z, r.tmax);
    inv_directions[i] = f4(r.inv_d.x, r.inv_d.y, r.inv_d.z, 0.0f);
}

#endif /* RT_HARNESS_CAMERA_RAYS_H */
