/* rt_memory.h - where the scene's buffers live (§3.1.1) and how device code reads them.
 *
 * Traversal and intersection code reads only through these macros and takes RT_SCENE_PARAMS, so it
 * reads the same for every memory placement. This file is the one place that differs by language
 * and by placement (RT_NODE_MEM).
 *   nodes      int2   kd-tree nodes (rtlab/accel/kdtree.py gives the encoding)
 *   node_data  float4 per-variant node data: ropes and leaf boxes (kd ropes), BVH nodes (bvh);
 *                     a dummy element otherwise
 *   objects    int    triangle indices of the leaves (the paper's object list)
 *   tris       float4 three vertices per triangle (w unused)
 *   tri_data   float4 per-triangle data precomputed for the intersection test (Wald, Plucker);
 *                     a dummy element for tests that need none (Moller-Trumbore)
 *   normals    float4 three vertex normals per triangle (only read when RT_SMOOTH_NORMALS)
 *   tri_materials int material id per triangle
 * rtlab/device_scene.py uploads them in this order.
 */
#ifndef RT_MEMORY_H
#define RT_MEMORY_H
#include "rt_port.h"

#if defined(__CUDACC__)
/* Read-only data path: const __restrict__ plus __ldg (the non-texture read-only cache). */
#define RT_SCENE_PARAMS                                                                         \
    const int2 *__restrict__ nodes, const float4 *__restrict__ node_data,                       \
        const int *__restrict__ objects, const float4 *__restrict__ tris,                       \
        const float4 *__restrict__ tri_data, const float4 *__restrict__ normals,                \
        const int *__restrict__ tri_materials
#define load_node(i) __ldg(&nodes[(i)])
#define load_node_data(i) __ldg(&node_data[(i)])
#define load_tri_data(i) __ldg(&tri_data[(i)])
#define load_object(i) __ldg(&objects[(i)])
#define load_tri_vertex(tri, k) __ldg(&tris[3 * (tri) + (k)])
#define load_tri_normal(tri, k) __ldg(&normals[3 * (tri) + (k)])
#define load_tri_material(tri) __ldg(&tri_materials[(tri)])
#else
#define RT_SCENE_PARAMS                                                                         \
    __global const int2 *restrict nodes, __global const float4 *restrict node_data,             \
        __global const int *restrict objects, __global const float4 *restrict tris,             \
        __global const float4 *restrict tri_data, __global const float4 *restrict normals,      \
        __global const int *restrict tri_materials
#define load_node(i) nodes[(i)]
#define load_node_data(i) node_data[(i)]
#define load_tri_data(i) tri_data[(i)]
#define load_object(i) objects[(i)]
#define load_tri_vertex(tri, k) tris[3 * (tri) + (k)]
#define load_tri_normal(tri, k) normals[3 * (tri) + (k)]
#define load_tri_material(tri) tri_materials[(tri)]
#endif

#define RT_SCENE_ARGS nodes, node_data, objects, tris, tri_data, normals, tri_materials

#endif /* RT_MEMORY_H */
