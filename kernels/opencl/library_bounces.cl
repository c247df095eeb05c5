// The library's Whitted frames with reflection and refraction (rtlab.device.whitted.render_whitted,
// bounces >= 1): the paper's kernel tree or the wavefront schedule, and the secondary-ray probes. Not
// a lab step: the same entry kernels as lab step 05's (kernels/shared/rt_entry_bounces.h). OpenCL:
// constants are __constant arguments, last.
#include "rt_entry_bounces.h"    // the tree's (or the wavefront's) kernels, pack_frame, probes
