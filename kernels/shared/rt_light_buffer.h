/* rt_light_buffer.h - shadow rays through a light buffer (Haines & Greenberg 1986): for a point light, a
 * cube of cells around it, each listing the triangles that may cross its cone of directions, nearest
 * to the light first (built by rtlab/accel/light_buffer.py, which gives the layout). The shadow ray of
 * light_visible, the same ray, is tested against the list of the cell its origin lies in, up to the
 * first triangle farther from the light than the origin: such a triangle cannot cross the segment;
 * an origin beyond the distance at which one triangle crosses the cell's whole cone is in shadow.
 * The lists are conservative, so the answer is the traversal's; a cell whose list was too long, or a
 * light without a block, asks the traversal (light_visible). The block is appended to node_data (read
 * a word at a time, as rt_bvh4.h reads its refs) at the word the light's position.w carries (int bits;
 * -1: none). Compiled in where the loader sets RT_LIGHT_BUFFER (rtlab.device.whitted). */
#ifndef RT_LIGHT_BUFFER_H
#define RT_LIGHT_BUFFER_H

/* The cell of point w (relative to the light) in a block of resolution res, or -1 for w = 0 */
RT_FN int light_buffer_cell(float3 w, int res)
{
    float ax = rt_abs(w.x), ay = rt_abs(w.y), az = rt_abs(w.z);
    int axis = ax >= ay && ax >= az ? 0 : (ay >= az ? 1 : 2);
    float m = rt_max(ax, rt_max(ay, az));
    if (!(m > 0.0f))
        return -1;
    float a = get3(w, axis), u = get3(w, axis == 2 ? 0 : axis + 1), v = get3(w, axis == 0 ? 2 : axis - 1);
    float half_res = 0.5f * (float)res;   /* |u| <= m, so u / m + 1 >= 0 and (int) is the floor */
    int col = rt_imin((int)((u / m + 1.0f) * half_res), res - 1);
    int row = rt_imin((int)((v / m + 1.0f) * half_res), res - 1);
    int face = 2 * axis + (a < 0.0f ? 1 : 0);
    return (face * res + row) * res + col;
}

/* Whether the segment from surface s to the point light is free (light_visible's answer) */
RT_FN int light_visible_buffered(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, const Surface *s, float4 light)
{
    float3 light_pos = xyz(light);
    int base = rt_as_int(light.w);
    float3 o = spawn_origin(s, sub3(light_pos, s->p));
    float3 w = sub3(o, light_pos);
    int cell = base >= 0 ? light_buffer_cell(w, load_node_word(node_data, base)) : -1;
    int first = 0, count = -1;
    float blocked = RT_INF;
    if (cell >= 0) {
        first = base + load_node_word(node_data, base + 1 + 3 * cell);
        count = load_node_word(node_data, base + 2 + 3 * cell);
        blocked = rt_as_float(load_node_word(node_data, base + 3 + 3 * cell));
    }
    if (count < 0)
        return light_visible(RT_SCENE_ARGS, frame, s, light_pos);
    float reach = rt_sqrt(dot3(w, w));
    if (reach > blocked)
        return 0;
    Ray shadow = make_ray(o, sub3(light_pos, o), 0.0f, 1.0f);
    Hit hit = make_miss(1.0f);
    for (int i = 0; i < count; ++i) {
        int ref = first + 2 * i;
        if (rt_as_float(load_node_word(node_data, ref + 1)) > reach)
            break;
        if (intersect_tri(RT_SCENE_ARGS, &shadow, load_node_word(node_data, ref), &hit))
            return 0;
    }
    return 1;
}

#endif /* RT_LIGHT_BUFFER_H */
