/* rt_entry_loop.h - rays against the first n_tris triangles of the scene in a loop, no acceleration
 * structure (rt_intersect.h's intersect_first_tris; RT_ISECT picks the test):
 *   intersect_triangles  each pixel's camera ray, the paper's Table 3 kernel ("the testing kernel
 *                        tested the first 1000 triangles of the scene in a for-loop", §4.2)
 *   trace_rays_loop      arbitrary rays, t refined as trace_rays': the brute force every traversal is
 *                        checked against (rtlab.device.probes.probe_brute_force)
 */
#ifndef RT_ENTRY_LOOP_H
#define RT_ENTRY_LOOP_H
#include "rt_primary.h"

/* Closest hit of pixel (x, y)'s camera ray among triangles [0, n_tris), as float4 (t, u, v, tri bits). */
RT_KERNEL void intersect_triangles(RT_SCENE_PARAMS, RT_OUT(float4) hits, int n_tris RT_WITH_FRAME)
{
    int x, y;
    launch_pixel(&x, &y);
    if (x >= rt_frame->width || y >= rt_frame->height)
        return;
    Ray ray = camera_ray(rt_frame, x, y);
    Hit hit = make_miss(ray.tmax);
    intersect_first_tris(RT_SCENE_ARGS, &ray, n_tris, &hit);
    hits[y * rt_frame->width + x] = pack_hit(hit);
}

/* Closest hit of arbitrary rays (origins (x, y, z, tmin), directions (x, y, z, tmax)) among triangles
 * [0, n_tris). */
RT_KERNEL void trace_rays_loop(RT_SCENE_PARAMS, RT_IN(float4) origins, RT_IN(float4) directions, RT_OUT(float4) hits,
                               int n_rays, int n_tris)
{
    int i = rt_global_id(0);
    if (i >= n_rays)
        return;
    rt_store_once(&hits[i], pack_hit(trace_one_loop(RT_SCENE_ARGS, rt_load_once(&origins[i]),
                                                    rt_load_once(&directions[i]), n_tris)));
}

#endif /* RT_ENTRY_LOOP_H */
