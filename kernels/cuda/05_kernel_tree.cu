// Lab step 05: reflection and refraction rays as a kernel tree (§3.2.2, Table 5) (CUDA). Every
// tree node is one launch of trace_reflection or trace_refraction over the records of the level
// above; rtlab/device/whitted_frames.py walks the tree depth-first. The per-ray work is shared with OpenCL in
// kernels/shared/rt_whitted.h; this file holds only what CUDA spells its own way.
#include "rt_whitted.h"
#if RT_WAVEFRONT
#include "rt_wavefront.h"
#endif

__constant__ RtFrame c_frame;
__constant__ RtLight c_lights[RT_MAX_LIGHTS];
__constant__ RtMaterial c_materials[RT_MAX_MATERIALS];

// The record buffers of one level: (direction, weight), (t, u, v, tri bits), pixel (compacted).
#define RT_LEVEL_OUT float4 *__restrict__ dirs_out, float4 *__restrict__ hits_out, \
    int *__restrict__ pixels_out, int *__restrict__ count_out
#define RT_LEVEL_IN const float4 *__restrict__ dirs_in, const float4 *__restrict__ hits_in, \
    const int *__restrict__ pixels_in, int n_in

#if !RT_WAVEFRONT
// Level 0: primary rays, shaded into the float4 frame, recorded for the first bounce.
RT_KERNEL void trace_primary_tree(RT_SCENE_PARAMS, float4 *__restrict__ frame_rgb, RT_LEVEL_OUT)
{
    int x = blockIdx.x * blockDim.x + threadIdx.x;
    int y = blockIdx.y * blockDim.y + threadIdx.y;
    if (x >= c_frame.width || y >= c_frame.height)
        return;
    trace_tree_primary(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, x, y, frame_rgb, dirs_out, hits_out,
                       pixels_out, count_out);
}

#if RT_REFLECTION
// A reflection node: one reflection ray per record of the level above.
RT_KERNEL void trace_reflection(RT_SCENE_PARAMS, RT_LEVEL_IN, float4 *__restrict__ frame_rgb, RT_LEVEL_OUT, int level)
{
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n_in)
        return;
    trace_tree_secondary(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, RT_RAY_REFLECTION, level, i, dirs_in,
                         hits_in, pixels_in, frame_rgb, dirs_out, hits_out, pixels_out, count_out);
}
#endif

#if RT_REFRACTION
// A refraction node: one refraction ray per record of the level above.
RT_KERNEL void trace_refraction(RT_SCENE_PARAMS, RT_LEVEL_IN, float4 *__restrict__ frame_rgb, RT_LEVEL_OUT, int level)
{
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n_in)
        return;
    trace_tree_secondary(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, RT_RAY_REFRACTION, level, i, dirs_in,
                         hits_in, pixels_in, frame_rgb, dirs_out, hits_out, pixels_out, count_out);
}
#endif

#if RT_TWO_PASS
// Two-pass tree: shadow rays and shading of one node's records, after the node's launch.
RT_KERNEL void shade_records(RT_SCENE_PARAMS, RT_LEVEL_IN, float4 *__restrict__ frame_rgb, int level)
{
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n_in)
        return;
    shade_tree_record(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, level, i, dirs_in, hits_in, pixels_in,
                      frame_rgb);
}
#endif

#else /* RT_WAVEFRONT: the tree's rays level by level, one launch per level */
// The queue a launch fills: (origin, weight), (direction, pixel bits), path, two counts, capacity.
#define RT_QUEUE_OUT float4 *__restrict__ q_ow, float4 *__restrict__ q_dp, int *__restrict__ q_path, \
    int *__restrict__ q_count, int q_cap

// Level 0: primary rays; their children go to the queue.
RT_KERNEL void trace_wavefront_primary(RT_SCENE_PARAMS, float4 *__restrict__ frame_rgb, float4 *__restrict__ hits_out,
                                       RT_QUEUE_OUT)
{
    int x = blockIdx.x * blockDim.x + threadIdx.x;
    int y = blockIdx.y * blockDim.y + threadIdx.y;
    if (x >= c_frame.width || y >= c_frame.height)
        return;
    trace_wavefront_pixel(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, x, y, frame_rgb, hits_out, q_ow, q_dp,
                          q_path, q_count, q_cap);
}

// Level >= 1: every ray of the level, reflection and refraction.
RT_KERNEL void trace_wavefront(RT_SCENE_PARAMS, const float4 *__restrict__ in_ow, const float4 *__restrict__ in_dp,
                               const int *__restrict__ in_path, int n_front, int n_in, int in_cap,
                               float4 *__restrict__ frame_rgb, float4 *__restrict__ hits_out, RT_QUEUE_OUT, int level)
{
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n_in)
        return;
    trace_wavefront_ray(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, level, i, in_ow, in_dp, in_path, n_front,
                        in_cap, frame_rgb, hits_out, q_ow, q_dp, q_path, q_count, q_cap);
}
#endif /* RT_WAVEFRONT */

// The accumulated frame to RGBA8.
RT_KERNEL void pack_frame(const float4 *__restrict__ frame_rgb, unsigned int *__restrict__ pixels, int n)
{
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n)
        return;
    pixels[i] = pack_rgba8(xyz(frame_rgb[i]));
}

// Test probe: the child of `kind` spawned from each stored hit, and what it hits.
RT_KERNEL void probe_secondary(RT_SCENE_PARAMS, const float4 *__restrict__ dirs, const float4 *__restrict__ hits,
                               int kind, int n, float4 *__restrict__ origins_out, float4 *__restrict__ dirs_out,
                               float4 *__restrict__ hits_out)
{
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n)
        return;
    probe_spawn(RT_SCENE_ARGS, &c_frame, c_materials, kind, dirs[i], hits[i], &origins_out[i], &dirs_out[i],
                &hits_out[i]);
}

// Test probe: refraction and Schlick reflectance of direction d[i] at normal n[i] (n.w = ior, d.w = front).
RT_KERNEL void probe_refract(const float4 *__restrict__ d, const float4 *__restrict__ n, float4 *__restrict__ out, int count)
{
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= count)
        return;
    out[i] = probe_refraction(d[i], n[i], n[i].w, d[i].w != 0.0f);
}
