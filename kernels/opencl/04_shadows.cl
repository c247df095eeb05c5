// Lab step 04: shadow rays, one-pass and two-pass (§3.2.1, Table 5) (OpenCL). The entry kernels are
// written once for both languages (kernels/shared/rt_entry_shadows.h); OpenCL takes the constants as
// __constant arguments, last (frame, lights, materials).
#include "rt_entry_shadows.h"    // render_shadows, trace_primary_hits, shade_hits, probe_shadow
