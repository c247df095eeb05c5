// Lab step 02: triangle intersection tests (the paper's Table 3, CUDA). Each thread takes the camera
// ray of its pixel and tests it against the first n_tris triangles of the scene in a loop, no
// acceleration structure ("the testing kernel tested the first 1000 triangles of the scene in a
// for-loop", §4.2); RT_ISECT picks the test. The loop is intersect_first_tris in
// kernels/shared/rt_intersect.h; this file holds the constant-memory frame and the thread index.
#include "rt_primary.h"

__constant__ RtFrame c_frame;

// Closest hit of pixel (x, y)'s camera ray among triangles [0, n_tris), as float4 (t, u, v, tri bits).
RT_KERNEL void intersect_triangles(RT_SCENE_PARAMS, float4 *__restrict__ hits, int n_tris)
{
    int x = blockIdx.x * blockDim.x + threadIdx.x;
    int y = blockIdx.y * blockDim.y + threadIdx.y;
    if (x >= c_frame.width || y >= c_frame.height)
        return;
    Ray ray = camera_ray(&c_frame, x, y);
    Hit hit = make_miss(ray.tmax);
    intersect_first_tris(RT_SCENE_ARGS, &ray, n_tris, &hit);
    hits[y * c_frame.width + x] = pack_hit(hit);
}

// Closest hit of arbitrary rays (origins (x, y, z, tmin), directions (x, y, z, tmax)) among triangles
// [0, n_tris), no acceleration structure: the brute force every traversal is checked against
// (rtlab.device.probes.probe_brute_force).
RT_KERNEL void trace_rays_loop(RT_SCENE_PARAMS, const float4 *__restrict__ origins, const float4 *__restrict__ directions,
                               float4 *__restrict__ hits, int n_rays, int n_tris)
{
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n_rays)
        return;
    hits[i] = pack_hit(trace_one_loop(RT_SCENE_ARGS, origins[i], directions[i], n_tris));
}
