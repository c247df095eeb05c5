/* rt_kd_shortstack.h - short-stack kd traversal (Horn, Sugerman, Houston & Hanrahan 2007; the
 * paper's §3.1.2, Table 4): a stack of RT_SHORT_STACK_SIZE entries kept as a ring, so a push onto
 * a full stack drops the oldest (farthest) entry; popping an empty stack falls back to kd-restart
 * from the root with tmin = the current cell's exit. Dropped entries are therefore never lost:
 * the restart walks every cell behind the current one in order. An entry keeps its cell's
 * KdSegment, so a restart after a leaf reached from a popped entry continues the tie order of
 * rt_kd_restart.h exactly. Rays lying in split planes take the side passes of rt_kd_restart.h (no
 * stack entry for them), so the stack only ever holds far cells in front-to-back order. */
#ifndef RT_KD_SHORTSTACK_H
#define RT_KD_SHORTSTACK_H
#include "rt_kd_restart.h"

#ifndef RT_SHORT_STACK_SIZE        /* entries; the loader passes Variant.short_stack */
#define RT_SHORT_STACK_SIZE 4
#endif

typedef struct {
    int node;
    KdSegment seg;
} KdShortStackEntry;

/* Short-stack traversal. Closest hit, or with any_hit the first hit found. */
RT_FN void traverse_kd_shortstack(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray,
                                  Hit *hit, int any_hit)
{
    /* BEGIN SOLUTION */
    float t_enter, t_exit;
    if (!clip_ray_box(ray, scene_min, scene_max, &t_enter, &t_exit))
        return;
    KdShortStackEntry stack[RT_SHORT_STACK_SIZE];
    int planes = 0;
    for (int side = 0; side < 8; ++side) {
        if (!kd_pass_needed(side, planes))
            continue;
        int top = 0, count = 0;          /* ring: stack[top] is the newest of count entries */
        int node = 0;
        KdSegment seg = kd_segment(t_enter, t_exit);
        while (seg.tmin <= t_cull(hit->t)) {
            int2 n = load_node(nodes, node);
            /* Descend, pushing far cells; a full ring forgets its oldest entry */
            while (!kd_is_leaf(n)) {
                int far;
                KdSegment far_seg;
                node = kd_child_restart(n, ray, &seg, side, &planes, &far, &far_seg);
                if (far >= 0) {
                    top = (top + 1) % RT_SHORT_STACK_SIZE;
                    stack[top].node = far;
                    stack[top].seg = far_seg;
                    count += count < RT_SHORT_STACK_SIZE;
                }
                n = load_node(nodes, node);
            }
            intersect_leaf(RT_SCENE_ARGS, n, ray, hit, any_hit);
            if (any_hit && hit->tri >= 0)
                return;
            if (t_cull(hit->t) < seg.tmax)
                break;
            if (count > 0) {
                node = stack[top].node;
                seg = stack[top].seg;
                top = (top + RT_SHORT_STACK_SIZE - 1) % RT_SHORT_STACK_SIZE;
                --count;
            } else {
                /* Underflow: restart from the root behind the current cell (kd-restart) */
                if (!kd_next_restart(&seg, t_exit))
                    break;
                node = 0;
            }
        }
    }
    /* END SOLUTION */
}

#endif /* RT_KD_SHORTSTACK_H */
