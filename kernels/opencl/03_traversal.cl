// Lab step 03: kd-tree traversal variants (the paper's Table 4) and the BVH (OpenCL). Same entry
// kernels and arguments as step 00 (kernels/shared/rt_entry_trace.h): built with RT_TRAVERSAL =
// packet, each work-group traces its rays as one packet with a stack in local memory
// (kernels/shared/rt_packet.h); any other traversal runs one ray a work-item through trace_closest.
#include "rt_entry_trace.h"      // trace_rays, render_primary
