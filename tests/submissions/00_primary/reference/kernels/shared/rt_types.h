RT_FN Ray camera_ray(RT_CONST const RtFrame *f, int x, int y)
{
    /* BEGIN SOLUTION */
    float sx = 2.0f * ((float)x + 0.5f) / (float)f->width - 1.0f;
    float sy = 1.0f - 2.0f * ((float)y + 0.5f) / (float)f->height;
    float3 d = add3(add3(xyz(f->w), mul3(xyz(f->u), sx)), mul3(xyz(f->v), sy));
    return make_ray(xyz(f->eye), normalize3(d), 0.0f, RT_INF);
    /* END SOLUTION */
}
