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
    /* TODO (lab 03_traversal): write traverse_kd_shortstack here; labs/03_traversal/README.md says what it must do. */
    return;
    /* END SOLUTION */
}

#endif /* RT_KD_SHORTSTACK_H */
