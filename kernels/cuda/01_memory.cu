// Lab step 01: memory placement (§3.1.1) (CUDA). Same entry kernels and arguments as step 00; the
// defines choose where each kind of data lives, and rtlab bench memory times every choice:
//   RT_NODE_MEM   tree, object list, vertices, normals: global memory through __ldg, or texture
//                 objects (the fetch functions in kernels/shared/rt_memory.h)
//   RT_CONST_MEM  camera, lights, materials: __constant__ symbols, or __device__ (global) symbols
//   RT_RAY_MEM    the ray: registers; shared memory (the paper's cure for local-memory rays, below);
//                 or arrays indexed by the split axis (get3 in rt_port.h), what spilled in 2008
// fetch_scene reads any scene buffer element through the placement compiled in, so a test can check
// a placement against the host arrays bit for bit.
#include "rt_primary.h"

#if RT_CONST_MEM == RT_MEM_GLOBAL
#define RT_CONST_SPACE __device__
#else
#define RT_CONST_SPACE __constant__
#endif

RT_CONST_SPACE RtFrame c_frame;
RT_CONST_SPACE RtLight c_lights[RT_MAX_LIGHTS];
RT_CONST_SPACE RtMaterial c_materials[RT_MAX_MATERIALS];

#if RT_RAY_MEM == RT_MEM_SHARED
#if !defined(RT_BLOCK_THREADS) || !defined(RT_TRACE_THREADS)
#error "RT_RAY_MEM == RT_MEM_SHARED needs RT_BLOCK_THREADS and RT_TRACE_THREADS (threads a block; the loader sets them)"
#endif
// Store this thread's ray in its slot of the block's shared ray array and return the slot: the
// traversal and shading then read origin and direction from shared memory, where indexing by the
// split axis costs nothing, instead of local memory (§3.1.1). One slot a thread, so no barrier.
RT_FN const Ray *place_ray_shared(Ray *slots, int lane, Ray ray)
{
    /* BEGIN SOLUTION */
    /* STUB: slots[lane] = make_ray(f3(0.0f, 0.0f, 0.0f), f3(0.0f, 0.0f, 1.0f), 0.0f, 0.0f); return &slots[lane]; */
    slots[lane] = ray;
    return &slots[lane];
    /* END SOLUTION */
}
#endif

// Closest hit of arbitrary rays: origins (x, y, z, tmin), directions (x, y, z, tmax).
RT_KERNEL void trace_rays(RT_SCENE_PARAMS, const float4 *__restrict__ origins,
                          const float4 *__restrict__ directions, float4 *__restrict__ hits, int n_rays)
{
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n_rays)
        return;
    float4 o = origins[i], d = directions[i];
#if RT_RAY_MEM == RT_MEM_SHARED
    __shared__ Ray s_rays[RT_TRACE_THREADS];
    const Ray *ray = place_ray_shared(s_rays, threadIdx.x, make_ray(xyz(o), xyz(d), o.w, d.w));
    hits[i] = pack_hit(closest_hit(RT_SCENE_ARGS, &c_frame, ray));
#else
    hits[i] = pack_hit(trace_one(RT_SCENE_ARGS, &c_frame, o, d));
#endif
}

// One thread a pixel; block_pixel maps threads to pixels (RT_RAY_ORDER).
RT_KERNEL void render_primary(RT_SCENE_PARAMS, unsigned int *__restrict__ pixels, float4 *__restrict__ hits)
{
    int x, y;
    block_pixel(blockIdx.x, blockIdx.y, blockDim.x, blockDim.y, threadIdx.x, threadIdx.y, &x, &y);
    if (x >= c_frame.width || y >= c_frame.height)
        return;
    Hit hit;
#if RT_RAY_MEM == RT_MEM_SHARED
    __shared__ Ray s_rays[RT_BLOCK_THREADS];
    const Ray *ray = place_ray_shared(s_rays, threadIdx.y * blockDim.x + threadIdx.x, camera_ray(&c_frame, x, y));
    unsigned int rgba = render_ray(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, ray, &hit);
#else
    unsigned int rgba = render_pixel(RT_SCENE_ARGS, &c_frame, c_lights, c_materials, x, y, &hit);
#endif
    int i = y * c_frame.width + x;
    pixels[i] = rgba;
#if RT_WRITE_HITS
    hits[i] = pack_hit(hit);
#endif
}

RT_FN int4 float4_bits(float4 f)
{
    return make_int4(rt_as_int(f.x), rt_as_int(f.y), rt_as_int(f.z), rt_as_int(f.w));
}

// Element i < n of scene buffer `which` (0..6 in RT_SCENE_PARAMS order) as raw bits, read through
// the load_* path of this placement.
RT_KERNEL void fetch_scene(RT_SCENE_PARAMS, int which, int n, int4 *__restrict__ out)
{
    int i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n)
        return;
    int2 node;
    int4 v = make_int4(0, 0, 0, 0);
    switch (which) {
    case 0: node = load_node(nodes, i); v = make_int4(node.x, node.y, 0, 0); break;
    case 1: v = float4_bits(load_node_data(node_data, i)); break;
    case 2: v.x = load_object(objects, i); break;
    case 3: v = float4_bits(load_tri_vertex(tris, i / 3, i % 3)); break;
    case 4: v = float4_bits(load_tri_data(tri_data, i)); break;
    case 5: v = float4_bits(load_tri_normal(normals, i / 3, i % 3)); break;
    default: v.x = load_tri_material(tri_materials, i); break;
    }
    out[i] = v;
}
