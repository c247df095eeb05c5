/* rt_entry_bounces.h - reflection and refraction rays (§3.2.2, Table 5), written once for CUDA and
 * OpenCL (the library's library_bounces, lab step 05). Two schedules of the same rays:
 *   the paper's kernel tree: every tree node one launch of trace_reflection or trace_refraction over
 *     the records of the level above, walked depth-first by the host (rtlab/device/whitted_frames.py);
 *   RT_WAVEFRONT: one launch per level over a queue of all its rays (rt_wavefront.h says why).
 */
#ifndef RT_ENTRY_BOUNCES_H
#define RT_ENTRY_BOUNCES_H
#include "rt_whitted.h"
#if RT_WAVEFRONT
#include "rt_wavefront.h"
#endif

/* The record buffers of one level: (direction, weight), (t, u, v, tri bits), pixel (compacted). */
#define RT_LEVEL_OUT RT_OUT(float4) dirs_out, RT_OUT(float4) hits_out, RT_OUT(int) pixels_out, RT_OUT(int) count_out
#define RT_LEVEL_IN RT_IN(float4) dirs_in, RT_IN(float4) hits_in, RT_IN(int) pixels_in, int n_in

#if !RT_WAVEFRONT
/* Level 0: primary rays, shaded into the float4 frame, recorded for the first bounce. */
RT_KERNEL void trace_primary_tree(RT_SCENE_PARAMS, RT_OUT(float4) frame_rgb, RT_LEVEL_OUT RT_WITH_SHADING)
{
    int x, y;
    launch_pixel(&x, &y);
    if (x >= rt_frame->width || y >= rt_frame->height)
        return;
    trace_tree_primary(RT_SCENE_ARGS, rt_frame, rt_lights, rt_materials, x, y, frame_rgb, dirs_out, hits_out,
                       pixels_out, count_out);
}

#if RT_REFLECTION
/* A reflection node: one reflection ray per record of the level above. */
RT_KERNEL void trace_reflection(RT_SCENE_PARAMS, RT_LEVEL_IN, RT_OUT(float4) frame_rgb, RT_LEVEL_OUT,
                                int level RT_WITH_SHADING)
{
    int i = rt_global_id(0);
    if (i >= n_in)
        return;
    trace_tree_secondary(RT_SCENE_ARGS, rt_frame, rt_lights, rt_materials, RT_RAY_REFLECTION, level, i, dirs_in,
                         hits_in, pixels_in, frame_rgb, dirs_out, hits_out, pixels_out, count_out);
}
#endif

#if RT_REFRACTION
/* A refraction node: one refraction ray per record of the level above. */
RT_KERNEL void trace_refraction(RT_SCENE_PARAMS, RT_LEVEL_IN, RT_OUT(float4) frame_rgb, RT_LEVEL_OUT,
                                int level RT_WITH_SHADING)
{
    int i = rt_global_id(0);
    if (i >= n_in)
        return;
    trace_tree_secondary(RT_SCENE_ARGS, rt_frame, rt_lights, rt_materials, RT_RAY_REFRACTION, level, i, dirs_in,
                         hits_in, pixels_in, frame_rgb, dirs_out, hits_out, pixels_out, count_out);
}
#endif

#if RT_TWO_PASS
/* Two-pass tree: shadow rays and shading of one node's records, after the node's launch. */
RT_KERNEL void shade_records(RT_SCENE_PARAMS, RT_LEVEL_IN, RT_OUT(float4) frame_rgb, int level RT_WITH_SHADING)
{
    int i = rt_global_id(0);
    if (i >= n_in)
        return;
    shade_tree_record(RT_SCENE_ARGS, rt_frame, rt_lights, rt_materials, level, i, dirs_in, hits_in, pixels_in,
                      frame_rgb);
}
#endif

#else /* RT_WAVEFRONT */
/* The queue a launch fills: (origin, weight), (direction, pixel bits), path, counts (reflection,
 * refraction, pending pixels), capacity. */
#define RT_QUEUE_OUT RT_OUT(float4) q_ow, RT_OUT(float4) q_dp, RT_OUT(int) q_path, RT_OUT(int) q_count, int q_cap

/* Level 0: primary rays; their children go to the queue, their pixels to `pixels` or `pending`. */
RT_KERNEL void trace_wavefront_primary(RT_SCENE_PARAMS, RT_OUT(float4) frame_rgb, RT_OUT(unsigned int) pixels,
                                       RT_OUT(int) pending, RT_OUT(float4) hits_out, RT_QUEUE_OUT RT_WITH_SHADING)
{
    int x, y;
    launch_pixel(&x, &y);
    if (x >= rt_frame->width || y >= rt_frame->height)
        return;
    trace_wavefront_pixel(RT_SCENE_ARGS, rt_frame, rt_lights, rt_materials, x, y, frame_rgb, pixels, pending,
                          hits_out, q_ow, q_dp, q_path, q_count, q_cap);
}

/* Level >= 1: every ray of the level, reflection and refraction. */
RT_KERNEL void trace_wavefront(RT_SCENE_PARAMS, RT_IN(float4) in_ow, RT_IN(float4) in_dp, RT_IN(int) in_path,
                               int n_front, int n_in, int in_cap, RT_OUT(float4) frame_rgb, RT_OUT(float4) hits_out,
                               RT_QUEUE_OUT, int level RT_WITH_SHADING)
{
    int i = rt_global_id(0);
    if (i >= n_in)
        return;
    trace_wavefront_ray(RT_SCENE_ARGS, rt_frame, rt_lights, rt_materials, level, i, in_ow, in_dp, in_path, n_front,
                        in_cap, frame_rgb, hits_out, q_ow, q_dp, q_path, q_count, q_cap);
}

/* After the last level: the pending pixels of the float4 frame to RGBA8. */
RT_KERNEL void pack_pending(RT_IN(float4) frame_rgb, RT_IN(int) pending, RT_OUT(unsigned int) pixels, int n)
{
    int i = rt_global_id(0);
    if (i >= n)
        return;
    int pixel = pending[i];
    pixels[pixel] = pack_rgba8(xyz(frame_rgb[pixel]));
}
#endif /* RT_WAVEFRONT */

/* The accumulated frame to RGBA8. */
RT_KERNEL void pack_frame(RT_IN(float4) frame_rgb, RT_OUT(unsigned int) pixels, int n)
{
    int i = rt_global_id(0);
    if (i >= n)
        return;
    pixels[i] = pack_rgba8(xyz(frame_rgb[i]));
}

/* Test probe: the child of `kind` spawned from each stored hit, and what it hits. */
RT_KERNEL void probe_secondary(RT_SCENE_PARAMS, RT_IN(float4) dirs, RT_IN(float4) hits, int kind, int n,
                               RT_OUT(float4) origins_out, RT_OUT(float4) dirs_out,
                               RT_OUT(float4) hits_out RT_WITH_FRAME_MATERIALS)
{
    int i = rt_global_id(0);
    if (i >= n)
        return;
    float4 o, d, h;
    probe_spawn(RT_SCENE_ARGS, rt_frame, rt_materials, kind, dirs[i], hits[i], &o, &d, &h);
    origins_out[i] = o;
    dirs_out[i] = d;
    hits_out[i] = h;
}

/* Test probe: refraction and Schlick reflectance of direction d[i] at normal n[i] (n.w = ior, d.w = front). */
RT_KERNEL void probe_refract(RT_IN(float4) d, RT_IN(float4) n, RT_OUT(float4) out, int count)
{
    int i = rt_global_id(0);
    if (i >= count)
        return;
    out[i] = probe_refraction(d[i], n[i], n[i].w, d[i].w != 0.0f);
}

#endif /* RT_ENTRY_BOUNCES_H */
