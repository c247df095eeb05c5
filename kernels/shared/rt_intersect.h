/* rt_intersect.h - ray/triangle tests (§3.1.2, Table 3) and the ray/box clip.
 * Each test updates *hit only for a hit nearer than hit->t and beyond ray->tmin, and says whether it did. */
#ifndef RT_INTERSECT_H
#define RT_INTERSECT_H
#include "rt_memory.h"
#include "rt_types.h"

/* Moller & Trumbore, "Fast, minimum storage ray/triangle intersection", JGT 1997.
 * No epsilon on the determinant (det == 0 only rejects parallel rays and zero-area triangles):
 * an epsilon there drops grazing hits. Edges are inclusive, so a ray through a shared edge hits. */
RT_FN int intersect_ray_tri_moller(const Ray *ray, float3 v0, float3 v1, float3 v2, int tri, Hit *hit)
{
    float3 e1 = sub3(v1, v0);
    float3 e2 = sub3(v2, v0);
    float3 p = cross3(ray->d, e2);
    float det = dot3(e1, p);
    if (det == 0.0f)
        return 0;
    float inv_det = 1.0f / det;
    float3 s = sub3(ray->o, v0);
    float u = dot3(s, p) * inv_det;
    if (u < 0.0f || u > 1.0f)
        return 0;
    float3 q = cross3(s, e1);
    float v = dot3(ray->d, q) * inv_det;
    if (v < 0.0f || u + v > 1.0f)
        return 0;
    float t = dot3(e2, q) * inv_det;
    /* Written so that a NaN t fails the test */
    if (!(t > ray->tmin && t < hit->t))
        return 0;
    hit->t = t;
    hit->u = u;
    hit->v = v;
    hit->tri = tri;
    return 1;
}

/* The test chosen by RT_ISECT, on triangle tri of the scene (the paper's Table 3 variable). */
RT_FN int intersect_tri(RT_SCENE_PARAMS, const Ray *ray, int tri, Hit *hit)
{
    float3 v0 = xyz(load_tri_vertex(tri, 0));
    float3 v1 = xyz(load_tri_vertex(tri, 1));
    float3 v2 = xyz(load_tri_vertex(tri, 2));
    return intersect_ray_tri_moller(ray, v0, v1, v2, tri, hit);
}

/* Clip the ray to an axis-aligned box: slab test (Kay & Kajiya). A zero direction component gives
 * +-inf slab distances; fmin/fmax drop the NaN of 0 * inf (origin exactly on a slab plane), which
 * keeps such rays instead of losing them. Rays with NaN/Inf origin or direction, or a zero
 * direction, never enter. */
RT_FN int clip_ray_box(const Ray *ray, float4 bmin, float4 bmax, float *t_enter, float *t_exit)
{
    if (!(finite3(ray->o) && finite3(ray->d) && dot3(ray->d, ray->d) > 0.0f))
        return 0;
    float t0 = ray->tmin, t1 = ray->tmax;
    float a0 = (bmin.x - ray->o.x) * ray->inv_d.x, a1 = (bmax.x - ray->o.x) * ray->inv_d.x;
    t0 = rt_max(t0, rt_min(a0, a1));
    t1 = rt_min(t1, rt_max(a0, a1));
    a0 = (bmin.y - ray->o.y) * ray->inv_d.y;
    a1 = (bmax.y - ray->o.y) * ray->inv_d.y;
    t0 = rt_max(t0, rt_min(a0, a1));
    t1 = rt_min(t1, rt_max(a0, a1));
    a0 = (bmin.z - ray->o.z) * ray->inv_d.z;
    a1 = (bmax.z - ray->o.z) * ray->inv_d.z;
    t0 = rt_max(t0, rt_min(a0, a1));
    t1 = rt_min(t1, rt_max(a0, a1));
    *t_enter = t0;
    *t_exit = t1;
    return t0 <= t1;
}

#endif /* RT_INTERSECT_H */
