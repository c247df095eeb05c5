// The library's Whitted frames without bounces (rtlab.device.whitted.render_whitted, bounces 0): shadows
// one-pass or two-pass, and the shadow-ray probe. Not a lab step: the same entry kernels as lab step
// 04's (kernels/shared/rt_entry_shadows.h). OpenCL: constants are __constant arguments, last.
#include "rt_entry_shadows.h"    // render_shadows, trace_primary_hits, shade_hits, probe_shadow
