// Lab step 01: memory placement (§3.1.1) (OpenCL). Same entry kernels and arguments as step 00; the
// defines choose where each kind of data lives:
//   RT_NODE_MEM   tree, object list, vertices, normals: __global buffers, or image1d_buffer images
//                 (the fetch functions in kernels/shared/rt_memory.h)
//   RT_CONST_MEM  camera, lights, materials: __constant or __global arguments (RT_CONST, rt_port.h)
//   RT_RAY_MEM    the ray: registers, or arrays indexed by the split axis (get3 in rt_port.h)
// The paper's third placement, the ray in shared (OpenCL: local) memory, is CUDA only: the shared
// functions take the ray through an unqualified pointer, which OpenCL C 1.2 makes __private, and
// the generic address space that would take a __local ray is optional in OpenCL 3.0 - neither
// PoCL 3.1 nor NVIDIA's driver has it.
// fetch_scene reads any scene buffer element through the placement compiled in, so a test can check
// a placement against the host arrays bit for bit.
#include "rt_primary.h"

#if RT_RAY_MEM == RT_MEM_SHARED
#error "RT_RAY_MEM == RT_MEM_SHARED (ray in local memory) needs the generic address space; CUDA only"
#endif

// Closest hit of arbitrary rays: origins (x, y, z, tmin), directions (x, y, z, tmax).
__kernel void trace_rays(RT_SCENE_PARAMS, __global const float4 *restrict origins,
                         __global const float4 *restrict directions, __global float4 *restrict hits,
                         int n_rays, RT_CONST const RtFrame *frame)
{
    int i = get_global_id(0);
    if (i >= n_rays)
        return;
    hits[i] = pack_hit(trace_one(RT_SCENE_ARGS, frame, origins[i], directions[i]));
}

// One work-item a pixel; block_pixel maps work-items to pixels (RT_RAY_ORDER).
__kernel void render_primary(RT_SCENE_PARAMS, __global unsigned int *restrict pixels,
                             __global float4 *restrict hits, RT_CONST const RtFrame *frame,
                             RT_CONST const RtLight *lights, RT_CONST const RtMaterial *materials)
{
    int x, y;
    block_pixel(get_group_id(0), get_group_id(1), get_local_size(0), get_local_size(1), get_local_id(0),
                get_local_id(1), &x, &y);
    if (x >= frame->width || y >= frame->height)
        return;
    Hit hit;
    unsigned int rgba = render_pixel(RT_SCENE_ARGS, frame, lights, materials, x, y, &hit);
    int i = y * frame->width + x;
    pixels[i] = rgba;
#if RT_WRITE_HITS
    hits[i] = pack_hit(hit);
#endif
}

// Element i < n of scene buffer `which` (0..6 in RT_SCENE_PARAMS order) as raw bits, read through
// the load_* path of this placement.
__kernel void fetch_scene(RT_SCENE_PARAMS, int which, int n, __global int4 *restrict out)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    int2 node;
    int4 v = (int4)(0, 0, 0, 0);
    switch (which) {
    case 0: node = load_node(nodes, i); v = (int4)(node.x, node.y, 0, 0); break;
    case 1: v = as_int4(load_node_data(node_data, i)); break;
    case 2: v.x = load_object(objects, i); break;
    case 3: v = as_int4(load_tri_vertex(tris, i / 3, i % 3)); break;
    case 4: v = as_int4(load_tri_data(tri_data, i)); break;
    case 5: v = as_int4(load_tri_normal(normals, i / 3, i % 3)); break;
    default: v.x = load_tri_material(tri_materials, i); break;
    }
    out[i] = v;
}
