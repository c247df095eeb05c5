/* rt_traverse.h - the traversal chosen by RT_TRAVERSAL (the paper's Table 4 variable), behind two
 * names, so ray-generation and shading code reads the same for every variant:
 *   trace_closest  closest hit (primary, reflection and refraction rays)
 *   trace_any      any hit within (tmin, tmax): occlusion (shadow rays, §3.2.1) */
#ifndef RT_TRAVERSE_H
#define RT_TRAVERSE_H
#include "rt_kdtree.h"

/* Closest hit of the ray within the scene box; *hit starts as a miss at ray->tmax. */
RT_FN void trace_closest(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray, Hit *hit)
{
    traverse_kd_stack(RT_SCENE_ARGS, scene_min, scene_max, ray, hit, 0);
}

/* Whether anything blocks the ray within (ray->tmin, ray->tmax). */
RT_FN int trace_any(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray)
{
    Hit hit = make_miss(ray->tmax);
    traverse_kd_stack(RT_SCENE_ARGS, scene_min, scene_max, ray, &hit, 1);
    return hit.tri >= 0;
}

#endif /* RT_TRAVERSE_H */
