// The library's Whitted frames without bounces (rtlab.device.whitted.render_whitted, bounces 0): shadows
// one-pass or two-pass, and the shadow-ray probe. Not a lab step: the same entry kernels as lab step
// 04's (kernels/shared/rt_entry_shadows.h). CUDA: the constant-memory symbols the kernels read.
#include "rt_types.h"

__constant__ RtFrame c_frame;
__constant__ RtLight c_lights[RT_MAX_LIGHTS];
__constant__ RtMaterial c_materials[RT_MAX_MATERIALS];

#include "rt_entry_shadows.h"    // render_shadows, trace_primary_hits, shade_hits, probe_shadow
