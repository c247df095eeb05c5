/* rt_shade.h - simple shading: the paper's Table 4 setting (primary rays, Lambert, no shadows).
 * The float64 reference (rtlab/reference/shading.py) implements the same formula. */
#ifndef RT_SHADE_H
#define RT_SHADE_H
#include "rt_memory.h"
#include "rt_types.h"

/* Surface normal at a hit: interpolated vertex normals or the flat geometric normal, turned to
 * face the incoming ray. */
RT_FN float3 hit_normal(RT_SCENE_PARAMS, const Ray *ray, const Hit *hit)
{
#if RT_SMOOTH_NORMALS
    float w = 1.0f - hit->u - hit->v;
    float3 n = mul3(xyz(load_tri_normal(hit->tri, 0)), w);
    n = madd3(n, xyz(load_tri_normal(hit->tri, 1)), hit->u);
    n = madd3(n, xyz(load_tri_normal(hit->tri, 2)), hit->v);
#else
    float3 v0 = xyz(load_tri_vertex(hit->tri, 0));
    float3 n = cross3(sub3(xyz(load_tri_vertex(hit->tri, 1)), v0),
                      sub3(xyz(load_tri_vertex(hit->tri, 2)), v0));
#endif
    n = normalize3(n);
    return dot3(n, ray->d) > 0.0f ? mul3(n, -1.0f) : n;
}

/* Lambert from point lights plus a constant ambient term, no shadows:
 * c = kd * (ambient + sum_l max(0, n.l) * light_l). */
RT_FN float3 shade_lambert(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                           RT_CONST const RtMaterial *materials, const Ray *ray, const Hit *hit)
{
    if (hit->tri < 0)
        return xyz(frame->background);
    float3 p = madd3(ray->o, ray->d, hit->t);
    float3 n = hit_normal(RT_SCENE_ARGS, ray, hit);
    float3 kd = xyz(materials[load_tri_material(hit->tri)].diffuse);
    float ambient = frame->background.w;
    float3 c = mul3(kd, ambient);
    for (int i = 0; i < frame->n_lights; ++i) {
        float3 l = normalize3(sub3(xyz(lights[i].position), p));
        float lambert = rt_max(dot3(n, l), 0.0f);
        c = add3(c, mul3(hadamard3(kd, xyz(lights[i].color)), lambert));
    }
    return c;
}

/* Pack a linear colour clamped to [0, 1] into RGBA8 (alpha 255), rounding to nearest. */
RT_FN unsigned int pack_rgba8(float3 c)
{
    unsigned int r = (unsigned int)(rt_min(rt_max(c.x, 0.0f), 1.0f) * 255.0f + 0.5f);
    unsigned int g = (unsigned int)(rt_min(rt_max(c.y, 0.0f), 1.0f) * 255.0f + 0.5f);
    unsigned int b = (unsigned int)(rt_min(rt_max(c.z, 0.0f), 1.0f) * 255.0f + 0.5f);
    return r | (g << 8) | (b << 16) | (255u << 24);
}

#endif /* RT_SHADE_H */
