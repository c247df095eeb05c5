RT_FN void traverse_kd_stack(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray,
                             Hit *hit, int any_hit)
{
    /* BEGIN SOLUTION */
    /* TODO (lab 00_primary): write traverse_kd_stack here; labs/00_primary/README.md says what it must do. */
    return;
    /* END SOLUTION */
}
