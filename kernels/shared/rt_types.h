/* rt_types.h - structs shared by host and device. Every struct that crosses to the host uses float4
 * and 4-byte scalars only and is mirrored by a numpy dtype in rtlab/device/layout.py ("sync with
 * layout.py"); tests/test_kernel_sources.py checks the sizes on the device (sizeof in a kernel). */
#ifndef RT_TYPES_H
#define RT_TYPES_H
#include "rt_port.h"

/* Per-frame constants (constant memory, §3.1.1): camera basis, scene box, shading constants.
 * A pixel (x, y), y down, looks along normalize(w + (2(x+.5)/W - 1) u + (1 - 2(y+.5)/H) v). */
typedef struct {
    float4 eye, u, v, w;           /* camera (see rtlab.scene.model.Camera.basis) */
    float4 scene_min, scene_max;   /* root box of the acceleration structure */
    float4 background;             /* rgb of a miss; w = ambient term */
    int width, height, n_lights, n_materials;
} RtFrame;                         /* 128 bytes */

typedef struct {
    float4 position;               /* w unused */
    float4 color;                  /* rgb * intensity; w unused */
} RtLight;                         /* 32 bytes */

typedef struct {
    float4 diffuse;                /* rgb; w unused */
    float4 specular;               /* rgb; w = shininess */
    float reflectivity, transparency, ior, pad;
} RtMaterial;                      /* 48 bytes */

/* A ray in registers. inv_d holds 1/d per component (+-inf for zero components, by IEEE rules). */
typedef struct {
    float3 o, d, inv_d;
    float tmin, tmax;
} Ray;

/* A closest-hit record; tri = -1 for a miss. Written to the host as float4 (t, u, v, tri bits). */
typedef struct {
    float t, u, v;
    int tri;
} Hit;

RT_FN Ray make_ray(float3 o, float3 d, float tmin, float tmax)
{
    Ray r;
    r.o = o;
    r.d = d;
    r.inv_d = f3(1.0f / d.x, 1.0f / d.y, 1.0f / d.z);
    r.tmin = tmin;
    r.tmax = tmax;
    return r;
}

/* Whether a hit at distance t on triangle tri replaces *hit: t within (tmin, hit->t), or exactly
 * hit->t on a lower triangle id. The tie rule makes the answer independent of the order triangles
 * are tested in, so every traversal reports the same triangle where two meet the ray at the same t
 * (a shared edge or vertex, duplicated triangles), as the float64 reference does. NaN t fails. */
RT_FN int closer_hit(const Ray *ray, float t, int tri, const Hit *hit)
{
    return t > ray->tmin && (t < hit->t || (t == hit->t && tri < hit->tri));
}

RT_FN Hit make_miss(float tmax)
{
    Hit h;
    h.t = tmax;
    h.u = 0.0f;
    h.v = 0.0f;
    h.tri = -1;
    return h;
}

/* Primary ray through pixel (x, y); the host builds the same ray in float32 (rtlab.camera_rays). */
RT_FN Ray camera_ray(RT_CONST const RtFrame *f, int x, int y)
{
    /* BEGIN SOLUTION */
    float sx = 2.0f * ((float)x + 0.5f) / (float)f->width - 1.0f;
    float sy = 1.0f - 2.0f * ((float)y + 0.5f) / (float)f->height;
    float3 d = add3(add3(xyz(f->w), mul3(xyz(f->u), sx)), mul3(xyz(f->v), sy));
    return make_ray(xyz(f->eye), normalize3(d), 0.0f, RT_INF);
    /* END SOLUTION */
}

#endif /* RT_TYPES_H */
