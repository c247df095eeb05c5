// Lab step 01: memory placement (§3.1.1) (CUDA). Same entry kernels and arguments as step 00 (written
// once, kernels/shared/rt_entry_*.h); the defines choose where each kind of data lives, and rtlab
// bench memory times every choice:
//   RT_NODE_MEM   tree, object list, vertices, normals: global memory through __ldg, or texture
//                 objects (the fetch functions in kernels/shared/rt_memory.h)
//   RT_CONST_MEM  camera, lights, materials: __constant__ symbols, or __device__ (global) symbols
//   RT_RAY_MEM    the ray: registers; shared memory (the paper's cure for local-memory rays, below);
//                 or arrays indexed by the split axis (get3 in rt_port.h), what spilled in 2008
// fetch_scene reads any scene buffer element through the placement compiled in, so a test can check
// a placement against the host arrays bit for bit.
#include "rt_types.h"

#if RT_CONST_MEM == RT_MEM_GLOBAL
#define RT_CONST_SPACE __device__
#else
#define RT_CONST_SPACE __constant__
#endif

RT_CONST_SPACE RtFrame c_frame;
RT_CONST_SPACE RtLight c_lights[RT_MAX_LIGHTS];
RT_CONST_SPACE RtMaterial c_materials[RT_MAX_MATERIALS];

#if RT_RAY_MEM == RT_MEM_SHARED
// Store this thread's ray in its slot of the block's shared ray array and return the slot: the
// traversal and shading then read origin and direction from shared memory, where indexing by the
// split axis costs nothing, instead of local memory (§3.1.1). One slot a thread, so no barrier.
// trace_rays and render_primary (rt_entry_trace.h) call it.
RT_FN const Ray *place_ray_shared(Ray *slots, int lane, Ray ray)
{
    /* BEGIN SOLUTION */
    /* STUB: slots[lane] = make_ray(f3(0.0f, 0.0f, 0.0f), f3(0.0f, 0.0f, 1.0f), 0.0f, 0.0f); return &slots[lane]; */
    slots[lane] = ray;
    return &slots[lane];
    /* END SOLUTION */
}
#define RT_PLACE_RAY_SHARED 1
#endif

#include "rt_entry_trace.h"      // trace_rays, render_primary
#include "rt_entry_fetch.h"      // fetch_scene
