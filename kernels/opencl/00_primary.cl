// Lab step 00: primary rays with simple shading (OpenCL). The entry kernels are written once for both
// languages (kernels/shared/rt_entry_*.h); OpenCL takes the constants as __constant arguments, last
// (frame, lights, materials), so nothing here is its own.
#include "rt_entry_trace.h"      // trace_rays, render_primary
#include "rt_entry_ray_grid.h"   // trace_ray_grid
