// Lab step 04: shadow rays, one-pass and two-pass (§3.2.1, Table 5) (CUDA). The entry kernels are
// written once for both languages (kernels/shared/rt_entry_shadows.h); this file declares what CUDA
// keeps apart: the constant-memory symbols they read.
#include "rt_types.h"

__constant__ RtFrame c_frame;
__constant__ RtLight c_lights[RT_MAX_LIGHTS];
__constant__ RtMaterial c_materials[RT_MAX_MATERIALS];

#include "rt_entry_shadows.h"    // render_shadows, trace_primary_hits, shade_hits, probe_shadow
