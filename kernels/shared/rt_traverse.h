/* rt_traverse.h - the traversal chosen by RT_TRAVERSAL (the paper's Table 4 variable), behind one
 * name, so ray-generation and shading code reads the same for every variant. */
#ifndef RT_TRAVERSE_H
#define RT_TRAVERSE_H
#include "rt_kdtree.h"

/* Closest hit of the ray within the scene box; *hit starts as a miss at ray->tmax. */
RT_FN void trace_closest(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray, Hit *hit)
{
    traverse_kd_stack(RT_SCENE_ARGS, scene_min, scene_max, ray, hit);
}

#endif /* RT_TRAVERSE_H */
