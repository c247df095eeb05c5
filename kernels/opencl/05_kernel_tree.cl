// Lab step 05: reflection and refraction rays as a kernel tree (§3.2.2, Table 5) (OpenCL). Every
// tree node is one launch of trace_reflection or trace_refraction over the records of the level
// above; rtlab/device/whitted_frames.py walks the tree depth-first. The per-ray work is shared with CUDA in
// kernels/shared/rt_whitted.h; this file holds only what OpenCL spells its own way: constant-memory
// arguments (last, in the order frame, lights, materials) and the work-item index.
#include "rt_whitted.h"
#if RT_WAVEFRONT
#include "rt_wavefront.h"
#endif

// The record buffers of one level: (direction, weight), (t, u, v, tri bits), pixel (compacted).
#define RT_LEVEL_OUT __global float4 *restrict dirs_out, __global float4 *restrict hits_out, \
    __global int *restrict pixels_out, __global int *restrict count_out
#define RT_LEVEL_IN __global const float4 *restrict dirs_in, __global const float4 *restrict hits_in, \
    __global const int *restrict pixels_in, int n_in
#define RT_SHADING_CONSTANTS __constant RtFrame *frame, __constant RtLight *lights, __constant RtMaterial *materials

#if !RT_WAVEFRONT
// Level 0: primary rays, shaded into the float4 frame, recorded for the first bounce.
__kernel void trace_primary_tree(RT_SCENE_PARAMS, __global float4 *restrict frame_rgb, RT_LEVEL_OUT,
                                 RT_SHADING_CONSTANTS)
{
    int x = get_global_id(0);
    int y = get_global_id(1);
    if (x >= frame->width || y >= frame->height)
        return;
    trace_tree_primary(RT_SCENE_ARGS, frame, lights, materials, x, y, frame_rgb, dirs_out, hits_out, pixels_out,
                       count_out);
}

#if RT_REFLECTION
// A reflection node: one reflection ray per record of the level above.
__kernel void trace_reflection(RT_SCENE_PARAMS, RT_LEVEL_IN, __global float4 *restrict frame_rgb, RT_LEVEL_OUT,
                               int level, RT_SHADING_CONSTANTS)
{
    int i = get_global_id(0);
    if (i >= n_in)
        return;
    trace_tree_secondary(RT_SCENE_ARGS, frame, lights, materials, RT_RAY_REFLECTION, level, i, dirs_in, hits_in,
                         pixels_in, frame_rgb, dirs_out, hits_out, pixels_out, count_out);
}
#endif

#if RT_REFRACTION
// A refraction node: one refraction ray per record of the level above.
__kernel void trace_refraction(RT_SCENE_PARAMS, RT_LEVEL_IN, __global float4 *restrict frame_rgb, RT_LEVEL_OUT,
                               int level, RT_SHADING_CONSTANTS)
{
    int i = get_global_id(0);
    if (i >= n_in)
        return;
    trace_tree_secondary(RT_SCENE_ARGS, frame, lights, materials, RT_RAY_REFRACTION, level, i, dirs_in, hits_in,
                         pixels_in, frame_rgb, dirs_out, hits_out, pixels_out, count_out);
}
#endif

#if RT_TWO_PASS
// Two-pass tree: shadow rays and shading of one node's records, after the node's launch.
__kernel void shade_records(RT_SCENE_PARAMS, RT_LEVEL_IN, __global float4 *restrict frame_rgb, int level,
                            RT_SHADING_CONSTANTS)
{
    int i = get_global_id(0);
    if (i >= n_in)
        return;
    shade_tree_record(RT_SCENE_ARGS, frame, lights, materials, level, i, dirs_in, hits_in, pixels_in, frame_rgb);
}
#endif

#else /* RT_WAVEFRONT: the tree's rays level by level, one launch per level */
// The queue a launch fills: (origin, weight), (direction, pixel bits), path, two counts, capacity.
#define RT_QUEUE_OUT __global float4 *restrict q_ow, __global float4 *restrict q_dp, __global int *restrict q_path, \
    __global int *restrict q_count, int q_cap

// Level 0: primary rays; their children go to the queue.
__kernel void trace_wavefront_primary(RT_SCENE_PARAMS, __global float4 *restrict frame_rgb,
                                      __global float4 *restrict hits_out, RT_QUEUE_OUT, RT_SHADING_CONSTANTS)
{
    int x = get_global_id(0);
    int y = get_global_id(1);
    if (x >= frame->width || y >= frame->height)
        return;
    trace_wavefront_pixel(RT_SCENE_ARGS, frame, lights, materials, x, y, frame_rgb, hits_out, q_ow, q_dp, q_path,
                          q_count, q_cap);
}

// Level >= 1: every ray of the level, reflection and refraction.
__kernel void trace_wavefront(RT_SCENE_PARAMS, __global const float4 *restrict in_ow,
                              __global const float4 *restrict in_dp, __global const int *restrict in_path,
                              int n_front, int n_in, int in_cap, __global float4 *restrict frame_rgb,
                              __global float4 *restrict hits_out, RT_QUEUE_OUT, int level, RT_SHADING_CONSTANTS)
{
    int i = get_global_id(0);
    if (i >= n_in)
        return;
    trace_wavefront_ray(RT_SCENE_ARGS, frame, lights, materials, level, i, in_ow, in_dp, in_path, n_front, in_cap,
                        frame_rgb, hits_out, q_ow, q_dp, q_path, q_count, q_cap);
}
#endif /* RT_WAVEFRONT */

// The accumulated frame to RGBA8.
__kernel void pack_frame(__global const float4 *restrict frame_rgb, __global unsigned int *restrict pixels, int n)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    pixels[i] = pack_rgba8(xyz(frame_rgb[i]));
}

// Test probe: the child of `kind` spawned from each stored hit, and what it hits.
__kernel void probe_secondary(RT_SCENE_PARAMS, __global const float4 *restrict dirs,
                              __global const float4 *restrict hits, int kind, int n,
                              __global float4 *restrict origins_out, __global float4 *restrict dirs_out,
                              __global float4 *restrict hits_out, __constant RtFrame *frame,
                              __constant RtMaterial *materials)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    float4 o, d, h;
    probe_spawn(RT_SCENE_ARGS, frame, materials, kind, dirs[i], hits[i], &o, &d, &h);
    origins_out[i] = o;
    dirs_out[i] = d;
    hits_out[i] = h;
}

// Test probe: refraction and Schlick reflectance of direction d[i] at normal n[i] (n.w = ior, d.w = front).
__kernel void probe_refract(__global const float4 *restrict d, __global const float4 *restrict n,
                            __global float4 *restrict out, int count)
{
    int i = get_global_id(0);
    if (i >= count)
        return;
    out[i] = probe_refraction(d[i], n[i], n[i].w, d[i].w != 0.0f);
}
