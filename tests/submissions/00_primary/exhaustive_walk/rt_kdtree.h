RT_FN void traverse_kd_stack(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray,
                             Hit *hit, int any_hit)
{
    /* BEGIN SOLUTION */
    /* Every node of the tree and every leaf's triangles, no culling: exact hits by brute force */
    int stack[RT_STACK_SIZE + 1];
    int sp = 0;
    int node = 0;
    for (;;) {
        int2 n = load_node(nodes, node);
        while (!kd_is_leaf(n)) {
            int left = n.x >> 2;
            stack[sp++] = left + 1;
            node = left;
            n = load_node(nodes, node);
        }
        intersect_leaf(RT_SCENE_ARGS, n, ray, hit, any_hit);
        if (sp == 0 || (any_hit && hit->tri >= 0))
            return;
        node = stack[--sp];
    }
    /* END SOLUTION */
}
