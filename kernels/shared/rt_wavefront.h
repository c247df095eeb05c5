/* rt_wavefront.h - the kernel tree's rays traced level by level (beyond the paper): one launch per
 * level over a queue of every ray of that level, reflection and refraction alike, instead of one
 * launch per tree node (rt_whitted.h, §3.2.2).
 *
 * Why: depth-first, level L of the tree is 2^L launches, each over the rays of one node; the deep
 * nodes hold a few thousand rays, too few warps to hide a traversal's memory latency, and each
 * small launch costs as long as its slowest ray (H100, SPONZA, 3 bounces: 8 launches of level 3
 * took 0.74 ms for 0.49 M parent records). Here a ray's children are spawned where the ray is
 * shaded, appended to the next level's queue, and the next launch traces them all.
 *
 * Same rays as the tree: the kernel shades a hit with shade_local and spawns with spawn_reflection
 * / spawn_refraction, exactly as the tree's kernels do, so every ray and its weight are bit for
 * bit the tree's. Only the order of the additions into the float4 frame differs (and, with
 * several rays of one pixel in a launch, depends on the atomics), so an 8-bit pixel may differ by
 * one step where a sum lands on a rounding boundary.
 *
 * A queue is struct-of-arrays: (origin, weight), (direction, pixel bits), path. Reflection
 * children are appended from the front (count[0]), refraction children from the back (count[1]),
 * so each kind stays together and keeps its neighbours' coherence; a parent appends at most one
 * of each, so capacity 2 x (rays of the level) cannot overflow (the host allocates that). The
 * path names the ray's tree node: bit L-1 is set when the level-L ray is a refraction ray (node
 * "PRT" = path 0b10 at level 2). Two queues, the level traced and the one filled, are alive at
 * once, however deep the tree.
 */
#ifndef RT_WAVEFRONT_H
#define RT_WAVEFRONT_H
#include "rt_whitted.h"

#define RT_QUEUE_PENDING 2   /* q_count[2] of level 0's queue: the pixels listed in `pending` */

/* Add colour c to a pixel that other rays of the same launch may also add to (rt_atomic_add_float:
 * rt_port.h). */
RT_FN void add_rgb_atomic(RT_GLOBAL float4 *frame_rgb, int pixel, float3 c)
{
    RT_GLOBAL float *p = (RT_GLOBAL float *)(frame_rgb + pixel);
    rt_atomic_add_float(p, c.x);
    rt_atomic_add_float(p + 1, c.y);
    rt_atomic_add_float(p + 2, c.z);
}

/* Append a child ray of kind RT_RAY_REFLECTION (front) or RT_RAY_REFRACTION (back). */
RT_FN void queue_push(RT_GLOBAL float4 *q_ow, RT_GLOBAL float4 *q_dp, RT_GLOBAL int *q_path,
                      RT_GLOBAL int *q_count, int q_cap, int kind, const Ray *ray, float w, int pixel, int path)
{
    int k = rt_atomic_inc(&q_count[kind]);
    int slot = kind == RT_RAY_REFLECTION ? k : q_cap - 1 - k;
    q_ow[slot] = f4(ray->o.x, ray->o.y, ray->o.z, w);
    q_dp[slot] = f4(ray->d.x, ray->d.y, ray->d.z, rt_as_float(pixel));
    q_path[slot] = path;
}

/* The ray of thread i of a launch over a queue with n_front reflection rays at the front. */
RT_FN int queue_slot(int i, int n_front, int q_cap)
{
    return i < n_front ? i : q_cap - 1 - (i - n_front);
}

/* A traced ray of level `level` (direction d, weight w, its hit): spawn its children into the
 * next queue (below RT_MAX_DEPTH), counted in *spawned, then shade it; returns weight x colour.
 * Children first, so the surface need not stay live across the shadow rays. */
RT_FN float3 shade_and_spawn(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                             RT_CONST const RtMaterial *materials, int level, float3 d, float w, const Hit *hit,
                             int pixel, int path, RT_GLOBAL float4 *q_ow, RT_GLOBAL float4 *q_dp,
                             RT_GLOBAL int *q_path, RT_GLOBAL int *q_count, int q_cap, int *spawned)
{
    *spawned = 0;
    if (hit->tri < 0)
        return mul3(xyz(frame->background), w);
    Surface s = surface_at(RT_SCENE_ARGS, d, hit);
    if (level < RT_MAX_DEPTH) {
        Ray child;
        float w_child;
#if RT_REFLECTION
        if (spawn_reflection(materials, d, w, &s, &child, &w_child)) {
            queue_push(q_ow, q_dp, q_path, q_count, q_cap, RT_RAY_REFLECTION, &child, w_child, pixel, path);
            ++*spawned;
        }
#endif
#if RT_REFRACTION
        if (spawn_refraction(materials, d, w, &s, &child, &w_child)) {
            queue_push(q_ow, q_dp, q_path, q_count, q_cap, RT_RAY_REFRACTION, &child, w_child, pixel,
                       path | (1 << level));
            ++*spawned;
        }
#endif
    }
    return mul3(shade_local(RT_SCENE_ARGS, frame, lights, materials, d, &s), w);
}

/* Level 0: the primary ray of pixel (x, y). A pixel that spawns no child is done: its RGBA8 is
 * stored here. One that does stores its colour as the float4 frame's first term and is listed in
 * `pending` (count q_count[2]) for pack_pending, after the last level: the frame's float4 traffic and
 * its packing are then only those of the pixels that secondary rays reach. */
RT_FN void trace_wavefront_pixel(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                                 RT_CONST const RtMaterial *materials, int x, int y, RT_GLOBAL float4 *frame_rgb,
                                 RT_GLOBAL unsigned int *pixels, RT_GLOBAL int *pending, RT_GLOBAL float4 *hits_out,
                                 RT_GLOBAL float4 *q_ow, RT_GLOBAL float4 *q_dp, RT_GLOBAL int *q_path,
                                 RT_GLOBAL int *q_count, int q_cap)
{
    int pixel = y * frame->width + x;
    Ray ray = camera_ray(frame, x, y);
    Hit hit = make_miss(ray.tmax);
    trace_closest(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, &ray, &hit);
#if RT_WRITE_HITS
    hits_out[pixel] = pack_hit(hit);
#endif
    int spawned;
    float3 c = shade_and_spawn(RT_SCENE_ARGS, frame, lights, materials, 0, ray.d, 1.0f, &hit, pixel, 0, q_ow,
                               q_dp, q_path, q_count, q_cap, &spawned);
    if (spawned) {
        frame_rgb[pixel] = f4(c.x, c.y, c.z, 1.0f);
        pending[rt_atomic_inc(&q_count[RT_QUEUE_PENDING])] = pixel;
    } else {
        pixels[pixel] = pack_rgba8(c);
    }
}

/* Level >= 1: thread i traces ray i of the level's queue and adds its colour to its pixel. */
RT_FN void trace_wavefront_ray(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                               RT_CONST const RtMaterial *materials, int level, int i,
                               RT_GLOBAL const float4 *in_ow, RT_GLOBAL const float4 *in_dp,
                               RT_GLOBAL const int *in_path, int n_front, int in_cap,
                               RT_GLOBAL float4 *frame_rgb, RT_GLOBAL float4 *hits_out, RT_GLOBAL float4 *q_ow,
                               RT_GLOBAL float4 *q_dp, RT_GLOBAL int *q_path, RT_GLOBAL int *q_count, int q_cap)
{
    int slot = queue_slot(i, n_front, in_cap);
    float4 ow = in_ow[slot];
    float4 dp = in_dp[slot];
    int pixel = rt_as_int(dp.w);
    Ray ray = make_ray(xyz(ow), xyz(dp), 0.0f, RT_INF);
    Hit hit = make_miss(RT_INF);
    trace_closest(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, &ray, &hit);
#if RT_WRITE_HITS
    hits_out[i] = pack_hit(hit);
#endif
    int spawned;
    float3 c = shade_and_spawn(RT_SCENE_ARGS, frame, lights, materials, level, ray.d, ow.w, &hit, pixel,
                               in_path[slot], q_ow, q_dp, q_path, q_count, q_cap, &spawned);
    add_rgb_atomic(frame_rgb, pixel, c);
}

#endif /* RT_WAVEFRONT_H */
