/* rt_memory.h - where the scene's buffers live (§3.1.1) and how device code reads them.
 *
 * Traversal and intersection code takes RT_SCENE_PARAMS (first, in every function that reads the
 * scene) and reads the buffers only through the loaders at the end of this file, each given its
 * buffer as Warp's bvh_load_node(nodes, i) is: load_node(nodes, i), load_tri_vertex(tris, tri, k)...
 * So it reads the same for every memory placement. This file is the one place that differs by
 * placement (RT_NODE_MEM); with rt_port.h and rt_lanes.h it is the port layer (rt_port.h).
 *   nodes      int2   kd-tree nodes (rtlab/accel/kdtree.py gives the encoding)
 *   node_data  float4 per-variant node data: ropes and leaf boxes (kd ropes), BVH nodes (bvh);
 *                     a dummy element otherwise
 *   objects    int    triangle indices of the leaves (the paper's object list)
 *   tris       float4 three vertices per triangle (w unused)
 *   tri_data   float4 per-triangle data precomputed for the intersection test (Wald, Plucker);
 *                     a dummy element for tests that need none (Moller-Trumbore)
 *   normals    float4 three vertex normals per triangle (only read when RT_SMOOTH_NORMALS)
 *   tri_materials int material id per triangle
 * rtlab/device/device_scene.py uploads them in this order.
 *
 * RT_NODE_MEM == RT_MEM_TEXTURE reads all seven through the texture path instead, as the paper does
 * for the node, object, vertex and normal lists (§3.1.1): CUDA texture objects (tex1Dfetch) and
 * OpenCL image1d_buffer images over the same buffers (rtlab.backends Backend.texture). PoCL has no
 * two-channel (RG) image format, so the OpenCL node image holds two int2 nodes per RGBA texel.
 * Lab step 01 (kernels/cuda/01_memory.cu, kernels/opencl/01_memory.cl) asks for the fetch functions
 * below in both languages.
 */
#ifndef RT_MEMORY_H
#define RT_MEMORY_H
#include "rt_port.h"

#if defined(__CUDACC__) && RT_NODE_MEM == RT_MEM_TEXTURE
/* Texture objects: each fetch goes through the texture cache (the 2008 path the paper measured). */
#define RT_SCENE_PARAMS                                                                         \
    cudaTextureObject_t nodes, cudaTextureObject_t node_data, cudaTextureObject_t objects,      \
        cudaTextureObject_t tris, cudaTextureObject_t tri_data, cudaTextureObject_t normals,    \
        cudaTextureObject_t tri_materials

/* Element i of a two-channel int32 texture (the kd-tree's int2 nodes). */
RT_FN int2 fetch_int2_texture(cudaTextureObject_t tex, int i)
{
    /* BEGIN SOLUTION */
    /* STUB: return make_int2(3, 0); */
    return tex1Dfetch<int2>(tex, i);
    /* END SOLUTION */
}

/* Element i of a four-channel float texture (vertices, normals, per-variant data). */
RT_FN float4 fetch_float4_texture(cudaTextureObject_t tex, int i)
{
    /* BEGIN SOLUTION */
    return tex1Dfetch<float4>(tex, i);
    /* END SOLUTION */
}

/* Element i of a one-channel int32 texture (object list, material ids). */
RT_FN int fetch_int_texture(cudaTextureObject_t tex, int i)
{
    /* BEGIN SOLUTION */
    return tex1Dfetch<int>(tex, i);
    /* END SOLUTION */
}

#define load_node(nodes, i) fetch_int2_texture((nodes), (i))
#define load_node_data(node_data, i) fetch_float4_texture((node_data), (i))
#define load_tri_data(tri_data, i) fetch_float4_texture((tri_data), (i))
#define load_object(objects, i) fetch_int_texture((objects), (i))
#define load_tri_vertex(tris, tri, k) fetch_float4_texture((tris), 3 * (tri) + (k))
#define load_tri_normal(normals, tri, k) fetch_float4_texture((normals), 3 * (tri) + (k))
#define load_tri_material(tri_materials, tri) fetch_int_texture((tri_materials), (tri))
#elif RT_NODE_MEM == RT_MEM_TEXTURE
/* Images over the buffers (image1d_buffer_t; NVIDIA's OpenCL and PoCL both have them). */
#define RT_SCENE_PARAMS                                                                         \
    read_only image1d_buffer_t nodes, read_only image1d_buffer_t node_data,                     \
        read_only image1d_buffer_t objects, read_only image1d_buffer_t tris,                    \
        read_only image1d_buffer_t tri_data, read_only image1d_buffer_t normals,                \
        read_only image1d_buffer_t tri_materials

/* int2 element i of an RGBA int32 image that packs two elements a texel (PoCL lacks RG images). */
RT_FN int2 fetch_int2_image(read_only image1d_buffer_t img, int i)
{
    /* BEGIN SOLUTION */
    /* STUB: return (int2)(3, 0); */
    int4 pair = read_imagei(img, i >> 1);
    return (i & 1) ? pair.zw : pair.xy;
    /* END SOLUTION */
}

/* Element i of an RGBA float image. */
RT_FN float4 fetch_float4_image(read_only image1d_buffer_t img, int i)
{
    /* BEGIN SOLUTION */
    return read_imagef(img, i);
    /* END SOLUTION */
}

/* Element i of a one-channel (R) int32 image. */
RT_FN int fetch_int_image(read_only image1d_buffer_t img, int i)
{
    /* BEGIN SOLUTION */
    return read_imagei(img, i).x;
    /* END SOLUTION */
}

#define load_node(nodes, i) fetch_int2_image((nodes), (i))
#define load_node_data(node_data, i) fetch_float4_image((node_data), (i))
#define load_tri_data(tri_data, i) fetch_float4_image((tri_data), (i))
#define load_object(objects, i) fetch_int_image((objects), (i))
#define load_tri_vertex(tris, tri, k) fetch_float4_image((tris), 3 * (tri) + (k))
#define load_tri_normal(normals, tri, k) fetch_float4_image((normals), 3 * (tri) + (k))
#define load_tri_material(tri_materials, tri) fetch_int_image((tri_materials), (tri))
#elif defined(__CUDACC__)
/* Read-only data path: const __restrict__ plus __ldg (the non-texture read-only cache). */
#define RT_SCENE_PARAMS                                                                         \
    const int2 *__restrict__ nodes, const float4 *__restrict__ node_data,                       \
        const int *__restrict__ objects, const float4 *__restrict__ tris,                       \
        const float4 *__restrict__ tri_data, const float4 *__restrict__ normals,                \
        const int *__restrict__ tri_materials
#define load_node(nodes, i) __ldg(&(nodes)[(i)])
#define load_node_data(node_data, i) __ldg(&(node_data)[(i)])
#define load_tri_data(tri_data, i) __ldg(&(tri_data)[(i)])
#define load_object(objects, i) __ldg(&(objects)[(i)])
#define load_tri_vertex(tris, tri, k) __ldg(&(tris)[3 * (tri) + (k)])
#define load_tri_normal(normals, tri, k) __ldg(&(normals)[3 * (tri) + (k)])
#define load_tri_material(tri_materials, tri) __ldg(&(tri_materials)[(tri)])
#else
#define RT_SCENE_PARAMS                                                                         \
    __global const int2 *restrict nodes, __global const float4 *restrict node_data,             \
        __global const int *restrict objects, __global const float4 *restrict tris,             \
        __global const float4 *restrict tri_data, __global const float4 *restrict normals,      \
        __global const int *restrict tri_materials
#define load_node(nodes, i) (nodes)[(i)]
#define load_node_data(node_data, i) (node_data)[(i)]
#define load_tri_data(tri_data, i) (tri_data)[(i)]
#define load_object(objects, i) (objects)[(i)]
#define load_tri_vertex(tris, tri, k) (tris)[3 * (tri) + (k)]
#define load_tri_normal(normals, tri, k) (normals)[3 * (tri) + (k)]
#define load_tri_material(tri_materials, tri) (tri_materials)[(tri)]
#endif

/* A vertex of a triangle already hit (the refined t, the shading): read as any vertex, but not the
 * walk's work, so the counting build below does not count it */
#define load_hit_vertex(tris, tri, k) load_tri_vertex(tris, tri, k)

/* Word i of node_data, four a float4 row (a child ref of rt_bvh4.h's refs row, read alone): one
 * 4-byte read from a buffer; from a texture, its row's component. */
#if RT_NODE_MEM == RT_MEM_TEXTURE
#define load_node_word(node_data, i) rt_as_int(get4(load_node_data(node_data, (i) >> 2), (i) & 3))
#elif defined(__CUDACC__)
#define load_node_word(node_data, i) __ldg((const int *)(node_data) + (i))
#else
#define load_node_word(node_data, i) (((RT_GLOBAL const int *)(node_data))[(i)])
#endif

#ifndef RT_COUNT_WORK
#define RT_COUNT_WORK 0
#endif
#if RT_COUNT_WORK
/* Counted loads: the grader's work budget. Every loader also counts into rt_work, a buffer after
 * the seven scene buffers with two counters a work-item (no atomics: each item its own): the
 * tree's reads (nodes, node data, object list) and the triangles' (vertices, per-triangle data).
 * A traversal that walks the whole tree reads many times what the reference reads on the same
 * rays (rtlab.course.checks). The buffers take opaque types here, so a plain read past the loaders
 * does not compile (a cast does: the grader also holds a launch to a triangle read a hit, and refuses
 * these names in submitted files). The hit triangle's own vertices, read again after the walk
 * (load_hit_vertex), are not counted. Global placement only. */
#if RT_NODE_MEM != RT_MEM_GLOBAL
#error "RT_COUNT_WORK needs the global placement (RT_NODE_MEM == RT_MEM_GLOBAL)"
#endif
struct RtNodeList;
struct RtFloat4List;
struct RtIntList;
#undef RT_SCENE_PARAMS
#undef load_node
#undef load_node_data
#undef load_tri_data
#undef load_object
#undef load_tri_vertex
#undef load_tri_normal
#undef load_tri_material
#undef load_node_word
#define RT_SCENE_PARAMS                                                                         \
    RT_GLOBAL const struct RtNodeList *nodes, RT_GLOBAL const struct RtFloat4List *node_data,   \
        RT_GLOBAL const struct RtIntList *objects, RT_GLOBAL const struct RtFloat4List *tris,    \
        RT_GLOBAL const struct RtFloat4List *tri_data, RT_GLOBAL const struct RtFloat4List *normals, \
        RT_GLOBAL const struct RtIntList *tri_materials, RT_GLOBAL unsigned int *rt_work
/* rt_work[0]: the slots it has room for; a work-item past them counts in the last (totals stay right) */
#define rt_counted(k, list, type, i)                                                            \
    (rt_work[2 + 2 * rt_imin((int)rt_item_index(), (int)rt_work[0] - 1) + (k)] += 1u,            \
     ((RT_GLOBAL const type *)(list))[(i)])
#define load_node(nodes, i) rt_counted(0, nodes, int2, i)
#define load_node_data(node_data, i) rt_counted(0, node_data, float4, i)
#define load_node_word(node_data, i) rt_counted(0, node_data, int, i)
#define load_object(objects, i) rt_counted(0, objects, int, i)
#define load_tri_data(tri_data, i) rt_counted(1, tri_data, float4, i)
#define load_tri_vertex(tris, tri, k) rt_counted(1, tris, float4, 3 * (tri) + (k))
#define load_tri_normal(normals, tri, k) (((RT_GLOBAL const float4 *)(normals))[3 * (tri) + (k)])
#undef load_hit_vertex
#define load_hit_vertex(tris, tri, k) (((RT_GLOBAL const float4 *)(tris))[3 * (tri) + (k)])
#define load_tri_material(tri_materials, tri) (((RT_GLOBAL const int *)(tri_materials))[(tri)])
/* RT_SCENE_PARAMS' names, to pass them on */
#define RT_SCENE_ARGS nodes, node_data, objects, tris, tri_data, normals, tri_materials, rt_work
#else
/* RT_SCENE_PARAMS' names, to pass them on */
#define RT_SCENE_ARGS nodes, node_data, objects, tris, tri_data, normals, tri_materials
#endif

#endif /* RT_MEMORY_H */
