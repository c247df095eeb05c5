// Lab step 02: triangle intersection tests (the paper's Table 3, OpenCL). Each work-item takes the
// camera ray of its pixel and tests it against the first n_tris triangles of the scene in a loop, no
// acceleration structure ("the testing kernel tested the first 1000 triangles of the scene in a
// for-loop", §4.2); RT_ISECT picks the test. The loop is intersect_first_tris in
// kernels/shared/rt_intersect.h; this file holds the constant-memory frame and the work-item index.
#include "rt_primary.h"

// Closest hit of pixel (x, y)'s camera ray among triangles [0, n_tris), as float4 (t, u, v, tri bits).
__kernel void intersect_triangles(RT_SCENE_PARAMS, __global float4 *restrict hits, int n_tris,
                                  __constant RtFrame *frame)
{
    int x = get_global_id(0);
    int y = get_global_id(1);
    if (x >= frame->width || y >= frame->height)
        return;
    Ray ray = camera_ray(frame, x, y);
    Hit hit = make_miss(ray.tmax);
    intersect_first_tris(RT_SCENE_ARGS, &ray, n_tris, &hit);
    hits[y * frame->width + x] = pack_hit(hit);
}

// Closest hit of arbitrary rays (origins (x, y, z, tmin), directions (x, y, z, tmax)) among triangles
// [0, n_tris), no acceleration structure: the brute force every traversal is checked against
// (rtlab.device.probes.probe_brute_force).
__kernel void trace_rays_loop(RT_SCENE_PARAMS, __global const float4 *restrict origins,
                              __global const float4 *restrict directions, __global float4 *restrict hits, int n_rays,
                              int n_tris)
{
    int i = get_global_id(0);
    if (i >= n_rays)
        return;
    hits[i] = pack_hit(trace_one_loop(RT_SCENE_ARGS, origins[i], directions[i], n_tris));
}
