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

/* The block's layout (rtlab/accel/light_buffer.py reads these): a header of 4 words, then two words a
 * cell, the first of them the cell's first ref (a word of the block) above its count's 7 bits, a count
 * of 127 sending the cell's rays to the traversal. */
#define RT_LB_HEADER_WORDS 4
#define RT_LB_CELL_WORDS 2
#define RT_LB_COUNT_BITS 7
#define RT_LB_TO_TRAVERSAL ((1 << RT_LB_COUNT_BITS) - 1)

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

/* Whether a triangle crosses the shadow ray (its t in (0, shadow->tmax): light_visible's segment) */
RT_FN int light_buffer_blocks(RT_SCENE_PARAMS, const Ray *shadow, int tri)
{
    Hit hit = make_miss(shadow->tmax);
    return intersect_tri(RT_SCENE_ARGS, shadow, tri, &hit);
}

/* The distance to the light a ref carries above its id_bits of triangle id: the float's bits
 * truncated, so never above the true distance. */
RT_FN float light_buffer_ref_distance(int ref, int id_bits)
{
    return rt_as_float((int)(((unsigned int)ref >> id_bits) << (id_bits - 1)));
}

/* Whether the segment from surface s to the point light is free (light_visible's answer). The list is
 * walked two refs at a time, both triangles tested at once: a walk is a chain of dependent loads (ref,
 * then triangle), and the pair halves its links. The light's color.w carries the block's resolution
 * and, from bit 16, the bits of a ref's triangle id. */
RT_FN int light_visible_buffered(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, const Surface *s,
                                 RT_CONST const RtLight *light)
{
    float3 light_pos = xyz(light->position);
    int base = rt_as_int(light->position.w);
    int shape = rt_as_int(light->color.w);
    float3 o = spawn_origin(s, sub3(light_pos, s->p));
    float3 w = sub3(o, light_pos);
    int cell = base >= 0 ? light_buffer_cell(w, shape & 0xffff) : -1;
    int head = RT_LB_TO_TRAVERSAL;
    float blocked = RT_INF;
    if (cell >= 0) {
        head = load_node_word(node_data, base + RT_LB_HEADER_WORDS + RT_LB_CELL_WORDS * cell);
        blocked = rt_as_float(load_node_word(node_data, base + RT_LB_HEADER_WORDS + RT_LB_CELL_WORDS * cell + 1));
    }
    int count = head & RT_LB_TO_TRAVERSAL;
    if (count == RT_LB_TO_TRAVERSAL)
        return light_visible(RT_SCENE_ARGS, frame, s, light_pos);
    float reach = rt_sqrt(dot3(w, w));
    if (reach > blocked)
        return 0;
    int first = base + (int)((unsigned int)head >> RT_LB_COUNT_BITS);
    int id_bits = shape >> 16;
    int id_mask = (1 << id_bits) - 1;
    float3 d = sub3(light_pos, o);
    Ray shadow = make_ray(o, d, 0.0f, shadow_segment_end(light_pos, d));
    for (int i = 0; i < count; i += 2) {
        int near = load_node_word(node_data, first + i);
        int far = load_node_word(node_data, first + rt_imin(i + 1, count - 1));
        if (light_buffer_ref_distance(near, id_bits) > reach)
            break;
        int near_blocks = light_buffer_blocks(RT_SCENE_ARGS, &shadow, near & id_mask);
        int far_blocks = light_buffer_blocks(RT_SCENE_ARGS, &shadow, far & id_mask);
        if (near_blocks)
            return 0;
        if (i + 1 >= count || light_buffer_ref_distance(far, id_bits) > reach)
            break;
        if (far_blocks)
            return 0;
    }
    return 1;
}

#endif /* RT_LIGHT_BUFFER_H */
