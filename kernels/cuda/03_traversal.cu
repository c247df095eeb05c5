// Lab step 03: kd-tree traversal variants (the paper's Table 4) and the BVH (CUDA). Same entry
// kernels and arguments as step 00 (kernels/shared/rt_entry_trace.h): built with RT_TRAVERSAL =
// packet, each block traces its rays as one packet with a stack in shared memory
// (kernels/shared/rt_packet.h); any other traversal runs one ray a thread through trace_closest.
#include "rt_types.h"

__constant__ RtFrame c_frame;
__constant__ RtLight c_lights[RT_MAX_LIGHTS];
__constant__ RtMaterial c_materials[RT_MAX_MATERIALS];

#include "rt_entry_trace.h"      // trace_rays, render_primary
