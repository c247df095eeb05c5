/* rt_entry_fetch.h - any scene buffer element read back through the memory placement compiled in
 * (rt_memory.h's loaders), so a test can check a placement against the host arrays bit for bit
 * (lab step 01). */
#ifndef RT_ENTRY_FETCH_H
#define RT_ENTRY_FETCH_H
#include "rt_memory.h"
#include "rt_types.h"

RT_FN int4 float4_bits(float4 f) { return i4(rt_as_int(f.x), rt_as_int(f.y), rt_as_int(f.z), rt_as_int(f.w)); }

/* Element i < n of scene buffer `which` (0..6 in RT_SCENE_PARAMS order) as raw bits. */
RT_KERNEL void fetch_scene(RT_SCENE_PARAMS, int which, int n, RT_OUT(int4) out)
{
    int i = rt_global_id(0);
    if (i >= n)
        return;
    int2 node;
    int4 v = i4(0, 0, 0, 0);
    switch (which) {
    case 0: node = load_node(nodes, i); v = i4(node.x, node.y, 0, 0); break;
    case 1: v = float4_bits(load_node_data(node_data, i)); break;
    case 2: v.x = load_object(objects, i); break;
    case 3: v = float4_bits(load_tri_vertex(tris, i / 3, i % 3)); break;
    case 4: v = float4_bits(load_tri_data(tri_data, i)); break;
    case 5: v = float4_bits(load_tri_normal(normals, i / 3, i % 3)); break;
    default: v.x = load_tri_material(tri_materials, i); break;
    }
    out[i] = v;
}

#endif /* RT_ENTRY_FETCH_H */
