// Lab step 00: primary rays with simple shading (CUDA). The entry kernels are written once for both
// languages (kernels/shared/rt_entry_*.h); this file declares what CUDA keeps apart: the
// constant-memory symbols they read.
#include "rt_types.h"

__constant__ RtFrame c_frame;
__constant__ RtLight c_lights[RT_MAX_LIGHTS];
__constant__ RtMaterial c_materials[RT_MAX_MATERIALS];

#include "rt_entry_trace.h"      // trace_rays, render_primary
#include "rt_entry_ray_grid.h"   // trace_ray_grid
