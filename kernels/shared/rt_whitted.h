/* rt_whitted.h - Whitted ray tracing as the paper does it (§3.2): point lights with a Blinn-Phong
 * highlight, shadow rays (§3.2.1, lab step 04), and reflection/refraction rays traced by a kernel
 * tree (§3.2.2, lab step 05). The entry kernels (rt_entry_shadows.h, rt_entry_bounces.h) only find
 * their index and call the functions at the end of this file.
 *
 * The shading model (rtlab/reference/whitted.py implements it again, independently, in float64;
 * keep the two in sync):
 *   local  c = wd kd ambient + sum_lights V_l L_l [wd kd (ns.l) + ks (ns.h)^shininess]
 *          wd = max(0, 1 - reflectivity - transparency): the share of light that is not mirrored
 *          or transmitted. The highlight is not scaled: it is the mirror image of the point light,
 *          which reflection rays cannot find. A light counts only where ns.l > 0 and it lies on the
 *          geometric front side (ng.l > 0); V_l is its shadow ray (1 with RT_SHADOWS off).
 *   split  kr = reflectivity + transparency F,  kt = transparency (1 - F)
 *          F: Schlick's approximation (RT_FRESNEL 1) with R0 = ((1 - ior) / (1 + ior))^2 and the
 *          cosine on the less dense side; or a fixed split (RT_FRESNEL 0): F = 0. Under total
 *          internal reflection F = 1 in both, so the transmitted share is reflected.
 *   child  weight = parent weight * kr (reflection) or * kt (refraction); a child lighter than
 *          RT_MIN_WEIGHT (far below one 8-bit step) is not spawned. Reflection mirrors d about ns;
 *          refraction bends it by eta = 1/ior entering (front face), ior leaving.
 *   pixel  the sum of weight * local colour (background for a miss) over the ray tree, clamped.
 * Transparent objects must be closed and wound counter-clockwise seen from outside: the winding
 * says whether a ray enters or leaves.
 */
#ifndef RT_WHITTED_H
#define RT_WHITTED_H
#include "rt_primary.h"

/* ---- Compile-time switches (rtlab/device/kernels.py build_defines; rtlab/device/whitted.py). The defaults are
 * the general kernel: everything compiled in. A scene-specialised kernel switches off what its
 * scene cannot use; the image does not change. */
#ifndef RT_LIGHTS                  /* 0: the scene has no lights: no lighting loop */
#define RT_LIGHTS 1
#endif
#ifndef RT_SHADOWS                 /* 1: shadow rays (§3.2.1); 0: lights are never occluded */
#define RT_SHADOWS 1
#endif
#ifndef RT_REFLECTION              /* 0: no material reflects: no reflection kernel */
#define RT_REFLECTION 1
#endif
#ifndef RT_REFRACTION              /* 0: no material transmits: no refraction kernel, no Fresnel */
#define RT_REFRACTION 1
#endif
#ifndef RT_MAX_DEPTH               /* bounces of the kernel tree: levels 0 (primary) .. RT_MAX_DEPTH */
#define RT_MAX_DEPTH 4
#endif
#ifndef RT_FRESNEL                 /* 1: Schlick; 0: fixed reflect/transmit split */
#define RT_FRESNEL 1
#endif
#ifndef RT_COMPACT                 /* 1: kernels append live rays to the next level (wavefront) */
#define RT_COMPACT 0
#endif
#ifndef RT_TWO_PASS                /* 1: tree kernels only trace; a shading kernel follows each */
#define RT_TWO_PASS 0
#endif
#ifndef RT_WAVEFRONT               /* 1: one launch per level over a ray queue (rt_wavefront.h) */
#define RT_WAVEFRONT 0
#endif
#define RT_MIN_WEIGHT (1.0f / 512.0f)  /* the host reads it (rtlab/kernel_constants.py) */
#define RT_RAY_REFLECTION 0
#define RT_RAY_REFRACTION 1
#define RT_NO_RAY (-2)             /* tri of a record whose ray was not spawned (-1: spawned, missed) */

/* ---- Spawning rays off a surface ------------------------------------------------------------ */

/* pbrt-v4's spawn offset (Pharr, Jakob & Humphreys, 4th ed., sec. 6.8, OffsetRayOrigin): p lies
 * within p_err of the exact point in every coordinate, so moving it along the unit normal n by
 * p_err (|n_x| + |n_y| + |n_z|), the distance along n that covers that error box, puts it on the
 * side n points to; each coordinate of the sum is then rounded one float further away from p, so
 * the addition's own rounding cannot pull it back. The offset scales with the triangle's
 * coordinates (position_error), at any distance from the origin. */
RT_FN float next_float_away(float x, float direction)
{
    if (direction == 0.0f || !rt_isfinite(x))
        return x;
    if (x == 0.0f)
        return direction > 0.0f ? rt_as_float(1) : -rt_as_float(1);
    int bits = rt_as_int(x);
    return rt_as_float((x > 0.0f) == (direction > 0.0f) ? bits + 1 : bits - 1);
}

RT_FN float3 offset_ray_origin(float3 p, float p_err, float3 n)
{
    float d = p_err * (rt_abs(n.x) + rt_abs(n.y) + rt_abs(n.z));
    float3 o = madd3(p, n, d);
    return f3(next_float_away(o.x, n.x), next_float_away(o.y, n.y), next_float_away(o.z, n.z));
}

/* Origin for a ray leaving surface s in direction d: offset to the side d points to. */
RT_FN float3 spawn_origin(const Surface *s, float3 d)
{
    return offset_ray_origin(s->p, s->p_err, dot3(d, s->ng) >= 0.0f ? s->ng : mul3(s->ng, -1.0f));
}

/* ---- Local shading with shadow rays (§3.2.1) ------------------------------------------------- */

/* Where a shadow segment from o along d = light_pos - o ends, as t (t = 1 is the light): short of the
 * light by RT_SHADOW_GAP_ULPS float ulps of the segment's and the light's coordinates (the largest
 * |component| of each). At t = 1, o + d rounds to a point up to an ulp of d past the light, and a
 * surface the light lies on is itself only within an ulp of its coordinates of the light: such a
 * surface (a lamp on the floor) would block the light it holds. A surface farther from the light
 * than the gap blocks it, however long the segment (a fixed share of the segment, pbrt's 1e-4, would
 * let a wall that near the light, on its far side, pass light through). Left out: surfaces
 * the segment meets at under ~1/RT_SHADOW_GAP_ULPS rad from their plane, within the gap over that
 * angle. The host reads the constant (rtlab/reference/whitted.py, rtlab/accel/light_buffer.py). */
#define RT_SHADOW_GAP_ULPS 32
RT_FN float shadow_segment_end(float3 light_pos, float3 d)
{
    float span = rt_max(rt_abs(d.x), rt_max(rt_abs(d.y), rt_abs(d.z)));
    float at = rt_max(rt_abs(light_pos.x), rt_max(rt_abs(light_pos.y), rt_abs(light_pos.z)));
    return 1.0f - (float)RT_SHADOW_GAP_ULPS * 5.9604645e-8f * (1.0f + at / span);
}

/* Shadow ray: whether the segment from surface s to the point light at light_pos is free. An
 * any-hit query with the primary rays' traversal code (the paper: "the same traversal code");
 * cast from the surface, whose spawn offset keeps it off its own triangle; t in (0,
 * shadow_segment_end) spans the segment, so nothing behind the light, or holding it, occludes. */
RT_FN int light_visible(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, const Surface *s, float3 light_pos)
{
    /* BEGIN SOLUTION */
    float3 o = spawn_origin(s, sub3(light_pos, s->p));
    float3 d = sub3(light_pos, o);
    Ray shadow = make_ray(o, d, 0.0f, shadow_segment_end(light_pos, d));
    return !trace_any(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, &shadow);
    /* END SOLUTION */
}

#ifndef RT_LIGHT_BUFFER            /* 1: shadow rays through each light's light buffer (rt_light_buffer.h) */
#define RT_LIGHT_BUFFER 0
#endif
#if RT_LIGHT_BUFFER
#include "rt_light_buffer.h"
#endif

/* Which lights reach surface s: bit i set when light i lies on the front side (ng.l > 0 and
 * ns.l > 0) and, with RT_SHADOWS, its shadow ray is free. Traced before any shading so that little
 * is live across the traversal (registers decide occupancy: the paper's Table 5). At most 32 lights
 * (the host checks). */
RT_FN unsigned int lights_reaching(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                                   const Surface *s)
{
    unsigned int mask = 0u;
#if RT_LIGHTS
    for (int i = 0; i < frame->n_lights; ++i) {
        float3 to_light = sub3(xyz(lights[i].position), s->p);
        if (dot3(s->ns, to_light) <= 0.0f || dot3(s->ng, to_light) <= 0.0f)
            continue;
#if RT_SHADOWS && RT_LIGHT_BUFFER
        if (!light_visible_buffered(RT_SCENE_ARGS, frame, s, &lights[i]))
            continue;
#elif RT_SHADOWS
        if (!light_visible(RT_SCENE_ARGS, frame, s, xyz(lights[i].position)))
            continue;
#endif
        mask |= 1u << i;
    }
#endif
    return mask;
}

/* Local colour of surface s seen along direction d: ambient, then for each light that reaches it,
 * Lambert times the unmirrored share plus a Blinn-Phong highlight (the model atop this file). */
RT_FN float3 shade_local(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                         RT_CONST const RtMaterial *materials, float3 d, const Surface *s)
{
    /* BEGIN SOLUTION */
    unsigned int mask = lights_reaching(RT_SCENE_ARGS, frame, lights, s);
    RT_CONST const RtMaterial *m = &materials[s->material];
    float wd = rt_max(1.0f - m->reflectivity - m->transparency, 0.0f);
    float3 kd = mul3(xyz(m->diffuse), wd);
    float3 c = mul3(kd, frame->background.w);
    for (int i = 0; mask != 0u; ++i, mask >>= 1) {
        if (!(mask & 1u))
            continue;
        float3 l = normalize3(sub3(xyz(lights[i].position), s->p));
        float3 h = normalize3(sub3(l, d));
        float spec = rt_pow(rt_max(dot3(s->ns, h), 0.0f), m->specular.w);
        float3 lit = add3(mul3(kd, dot3(s->ns, l)), mul3(xyz(m->specular), spec));
        c = add3(c, hadamard3(lit, xyz(lights[i].color)));
    }
    return c;
    /* END SOLUTION */
}

/* Colour of a traced ray with direction d: background for a miss, else local shading. */
RT_FN float3 shade_hit(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                       RT_CONST const RtMaterial *materials, float3 d, const Hit *hit)
{
    if (hit->tri < 0)
        return xyz(frame->background);
    Surface s = surface_at(RT_SCENE_ARGS, d, hit);
    return shade_local(RT_SCENE_ARGS, frame, lights, materials, d, &s);
}

/* ---- Reflection, refraction, Fresnel (§3.2.2) ----------------------------------------------- */

/* Mirror d about the unit normal n. */
RT_FN float3 reflect_dir(float3 d, float3 n) { return madd3(d, n, -2.0f * dot3(d, n)); }

/* Bend unit d through the interface with unit normal n (facing d's origin side) for the ratio
 * eta = n_from / n_to (Snell's law in vector form, e.g. pbrt 4th ed., sec. 9.3). Returns 0 under
 * total internal reflection; else *cos_t and the refracted direction in *t. */
RT_FN int refract_dir(float3 d, float3 n, float eta, float3 *t, float *cos_t)
{
    float cos_i = -dot3(d, n);
    float sin2_t = eta * eta * rt_max(1.0f - cos_i * cos_i, 0.0f);
    if (sin2_t > 1.0f)
        return 0;
    *cos_t = rt_sqrt(1.0f - sin2_t);
    *t = madd3(mul3(d, eta), n, eta * cos_i - *cos_t);
    return 1;
}

/* Schlick, "An Inexpensive BRDF Model for Physically-based Rendering", 1994: reflectance of a
 * dielectric interface, cos_theta measured on the less dense side. */
RT_FN float fresnel_schlick(float ior, float cos_theta)
{
    float r0 = (1.0f - ior) / (1.0f + ior);
    r0 *= r0;
    float x = 1.0f - cos_theta;
    float x2 = x * x;
    return r0 + (1.0f - r0) * (x2 * x2 * x);
}

/* How a surface hit splits its weight: kr to the reflection ray, kt to the refraction ray. */
typedef struct {
    float kr, kt;
    float eta;       /* n_from / n_to along the ray */
} Split;

RT_FN Split split_weights(RT_CONST const RtMaterial *m, float3 d, const Surface *s)
{
    Split sp;
    sp.kr = m->reflectivity;
    sp.kt = 0.0f;
    sp.eta = 1.0f;
#if RT_REFRACTION
    if (m->transparency > 0.0f) {
        sp.eta = s->front ? 1.0f / m->ior : m->ior;
        float3 t;
        float cos_t;
        float fresnel = 1.0f;   /* total internal reflection */
        if (refract_dir(d, s->ns, sp.eta, &t, &cos_t)) {
#if RT_FRESNEL
            fresnel = fresnel_schlick(m->ior, sp.eta > 1.0f ? cos_t : -dot3(d, s->ns));
#else
            fresnel = 0.0f;
#endif
        }
        sp.kr += m->transparency * fresnel;
        sp.kt = m->transparency * (1.0f - fresnel);
    }
#endif
    return sp;
}

/* Reflection child of a ray (direction d, weight w) at surface s: the ray in *child, its weight
 * in *w_child. Returns 0 when the surface reflects too little to spawn one. */
RT_FN int spawn_reflection(RT_CONST const RtMaterial *materials, float3 d, float w, const Surface *s,
                           Ray *child, float *w_child)
{
    /* BEGIN SOLUTION */
    Split sp = split_weights(&materials[s->material], d, s);
    *w_child = w * sp.kr;
    if (!(*w_child >= RT_MIN_WEIGHT))
        return 0;
    float3 r = reflect_dir(d, s->ns);
    *child = make_ray(spawn_origin(s, r), r, 0.0f, RT_INF);
    return 1;
    /* END SOLUTION */
}

/* Refraction child of a ray (direction d, weight w) at surface s, as spawn_reflection. None under
 * total internal reflection (kt = 0 there). */
RT_FN int spawn_refraction(RT_CONST const RtMaterial *materials, float3 d, float w, const Surface *s,
                           Ray *child, float *w_child)
{
    /* BEGIN SOLUTION */
    Split sp = split_weights(&materials[s->material], d, s);
    *w_child = w * sp.kt;
    float3 t;
    float cos_t;
    if (!(*w_child >= RT_MIN_WEIGHT) || !refract_dir(d, s->ns, sp.eta, &t, &cos_t))
        return 0;
    *child = make_ray(spawn_origin(s, t), t, 0.0f, RT_INF);
    return 1;
    /* END SOLUTION */
}

/* ---- Lab step 04: shadows one-pass and two-pass (§3.2.1, Table 5) --------------------------- */

/* One-pass: primary ray, shadow rays and shading in one kernel; the pixel's hit in *hit. */
RT_FN unsigned int render_pixel_shadows(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame,
                                        RT_CONST const RtLight *lights, RT_CONST const RtMaterial *materials,
                                        int x, int y, Hit *hit)
{
    Ray ray = camera_ray(frame, x, y);
    *hit = make_miss(ray.tmax);
    trace_closest(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, &ray, hit);
    return pack_rgba8(shade_hit(RT_SCENE_ARGS, frame, lights, materials, ray.d, hit));
}

/* Two-pass, pass 1: the primary hit of pixel (x, y), for the global buffer between the passes. */
RT_FN Hit trace_pixel(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, int x, int y)
{
    Ray ray = camera_ray(frame, x, y);
    Hit hit = make_miss(ray.tmax);
    trace_closest(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, &ray, &hit);
    return hit;
}

RT_FN Hit unpack_hit(float4 h)
{
    Hit hit;
    hit.t = h.x;
    hit.u = h.y;
    hit.v = h.z;
    hit.tri = rt_as_int(h.w);
    return hit;
}

/* Two-pass, pass 2: shadow rays and shading of pixel (x, y) from its stored hit. The camera ray
 * is rebuilt (the same float operations give the same direction), so only the hit is stored. */
RT_FN unsigned int shade_pixel(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                               RT_CONST const RtMaterial *materials, int x, int y, float4 stored_hit)
{
    Ray ray = camera_ray(frame, x, y);
    Hit hit = unpack_hit(stored_hit);
    return pack_rgba8(shade_hit(RT_SCENE_ARGS, frame, lights, materials, ray.d, &hit));
}

/* Whether the segment from the hit of direction-d ray to target is free (probe for tests: the
 * very shadow ray of shade_local, from any hit to any point). */
RT_FN int probe_visible(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, float4 d, float4 stored_hit, float4 target)
{
    Hit hit = unpack_hit(stored_hit);
    if (hit.tri < 0)
        return 1;
    Surface s = surface_at(RT_SCENE_ARGS, xyz(d), &hit);
    return light_visible(RT_SCENE_ARGS, frame, &s, xyz(target));
}

/* ---- Lab step 05: the kernel tree (§3.2.2) --------------------------------------------------
 * Each node of the tree is one kernel launch over the rays of one kind (primary, reflection or
 * refraction) at one level. A node reads its parents' records from the buffer of level L-1 and
 * writes its own to the buffer of level L: (direction, weight), (t, u, v, tri) and, compacted,
 * the pixel. The host walks the tree depth-first, so one buffer per level, RT_MAX_DEPTH + 1 in
 * all, is alive at once (the paper's count). Each node adds weight * colour to a float4 frame. */

/* Parents of further rays: hits on a material that reflects or transmits. */
RT_FN int spawns_children(RT_SCENE_PARAMS, RT_CONST const RtMaterial *materials, const Hit *hit)
{
    if (hit->tri < 0)
        return 0;
    RT_CONST const RtMaterial *m = &materials[load_tri_material(tri_materials, hit->tri)];
    return m->reflectivity + m->transparency > 0.0f;
}

RT_FN void add_rgb(RT_GLOBAL float4 *frame_rgb, int pixel, float3 c)
{
    float4 a = frame_rgb[pixel];
    frame_rgb[pixel] = f4(a.x + c.x, a.y + c.y, a.z + c.z, a.w);
}

/* Write the record of a traced ray at level `level` (slot: the launch index; pixel: its pixel).
 * Kept: rays that can have children; with RT_TWO_PASS (the shading kernel needs them) or
 * RT_WRITE_HITS (the host reads the ray tree) every spawned ray, the last level included.
 * Uncompacted, a slot is always written (weight 0: no ray), since the buffer is reused by the
 * node's siblings; compacted, kept rays are appended and the count is the next launch's size. */
RT_FN void write_record(RT_SCENE_PARAMS, RT_CONST const RtMaterial *materials, int level, int slot,
                        int pixel, float3 d, float w, Hit hit, int spawned, RT_GLOBAL float4 *dirs_out,
                        RT_GLOBAL float4 *hits_out, RT_GLOBAL int *pixels_out, RT_GLOBAL int *count_out)
{
#if RT_TWO_PASS || RT_WRITE_HITS
    int keep = spawned;
#else
    if (level >= RT_MAX_DEPTH)
        return;
    int keep = spawned && spawns_children(RT_SCENE_ARGS, materials, &hit);
#endif
    if (!spawned)
        hit.tri = RT_NO_RAY;
#if RT_COMPACT
    if (!keep)
        return;
    slot = rt_atomic_inc(count_out);
    pixels_out[slot] = pixel;
#endif
    dirs_out[slot] = f4(d.x, d.y, d.z, keep ? w : 0.0f);
    hits_out[slot] = pack_hit(hit);
}

/* Level 0 of the tree: the primary ray of pixel (x, y), shaded (unless two-pass) into the frame,
 * recorded for its children. */
RT_FN void trace_tree_primary(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                              RT_CONST const RtMaterial *materials, int x, int y, RT_GLOBAL float4 *frame_rgb,
                              RT_GLOBAL float4 *dirs_out, RT_GLOBAL float4 *hits_out, RT_GLOBAL int *pixels_out,
                              RT_GLOBAL int *count_out)
{
    int pixel = y * frame->width + x;
    Ray ray = camera_ray(frame, x, y);
    Hit hit = make_miss(ray.tmax);
    trace_closest(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, &ray, &hit);
#if !RT_TWO_PASS
    float3 c = shade_hit(RT_SCENE_ARGS, frame, lights, materials, ray.d, &hit);
    frame_rgb[pixel] = f4(c.x, c.y, c.z, 1.0f);
#endif
    write_record(RT_SCENE_ARGS, materials, 0, pixel, pixel, ray.d, 1.0f, hit, 1, dirs_out, hits_out,
                 pixels_out, count_out);
}

/* One tree node for parent record `slot` of level - 1: spawn its child of `kind`, trace it, add
 * its weighted colour to the frame (unless two-pass), record it at `level`. */
RT_FN void trace_tree_secondary(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                                RT_CONST const RtMaterial *materials, int kind, int level, int slot,
                                RT_GLOBAL const float4 *dirs_in, RT_GLOBAL const float4 *hits_in,
                                RT_GLOBAL const int *pixels_in, RT_GLOBAL float4 *frame_rgb,
                                RT_GLOBAL float4 *dirs_out, RT_GLOBAL float4 *hits_out,
                                RT_GLOBAL int *pixels_out, RT_GLOBAL int *count_out)
{
#if RT_COMPACT
    int pixel = pixels_in[slot];
#else
    int pixel = slot;
#endif
    float4 dw = dirs_in[slot];
    Hit parent = unpack_hit(hits_in[slot]);
    Ray child;
    float w = 0.0f;
    int spawned = 0;
    if (dw.w > 0.0f && parent.tri >= 0) {
        Surface s = surface_at(RT_SCENE_ARGS, xyz(dw), &parent);
        spawned = kind == RT_RAY_REFLECTION ? spawn_reflection(materials, xyz(dw), dw.w, &s, &child, &w)
                                            : spawn_refraction(materials, xyz(dw), dw.w, &s, &child, &w);
    }
    Hit hit = make_miss(RT_INF);
    if (spawned) {
        trace_closest(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, &child, &hit);
#if !RT_TWO_PASS
        add_rgb(frame_rgb, pixel, mul3(shade_hit(RT_SCENE_ARGS, frame, lights, materials, child.d, &hit), w));
#endif
    }
    write_record(RT_SCENE_ARGS, materials, level, slot, pixel, spawned ? child.d : f3(0.0f, 0.0f, 0.0f), w,
                 hit, spawned, dirs_out, hits_out, pixels_out, count_out);
}

/* Two-pass tree: the shading kernel after a node, over that node's records (shadow rays here). */
RT_FN void shade_tree_record(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights,
                             RT_CONST const RtMaterial *materials, int level, int slot,
                             RT_GLOBAL const float4 *dirs, RT_GLOBAL const float4 *hits,
                             RT_GLOBAL const int *pixels, RT_GLOBAL float4 *frame_rgb)
{
#if RT_COMPACT
    int pixel = pixels[slot];
#else
    int pixel = slot;
#endif
    float4 dw = dirs[slot];
    if (!(dw.w > 0.0f))
        return;
    Hit hit = unpack_hit(hits[slot]);
    float3 c = mul3(shade_hit(RT_SCENE_ARGS, frame, lights, materials, xyz(dw), &hit), dw.w);
    if (level == 0)
        frame_rgb[pixel] = f4(c.x, c.y, c.z, 1.0f);
    else
        add_rgb(frame_rgb, pixel, c);
}

/* Probe for tests: the child of `kind` spawned from a stored hit, and its closest hit. Writes
 * (origin, weight), (direction, 0) and the hit; weight 0 and tri RT_NO_RAY when none is spawned. */
RT_FN void probe_spawn(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_CONST const RtMaterial *materials,
                       int kind, float4 d, float4 stored_hit, float4 *origin_w, float4 *dir, float4 *child_hit)
{
    Hit parent = unpack_hit(stored_hit);
    Ray child;
    float w = 0.0f;
    int spawned = 0;
    if (parent.tri >= 0) {
        Surface s = surface_at(RT_SCENE_ARGS, xyz(d), &parent);
        spawned = kind == RT_RAY_REFLECTION ? spawn_reflection(materials, xyz(d), 1.0f, &s, &child, &w)
                                            : spawn_refraction(materials, xyz(d), 1.0f, &s, &child, &w);
    }
    Hit hit = make_miss(RT_INF);
    if (spawned)
        trace_closest(RT_SCENE_ARGS, frame->scene_min, frame->scene_max, &child, &hit);
    else
        hit.tri = RT_NO_RAY;
    *origin_w = spawned ? f4(child.o.x, child.o.y, child.o.z, w) : f4(0.0f, 0.0f, 0.0f, 0.0f);
    *dir = spawned ? f4(child.d.x, child.d.y, child.d.z, 0.0f) : f4(0.0f, 0.0f, 0.0f, 0.0f);
    *child_hit = pack_hit(hit);
}

/* Probe for tests: refraction of unit d through unit normal n (facing d's origin) for ior, the
 * ray entering when front != 0. Writes (t, F): the refracted direction and the Schlick
 * reflectance; (0, 0, 0, 1) under total internal reflection. */
RT_FN float4 probe_refraction(float4 d, float4 n, float ior, int front)
{
    float eta = front ? 1.0f / ior : ior;
    float3 t;
    float cos_t;
    if (!refract_dir(xyz(d), xyz(n), eta, &t, &cos_t))
        return f4(0.0f, 0.0f, 0.0f, 1.0f);
    float f = fresnel_schlick(ior, eta > 1.0f ? cos_t : -dot3(xyz(d), xyz(n)));
    return f4(t.x, t.y, t.z, f);
}

#endif /* RT_WHITTED_H */
