/* rt_traverse.h - the traversal chosen by RT_TRAVERSAL (the paper's Table 4 variable), behind two
 * names, so ray-generation and shading code reads the same for every variant:
 *   trace_closest  closest hit (primary, reflection and refraction rays)
 *   trace_any      any hit within (tmin, tmax): occlusion (shadow rays, §3.2.1)
 * The packet traversal needs the block-wide shared stack that only the entry kernels of closest hits
 * and primary rays declare (rt_entry_trace.h, rt_entry_ray_grid.h: they call traverse_kd_packet
 * themselves); any other kernel built for it (shadows, secondary rays) is a compile error rather than
 * a silent fallback to another traversal. */
#ifndef RT_TRAVERSE_H
#define RT_TRAVERSE_H
#include "rt_kdtree.h"

#if RT_TRAVERSAL == RT_TRAVERSAL_STACK
#define RT_TRAVERSE_RAY traverse_kd_stack
#elif RT_TRAVERSAL == RT_TRAVERSAL_RESTART
#include "rt_kd_restart.h"
#define RT_TRAVERSE_RAY traverse_kd_restart
#elif RT_TRAVERSAL == RT_TRAVERSAL_SHORTSTACK
#include "rt_kd_shortstack.h"
#define RT_TRAVERSE_RAY traverse_kd_shortstack
#elif RT_TRAVERSAL == RT_TRAVERSAL_ROPES
#include "rt_kd_ropes.h"
#define RT_TRAVERSE_RAY traverse_kd_ropes
#elif RT_TRAVERSAL == RT_TRAVERSAL_BVH
#include "rt_bvh.h"
#define RT_TRAVERSE_RAY traverse_bvh
#elif RT_TRAVERSAL == RT_TRAVERSAL_BVH8
#include "rt_bvh8.h"
#define RT_TRAVERSE_RAY traverse_bvh8
#elif RT_TRAVERSAL == RT_TRAVERSAL_BVH4
#include "rt_bvh4.h"
#define RT_TRAVERSE_RAY traverse_bvh4
#elif RT_TRAVERSAL == RT_TRAVERSAL_BVH_PACKET
/* trace_rays and render_primary take RT_LANES rays a work-item (rt_primary.h); single rays (shadows,
 * reflections) go through the wide traversal of the same tree */
#include "rt_bvh_packet.h"
#define RT_TRAVERSE_RAY traverse_bvh_wide
#elif RT_TRAVERSAL == RT_TRAVERSAL_BVH_WIDE
#include "rt_bvh_wide.h"
#define RT_TRAVERSE_RAY traverse_bvh_wide
#elif RT_TRAVERSAL == RT_TRAVERSAL_PACKET
#ifndef RT_PACKET_KERNELS
#error "the packet traversal needs its block-wide shared stack, which only trace_rays, trace_ray_grid and render_primary declare"
#endif
#include "rt_packet.h"
/* the packet kernels call traverse_kd_packet; the single-ray names stay defined, unused */
#define RT_TRAVERSE_RAY traverse_kd_stack
#else
#error "unknown RT_TRAVERSAL (codes atop rt_port.h)"
#endif

/* Closest hit of the ray within the scene box; *hit starts as a miss at ray->tmax. */
RT_FN void trace_closest(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray, Hit *hit)
{
    RT_TRAVERSE_RAY(RT_SCENE_ARGS, scene_min, scene_max, ray, hit, 0);
}

/* Whether anything blocks the ray within (ray->tmin, ray->tmax). */
RT_FN int trace_any(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray)
{
    Hit hit = make_miss(ray->tmax);
    RT_TRAVERSE_RAY(RT_SCENE_ARGS, scene_min, scene_max, ray, &hit, 1);
    return hit.tri >= 0;
}

#endif /* RT_TRAVERSE_H */
