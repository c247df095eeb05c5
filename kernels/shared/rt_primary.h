/* rt_primary.h - per-ray work of closest hits and primary rays (simple shading: the paper's Table 4
 * setting), and how threads map to pixels. The entry kernels (rt_entry_trace.h, rt_entry_ray_grid.h,
 * rt_entry_loop.h) only find their ray or pixel and call these. */
#ifndef RT_PRIMARY_H
#define RT_PRIMARY_H
#include "rt_traverse.h"
#include "rt_shade.h"

/* The host reads a hit as float4 (t, u, v, tri bits); a miss has tri = -1 and t = tmax. */
RT_FN float4 pack_hit(Hit h) { return f4(h.t, h.u, h.v, rt_as_float(h.tri)); }

/* Closest hit along *ray, its distance refined. The ray may live anywhere the pointer reaches: lab
 * step 01's CUDA kernels keep it in shared memory (§3.1.1). */
RT_FN Hit closest_hit(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, const Ray *ray)
{
    Hit hit = make_miss(ray->tmax);
    trace_closest(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, ray, &hit);
    refine_hit_t(RT_SCENE_ARGS, ray, &hit);
    return hit;
}

/* Closest hit of one ray: the work of trace_rays. origin.w = tmin, direction.w = tmax. */
RT_FN Hit trace_one(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, float4 origin, float4 direction)
{
    Ray ray = make_ray(xyz(origin), xyz(direction), origin.w, direction.w);
    return closest_hit(RT_SCENE_ARGS, frame, &ray);
}

/* Closest hit of one ray among triangles [0, n_tris), no acceleration structure, its distance
 * refined as closest_hit's: the brute force in the kernels' own arithmetic that every traversal must
 * match, ties included (trace_rays_loop, rt_entry_loop.h). */
RT_FN Hit trace_one_loop(RT_SCENE_PARAMS, float4 origin, float4 direction, int n_tris)
{
    Ray ray = make_ray(xyz(origin), xyz(direction), origin.w, direction.w);
    Hit hit = make_miss(ray.tmax);
    if (ray_can_enter(&ray))
        intersect_first_tris(RT_SCENE_ARGS, &ray, n_tris, &hit);
    refine_hit_t(RT_SCENE_ARGS, &ray, &hit);
    return hit;
}

#if RT_TRAVERSAL == RT_TRAVERSAL_BVH_PACKET
/* Lane k's closest hit after a packet traversal, refined as trace_one's (a miss for a lane that was
 * not live); ray is lane k's ray. */
RT_FN Hit packet_lane_hit(RT_SCENE_PARAMS, const HitPacket *h, lanei live, int k, const Ray *ray)
{
    Hit hit = make_miss(ray->tmax);
    if (li_get(live, k)) {
        packet_get_hit(h, k, &hit);
        refine_hit_t(RT_SCENE_ARGS, ray, &hit);
    }
    return hit;
}

/* The work of trace_rays with the packet traversal: rays first .. first + RT_LANES - 1 (those
 * below n_rays) traced as one packet where they are coherent (packet_is_coherent), else one by one
 * through the wide traversal (trace_one); each hit refined and written as trace_one's would be. */
RT_FN void trace_packet(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_GLOBAL const float4 *origins,
                        RT_GLOBAL const float4 *directions, RT_GLOBAL float4 *hits, int first, int n_rays)
{
    int count = n_rays - first < RT_LANES ? n_rays - first : RT_LANES;
    lanef ox, oy, oz, tmin, dx, dy, dz, tmax;
    lanes_load_rows(origins, first, count, &ox, &oy, &oz, &tmin);
    lanes_load_rows(directions, first, count, &dx, &dy, &dz, &tmax);
    RayPacket p;
    HitPacket h;
    lanei live = packet_init(&p, &h, frame->scene_min, frame->scene_max, ox, oy, oz, dx, dy, dz, tmin, tmax);
    /* lanes past count: d = 0 */
    if (!packet_is_coherent(&p, live)) {
        for (int k = 0; k < count; ++k)
            hits[first + k] = pack_hit(trace_one(RT_SCENE_ARGS, frame, origins[first + k], directions[first + k]));
        return;
    }
    if (lane_any(live))
        traverse_bvh_packet(RT_SCENE_ARGS, &p, &h, live, 0);
    /* Unrolled, so that each lane is read by a constant index (an extract), not through memory */
#pragma unroll
    for (int k = 0; k < RT_LANES; ++k) {
        if (k < count) {
            Ray ray = make_ray(f3(lf_get(ox, k), lf_get(oy, k), lf_get(oz, k)),
                               f3(lf_get(dx, k), lf_get(dy, k), lf_get(dz, k)), lf_get(tmin, k), lf_get(tmax, k));
            hits[first + k] = pack_hit(packet_lane_hit(RT_SCENE_ARGS, &h, live, k, &ray));
        }
    }
}
#endif

/* Shaded colour of the closest hit along *ray; its hit record in *hit. */
RT_FN unsigned int render_ray(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                              RT_CONST const RtMaterial *materials, const Ray *ray, Hit *hit)
{
    *hit = closest_hit(RT_SCENE_ARGS, frame, ray);
    return pack_rgba8(shade_lambert(RT_SCENE_ARGS, frame, lights, materials, ray, hit));
}

/* Shaded colour of pixel (x, y); its hit record in *hit. */
RT_FN unsigned int render_pixel(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame,
                                RT_CONST const RtLight *lights, RT_CONST const RtMaterial *materials,
                                int x, int y, Hit *hit)
{
    Ray ray = camera_ray(frame, x, y);
    return render_ray(RT_SCENE_ARGS, frame, lights, materials, &ray, hit);
}

#if RT_TRAVERSAL == RT_TRAVERSAL_BVH_PACKET
/* The work of render_primary with the packet traversal: pixels x0 .. x0 + RT_LANES - 1 of row y
 * (those inside the frame), their camera rays traced as one packet (one by one where they are not
 * coherent: a row segment across an axis of the view, where a direction component changes sign),
 * each then shaded and written as render_pixel's would be. */
RT_FN void render_packet(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                         RT_CONST const RtMaterial *materials, int x0, int y, RT_GLOBAL unsigned int *pixels,
                         RT_GLOBAL float4 *hits)
{
    if (x0 >= frame->width || y >= frame->height)
        return;
    int count = frame->width - x0 < RT_LANES ? frame->width - x0 : RT_LANES;
    Ray rays[RT_LANES];
#pragma unroll
    for (int k = 0; k < RT_LANES; ++k)
        rays[k] = camera_ray(frame, k < count ? x0 + k : x0, y);
    RayPacket p;
    HitPacket h;
    lanei live = packet_of_rays(&p, &h, frame->scene_min, frame->scene_max, rays, count);
    if (!packet_is_coherent(&p, live)) {
        for (int k = 0; k < count; ++k) {
            Hit hit;
            int i = y * frame->width + x0 + k;
            pixels[i] = render_pixel(RT_SCENE_ARGS, frame, lights, materials, x0 + k, y, &hit);
#if RT_WRITE_HITS
            hits[i] = pack_hit(hit);
#endif
        }
        return;
    }
    if (lane_any(live))
        traverse_bvh_packet(RT_SCENE_ARGS, &p, &h, live, 0);
#pragma unroll
    for (int k = 0; k < RT_LANES; ++k) {
        if (k < count) {
            Hit hit = packet_lane_hit(RT_SCENE_ARGS, &h, live, k, &rays[k]);
            int i = y * frame->width + x0 + k;
            pixels[i] = pack_rgba8(shade_lambert(RT_SCENE_ARGS, frame, lights, materials, &rays[k], &hit));
#if RT_WRITE_HITS
            hits[i] = pack_hit(hit);
#endif
        }
    }
}
#endif

/* Bits 0, 2, 4, ... of v packed together (Morton decode). */
RT_FN int compact_even_bits(int v)
{
    v &= 0x55555555;
    v = (v | (v >> 1)) & 0x33333333;
    v = (v | (v >> 2)) & 0x0f0f0f0f;
    v = (v | (v >> 4)) & 0x00ff00ff;
    return (v | (v >> 8)) & 0x0000ffff;
}

RT_FN int log2_int(int n)
{
    int k = 0;
    while ((2 << k) <= n)
        ++k;
    return k;
}

/* Pixel of thread (tx, ty) in block (bx, by) of bw x bh threads: which rays share a warp (§4.1).
 * RT_ORDER_ROWS: a warp takes a row segment of the block. RT_ORDER_MORTON: thread t = ty * bw + tx
 * takes the t-th pixel of the block's Z curve, so 32 threads cover an 8x4 tile; bw and bh must be
 * powers of two (the loader checks), the longer side taking the curve's high bits. */
RT_FN void block_pixel(int bx, int by, int bw, int bh, int tx, int ty, int *x, int *y)
{
#if RT_RAY_ORDER == RT_ORDER_MORTON
    int t = ty * bw + tx;
    int lw = log2_int(bw), lh = log2_int(bh);
    int m = lw < lh ? lw : lh;
    int low = t & ((1 << (2 * m)) - 1), high = t >> (2 * m);
    int mx = compact_even_bits(low), my = compact_even_bits(low >> 1);
    if (lw > lh)
        mx |= high << m;
    else
        my |= high << m;
    *x = bx * bw + mx;
    *y = by * bh + my;
#else
    *x = bx * bw + tx;
    *y = by * bh + ty;
#endif
}

/* This thread's pixel in a 2-D launch: its block's tile, in block_pixel's order. */
RT_FN void launch_pixel(int *x, int *y)
{
    block_pixel(rt_group_id(0), rt_group_id(1), rt_local_size(0), rt_local_size(1), rt_local_id(0), rt_local_id(1), x, y);
}

#endif /* RT_PRIMARY_H */
