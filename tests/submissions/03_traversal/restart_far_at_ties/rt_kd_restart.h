/* The textbook kd-restart (Foley & Sugerman 2005) without the tie bookkeeping of the reference:
 * at a split lying exactly at tmin it takes the far child, so a flat cell (a zero-width slab the
 * builder cuts around planar triangles) touched only at tmin is stepped over. */
RT_FN void traverse_kd_restart(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray,
                               Hit *hit, int any_hit)
{
    /* BEGIN SOLUTION */
    float t_enter, t_exit;
    if (!clip_ray_box(ray, scene_min, scene_max, &t_enter, &t_exit))
        return;
    int planes = 0;
    for (int side = 0; side < 8; ++side) {
        if (!kd_pass_needed(side, planes))
            continue;
        float tmin = t_enter;
        while (tmin < hit->t) {
            float tmax = t_exit;
            int2 n = load_node(nodes, 0);
            while (!kd_is_leaf(n)) {
                int first, second;
                float t_split;
                int visit = kd_children(n, ray, tmin, tmax, &first, &second, &t_split);
                if (visit == 3) {
                    int axis = n.x & 3;
                    planes |= 1 << axis;
                    n = load_node(nodes, ((side >> axis) & 1) ? second : first);
                    continue;
                }
                if (visit == 2) {
                    if (t_split <= tmin) {          /* the split at or before tmin: far child */
                        n = load_node(nodes, second);
                        continue;
                    }
                    tmax = rt_min(tmax, t_split);
                }
                n = load_node(nodes, first);
            }
            intersect_leaf(RT_SCENE_ARGS, n, ray, hit, any_hit);
            if (any_hit && hit->tri >= 0)
                return;
            if (hit->t <= tmax || tmax >= t_exit)
                break;
            tmin = tmax;
        }
    }
    /* END SOLUTION */
}
