/* rt_entry_trace.h - the entry kernels of closest hits and primary rays, written once for CUDA and
 * OpenCL (the kernel-side macros of rt_port.h):
 *   trace_rays      closest hit of arbitrary rays: origins (x, y, z, tmin), directions (x, y, z, tmax)
 *   render_primary  one thread a pixel, simple shading (the paper's Table 4 setting)
 * Every traversal runs through them: one ray a thread; the kd packet (one block a packet, its stack
 * in block-wide memory, rt_packet.h); bvh-packet (RT_LANES rays a work-item, rt_bvh_packet.h). A
 * program includes this after declaring its constant memory (the library's library_trace, lab
 * steps 00, 01, 03). With RT_RAY_MEM == RT_MEM_SHARED the ray goes through the block's shared
 * memory (§3.1.1): CUDA only, through lab step 01's place_ray_shared, which its .cu defines first.
 */
#ifndef RT_ENTRY_TRACE_H
#define RT_ENTRY_TRACE_H
/* the packet traversal's block-wide stack is declared here (rt_traverse.h refuses it elsewhere) */
#define RT_PACKET_KERNELS 1
#include "rt_primary.h"

#if RT_RAY_MEM == RT_MEM_SHARED
#ifndef RT_PLACE_RAY_SHARED
#error "RT_RAY_MEM == RT_MEM_SHARED needs place_ray_shared: lab step 01's CUDA kernels (01_memory.cu)"
#endif
#ifndef RT_BLOCK_THREADS
#error "RT_RAY_MEM == RT_MEM_SHARED needs RT_BLOCK_THREADS, threads a render block (the loader sets it)"
#endif
#endif

RT_KERNEL void trace_rays(RT_SCENE_PARAMS, RT_IN(float4) origins, RT_IN(float4) directions, RT_OUT(float4) hits,
                          int n_rays RT_WITH_FRAME)
{
    int i = rt_global_id(0);
#if RT_TRAVERSAL == RT_TRAVERSAL_BVH_PACKET
    /* RT_LANES rays a work-item, traced together in SIMD lanes */
    trace_packet(RT_SCENE_ARGS, rt_frame, origins, directions, hits, i * RT_LANES, n_rays);
#elif RT_TRAVERSAL == RT_TRAVERSAL_PACKET
    /* Threads past the end still take part in the packet's barriers */
    RT_SHARED KdPacketShared packet;
    int valid = i < n_rays;
    int j = valid ? i : 0;
    Hit hit = trace_one_packet(RT_SCENE_ARGS, rt_frame, rt_load_once(&origins[j]), rt_load_once(&directions[j]), valid,
                               &packet, rt_local_id(0));
    if (valid)
        rt_store_once(&hits[i], pack_hit(hit));
#elif RT_RAY_MEM == RT_MEM_SHARED
    /* One slot a thread of the block: no barrier */
    RT_SHARED Ray s_rays[RT_TRACE_THREADS];
    if (i >= n_rays)
        return;
    float4 o = rt_load_once(&origins[i]), d = rt_load_once(&directions[i]);
    const Ray *ray = place_ray_shared(s_rays, rt_local_id(0), make_ray(xyz(o), xyz(d), o.w, d.w));
    rt_store_once(&hits[i], pack_hit(closest_hit(RT_SCENE_ARGS, rt_frame, ray)));
#else
    if (i >= n_rays)
        return;
    rt_store_once(&hits[i], pack_hit(trace_one(RT_SCENE_ARGS, rt_frame, rt_load_once(&origins[i]),
                                               rt_load_once(&directions[i]))));
#endif
}

#if (RT_TRAVERSAL == RT_TRAVERSAL_BVH || RT_TRAVERSAL == RT_TRAVERSAL_BVH4) && defined(RT_FETCH_KERNEL)
/* The walk kept across refills: the binary BVH's (rt_bvh.h) or the 4-wide one's (rt_bvh4.h) */
#if RT_TRAVERSAL == RT_TRAVERSAL_BVH4
typedef Bvh4Trace FetchTrace;
typedef Bvh4Entry FetchEntry;
#define RT_FETCH_STACK (RT_STACK_SIZE + 3)
#define fetch_trace_start bvh4_trace_start
#define fetch_trace_steps bvh4_trace_steps
/* CUDA: 64 registers (32 warps an SM) rather than the program's 72 (28). With its stack holding refs
 * the 4-wide fetch walk fits without spilling, and the more warps hide more of its memory latency.
 * NVIDIA's OpenCL caps programs only and keeps 72 (docs/results.md, "The ray fetch's stack holding
 * refs, and 64 registers") */
#ifndef RT_FETCH_MAX_REGISTERS
#define RT_FETCH_MAX_REGISTERS 64      /* 0: the program's cap (A/Bs) */
#endif
#if RT_FETCH_MAX_REGISTERS
#define RT_FETCH_BOUNDS RT_KERNEL_MAX_REGISTERS(RT_FETCH_MAX_REGISTERS)
#else
#define RT_FETCH_BOUNDS
#endif
#else
typedef BvhTrace FetchTrace;
typedef int FetchEntry;
#define RT_FETCH_STACK RT_STACK_SIZE
#define fetch_trace_start bvh_trace_start
#define fetch_trace_steps bvh_trace_steps
#define RT_FETCH_BOUNDS
#endif

/* trace_rays with rays fetched as lanes free up (rt_bvh.h's bvh_trace_steps): each lane takes ray
 * after ray from *next_ray (zero before the launch) until all n_rays are taken; the same hits as
 * trace_rays. Launch as many threads as trace_rays would: those that start after the rays are
 * taken leave at once. Only the library's program declares it (RT_FETCH_KERNEL): the lab steps'
 * kernels stay the paper's. */
RT_KERNEL RT_FETCH_BOUNDS void trace_rays_fetch(RT_SCENE_PARAMS, RT_IN(float4) origins, RT_IN(float4) directions,
                                                RT_OUT(float4) hits, int n_rays, RT_GLOBAL int *next_ray RT_WITH_FRAME)
{
    FetchEntry stack[RT_FETCH_STACK];
    FetchTrace s;
    s.ref = BVH_DONE;
    int index = -1;
    for (;;) {
        if (s.ref == BVH_DONE) {
            if (index >= 0) {
                refine_hit_t(RT_SCENE_ARGS, &s.ray, &s.hit);
                rt_store_once(&hits[index], pack_hit(s.hit));
            }
            index = rt_atomic_inc(next_ray);
            if (index >= n_rays)
                return;
            float4 o = rt_load_once(&origins[index]), d = rt_load_once(&directions[index]);
            s.ray = make_ray(xyz(o), xyz(d), o.w, d.w);
            fetch_trace_start(&s, rt_frame->scene_min, rt_frame->scene_max);
            if (s.ref == BVH_DONE)
                continue;
        }
        fetch_trace_steps(RT_SCENE_ARGS, &s, stack);
    }
}
#endif

/* The block shape is the launch's (the paper's Fig. 4 studies it); launch_pixel maps threads to
 * pixels (RT_RAY_ORDER). With the kd packet one block is one packet of rays. */
RT_KERNEL void render_primary(RT_SCENE_PARAMS, RT_OUT(unsigned int) pixels, RT_OUT(float4) hits RT_WITH_SHADING)
{
#if RT_TRAVERSAL == RT_TRAVERSAL_BVH_PACKET
    /* RT_LANES pixels of a row a work-item, traced together in SIMD lanes */
    render_packet(RT_SCENE_ARGS, rt_frame, rt_lights, rt_materials, rt_global_id(0) * RT_LANES, rt_global_id(1),
                  pixels, hits);
#else
    int x, y;
    launch_pixel(&x, &y);
    Hit hit;
#if RT_TRAVERSAL == RT_TRAVERSAL_PACKET
    /* Threads outside the frame still take part in the packet's barriers */
    RT_SHARED KdPacketShared packet;
    int valid = x < rt_frame->width && y < rt_frame->height;
    unsigned int rgba = render_pixel_packet(RT_SCENE_ARGS, rt_frame, rt_lights, rt_materials, x, y, valid, &packet,
                                            rt_local_id(1) * rt_local_size(0) + rt_local_id(0), &hit);
    if (!valid)
        return;
#elif RT_RAY_MEM == RT_MEM_SHARED
    RT_SHARED Ray s_rays[RT_BLOCK_THREADS];
    if (x >= rt_frame->width || y >= rt_frame->height)
        return;
    const Ray *ray = place_ray_shared(s_rays, rt_local_id(1) * rt_local_size(0) + rt_local_id(0),
                                      camera_ray(rt_frame, x, y));
    unsigned int rgba = render_ray(RT_SCENE_ARGS, rt_frame, rt_lights, rt_materials, ray, &hit);
#else
    if (x >= rt_frame->width || y >= rt_frame->height)
        return;
    unsigned int rgba = render_pixel(RT_SCENE_ARGS, rt_frame, rt_lights, rt_materials, x, y, &hit);
#endif
    int i = y * rt_frame->width + x;
    pixels[i] = rgba;
#if RT_WRITE_HITS
    hits[i] = pack_hit(hit);
#endif
#endif
}

#endif /* RT_ENTRY_TRACE_H */
