RT_FN void traverse_kd_stack(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray,
                             Hit *hit, int any_hit)
{
    /* BEGIN SOLUTION */
    float tmin, tmax;
    if (!clip_ray_box(ray, scene_min, scene_max, &tmin, &tmax))
        return;
    KdStackEntry stack[RT_STACK_SIZE];
    int sp = 0;
    int node = 0;
    for (;;) {
        int2 n = load_node(nodes, node);
        /* Descend to a leaf, pushing the far child when the segment crosses the split */
        while (!kd_is_leaf(n)) {
            int first, second;
            float t_split;
            int visit = kd_children(n, ray, tmin, tmax, &first, &second, &t_split);
            if (visit >= 2) {
                float entry_tmin = visit == 3 ? tmin : t_split;
                stack[sp].node = second;
                stack[sp].tmin = entry_tmin;
                stack[sp].tmax = tmax;
                stack[sp].t_stop = sp > 0 ? rt_min(entry_tmin, stack[sp - 1].t_stop) : entry_tmin;
                ++sp;
                tmax = t_split;
            }
            node = first;
            n = load_node(nodes, node);
        }
        intersect_leaf(RT_SCENE_ARGS, n, ray, hit, any_hit);
        /* Done when no pending cell starts before the hit: the stack holds every unvisited cell
         * the ray crosses */
        if (sp <= 1 || hit->t <= stack[sp - 1].t_stop || (any_hit && hit->tri >= 0))
            return;
        --sp;
        node = stack[sp].node;
        tmin = stack[sp].tmin;
        tmax = stack[sp].tmax;
    }
    /* END SOLUTION */
}
