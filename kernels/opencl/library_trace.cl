// The library's closest hits and primary rays (rtlab.trace, rtlab.render, the brute-force probe):
// every traversal, triangle test and node placement of the variant registry (rtlab/device/variants.py).
// Not a lab step: the same entry kernels as the labs' (kernels/shared/rt_entry_*.h), so a change to a
// lab file never changes the library. OpenCL: constants are __constant arguments, last.
#ifndef RT_BVH4_OCTANT_WALKS
#define RT_BVH4_OCTANT_WALKS 1         // the 4-wide walk inlined per octant, taken where a warp shares one (rt_bvh4.h)
#endif
#define RT_FETCH_KERNEL 1              // trace_rays_fetch: rays taken as lanes free up (rt_bvh.h)
#include "rt_entry_trace.h"      // trace_rays, render_primary, trace_rays_fetch
#define RT_ORDERED_GRID_KERNEL 1       // trace_ray_grid_ordered: the costliest tiles first (tile_orders.py)
#include "rt_entry_ray_grid.h"   // trace_ray_grid, trace_ray_grid_ordered
#include "rt_entry_loop.h"       // trace_rays_loop (and intersect_triangles)
