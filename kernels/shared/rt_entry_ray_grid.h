/* rt_entry_ray_grid.h - closest hits of rays laid out as an image, width x height row-major
 * (rtlab.trace(..., width=)): a 2-D launch whose blocks take tiles of it in launch_pixel's order, as
 * render_primary's do, so a warp traces neighbouring rays. With the kd packet one tile is one packet.
 * (bvh-packet takes consecutive rays, a row segment, through trace_rays: the host launches that.)
 */
#ifndef RT_ENTRY_RAY_GRID_H
#define RT_ENTRY_RAY_GRID_H
#define RT_PACKET_KERNELS 1
#include "rt_primary.h"

#if RT_TRAVERSAL != RT_TRAVERSAL_PACKET
/* The closest hit of pixel (x, y)'s ray, if it lies in the image */
RT_FN void trace_image_ray(RT_SCENE_PARAMS, RT_CONST const RtFrame *frame, RT_IN(float4) origins, RT_IN(float4) directions,
                           RT_OUT(float4) hits, int width, int height, int x, int y)
{
    if (x >= width || y >= height)
        return;
    int i = y * width + x;
    rt_store_once(&hits[i], pack_hit(trace_one(RT_SCENE_ARGS, frame, rt_load_once(&origins[i]),
                                               rt_load_once(&directions[i]))));
}
#endif

RT_KERNEL void trace_ray_grid(RT_SCENE_PARAMS, RT_IN(float4) origins, RT_IN(float4) directions, RT_OUT(float4) hits,
                              int width, int height RT_WITH_FRAME)
{
    int x, y;
    launch_pixel(&x, &y);
#if RT_TRAVERSAL == RT_TRAVERSAL_PACKET
    /* Threads outside the image still take part in the packet's barriers */
    RT_SHARED KdPacketShared packet;
    int valid = x < width && y < height;
    int i = valid ? y * width + x : 0;
    Hit hit = trace_one_packet(RT_SCENE_ARGS, rt_frame, rt_load_once(&origins[i]), rt_load_once(&directions[i]), valid,
                               &packet, rt_local_id(1) * rt_local_size(0) + rt_local_id(0));
    if (valid)
        rt_store_once(&hits[i], pack_hit(hit));
#else
    trace_image_ray(RT_SCENE_ARGS, rt_frame, origins, directions, hits, width, height, x, y);
#endif
}

#if defined(RT_ORDERED_GRID_KERNEL) && RT_TRAVERSAL != RT_TRAVERSAL_PACKET
/* trace_ray_grid with block b taking the tile tiles[b] (its column and row, in block units) in place of
 * its own: the host orders the tiles costliest first (rtlab.device.tile_orders), so a launch does not
 * end behind costly tiles started last. b counts blocks row by row of the launch's grid, whose width
 * in blocks, ceil(width / block width), is read from the launch (a division there would be ~30
 * instructions a thread ahead of the tile's first load). Only the library's program declares it: the
 * labs' grid stays the paper's. */
RT_KERNEL void trace_ray_grid_ordered(RT_SCENE_PARAMS, RT_IN(float4) origins, RT_IN(float4) directions,
                                      RT_OUT(float4) hits, int width, int height, RT_IN(int2) tiles RT_WITH_FRAME)
{
    int2 tile = tiles[rt_group_id(1) * rt_num_groups(0) + rt_group_id(0)];
    int x, y;
    block_pixel(tile.x, tile.y, rt_local_size(0), rt_local_size(1), rt_local_id(0), rt_local_id(1), &x, &y);
    trace_image_ray(RT_SCENE_ARGS, rt_frame, origins, directions, hits, width, height, x, y);
}
#endif

#endif /* RT_ENTRY_RAY_GRID_H */
