/* rt_packet.h - packet kd traversal (the paper's §3.1.2 "packet" column of Table 4): all rays of
 * a block / work-group walk the tree together with ONE stack in shared (CUDA) / local (OpenCL)
 * memory, as in Guenther et al. 2007's shared-stack packets, here on the kd-tree.
 *
 * Each step all threads look at the same node. A ray whose segment needs the node votes for the
 * children it needs and for its nearer child; between two barriers thread 0 takes the child most
 * rays meet first, pushes the other when some ray needs it, or pops. The stack holds a node and
 * its cell box (shared by all rays): on a pop every ray clips itself to the popped cell, so no
 * ray needs a stack of its own. Rays that do not need a node just skip it (and cast no vote); at
 * a leaf each ray that needs it tests the leaf's triangles against its own ray.
 * Every thread of the block must call the traversal (invalid ones with valid = 0): it contains
 * barriers. The paper found the packet slow on CUDA (15.8 vs 43.2 fps): two barriers per node.
 *
 * Entry kernels declare the KdPacketShared at kernel scope (rt_entry_trace.h, rt_entry_ray_grid.h):
 * OpenCL allows __local variables only there. Pointers to it are
 * RT_SHARED_PTR; barriers and the votes' atomics are rt_port.h's rt_barrier, rt_shared_atomic_add.
 */
#ifndef RT_PACKET_H
#define RT_PACKET_H
#include "rt_kdtree.h"
#include "rt_shade.h"

/* The packet's shared state (about 36 B per stack entry + 64 B) */
typedef struct {
    float4 box_min, box_max;               /* cell of the current node */
    float4 stack_min[RT_STACK_SIZE];       /* cells of the pending nodes */
    float4 stack_max[RT_STACK_SIZE];
    int stack_node[RT_STACK_SIZE];
    int node;                              /* current node; -1 when the packet is done */
    int sp;
    int descended;                         /* 1: node is a child of the last one; 0: popped */
    int votes[4];                          /* rays needing the lower / upper child; rays whose
                                              nearer child is the lower / upper one */
} KdPacketShared;

RT_FN float4 set4(float4 a, int axis, float value)
{
    if (axis == 0)
        a.x = value;
    else if (axis == 1)
        a.y = value;
    else
        a.z = value;
    return a;
}

/* Thread 0, between the barriers: descend to the child most needing rays meet first (pushing the
 * other when it is needed too), or pop when no ray needs a child of node n (or n is a leaf). */
RT_FN void step_kd_packet(int2 n, RT_SHARED_PTR KdPacketShared *sh)
{
    int need_lower = sh->votes[0] > 0, need_upper = sh->votes[1] > 0;
    int lower_first = sh->votes[2] >= sh->votes[3];
    for (int k = 0; k < 4; ++k)
        sh->votes[k] = 0;
    if (!kd_is_leaf(n) && (need_lower || need_upper)) {
        int axis = n.x & 3, lower = n.x >> 2;
        float split = rt_as_float(n.y);
        float4 lo = sh->box_min, hi = sh->box_max;
        float4 lower_max = set4(hi, axis, split), upper_min = set4(lo, axis, split);
        int go_lower = need_lower && (!need_upper || lower_first);
        if (need_lower && need_upper) {
            int sp = sh->sp;
            sh->stack_node[sp] = go_lower ? lower + 1 : lower;
            sh->stack_min[sp] = go_lower ? upper_min : lo;
            sh->stack_max[sp] = go_lower ? hi : lower_max;
            sh->sp = sp + 1;
        }
        sh->node = go_lower ? lower : lower + 1;
        sh->box_min = go_lower ? lo : upper_min;
        sh->box_max = go_lower ? lower_max : hi;
        sh->descended = 1;
    } else if (sh->sp > 0) {
        int sp = sh->sp - 1;
        sh->node = sh->stack_node[sp];
        sh->box_min = sh->stack_min[sp];
        sh->box_max = sh->stack_max[sp];
        sh->sp = sp;
        sh->descended = 0;
    } else {
        sh->node = -1;
        sh->descended = 0;
    }
}

/* Packet traversal for the calling thread's ray; lane = the thread's index in its block (thread 0
 * keeps the shared state). Closest hit, or with any_hit the first hit found. The stack needs at
 * most the tree depth entries: RT_STACK_SIZE is depth + 1. */
RT_FN void traverse_kd_packet(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray,
                              int valid, Hit *hit, int any_hit, RT_SHARED_PTR KdPacketShared *sh,
                              int lane)
{
    /* BEGIN SOLUTION */
    float tmin = 0.0f, tmax = 0.0f;
    int live = valid && clip_ray_box(ray, scene_min, scene_max, &tmin, &tmax);
    /* Wait for every thread to be done with an earlier traversal's shared state */
    rt_barrier();
    if (lane == 0) {
        sh->node = 0;
        sh->sp = 0;
        sh->box_min = scene_min;
        sh->box_max = scene_max;
        for (int k = 0; k < 4; ++k)
            sh->votes[k] = 0;
    }
    rt_barrier();
    for (;;) {
        int node = sh->node;
        if (node < 0)
            break;
        int2 n = load_node(nodes, node);
        int first = -1, second = -1, visit = 0;
        float t_split = 0.0f;
        live = live && tmin <= t_cull(hit->t) && !(any_hit && hit->tri >= 0);
        /* Work on this node where the ray's segment needs it: test a leaf, or vote */
        if (live && kd_is_leaf(n)) {
            intersect_leaf(RT_SCENE_ARGS, n, ray, hit, any_hit);
        } else if (live) {
            int lower = n.x >> 2;
            visit = kd_children(n, ray, tmin, tmax, &first, &second, &t_split);
            rt_shared_atomic_add(&sh->votes[first - lower], 1);
            if (visit >= 2)
                rt_shared_atomic_add(&sh->votes[second - lower], 1);
            rt_shared_atomic_add(&sh->votes[2 + first - lower], 1);
        }
        rt_barrier();
        if (lane == 0)
            step_kd_packet(n, sh);
        rt_barrier();
        /* Follow the packet: the child's part of the segment, or the popped cell's */
        if (sh->descended) {
            int child = sh->node;
            if (live && child == first && visit == 2)
                tmax = t_split;
            else if (live && child == second && visit == 2)
                tmin = t_split;
            else if (!(live && (child == first || (child == second && visit == 3))))
                live = 0;
        } else if (sh->node >= 0) {
            live = valid && clip_ray_box(ray, sh->box_min, sh->box_max, &tmin, &tmax);
        }
    }
    /* END SOLUTION */
}

/* Closest hit of one ray of a packet (trace_rays, trace_ray_grid). origin.w = tmin, direction.w = tmax */
RT_FN Hit trace_one_packet(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, float4 origin, float4 direction,
                           int valid, RT_SHARED_PTR KdPacketShared *sh, int lane)
{
    Ray ray = make_ray(xyz(origin), xyz(direction), origin.w, direction.w);
    Hit hit = make_miss(ray.tmax);
    traverse_kd_packet(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, &ray, valid, &hit, 0, sh, lane);
    refine_hit_t(RT_SCENE_ARGS, &ray, &hit);
    return hit;
}

/* Shaded colour of pixel (x, y) traced as part of its block's packet; its hit record in *hit */
RT_FN unsigned int render_pixel_packet(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame,
                                       RT_CONST const RtLight *lights, RT_CONST const RtMaterial *materials,
                                       int x, int y, int valid, RT_SHARED_PTR KdPacketShared *sh, int lane,
                                       Hit *hit)
{
    Ray ray = camera_ray(frame, x, y);
    *hit = make_miss(ray.tmax);
    traverse_kd_packet(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, &ray, valid, hit, 0, sh, lane);
    refine_hit_t(RT_SCENE_ARGS, &ray, hit);
    return pack_rgba8(shade_lambert(RT_SCENE_ARGS, frame, lights, materials, &ray, hit));
}

#endif /* RT_PACKET_H */
