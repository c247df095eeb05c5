// Lab step 05: reflection and refraction rays as a kernel tree (§3.2.2, Table 5) (CUDA). Every tree
// node is one launch of trace_reflection or trace_refraction over the records of the level above;
// rtlab/device/whitted_frames.py walks the tree depth-first. The entry kernels are written once for
// both languages (kernels/shared/rt_entry_bounces.h); this file declares the constant-memory symbols.
#include "rt_types.h"

__constant__ RtFrame c_frame;
__constant__ RtLight c_lights[RT_MAX_LIGHTS];
__constant__ RtMaterial c_materials[RT_MAX_MATERIALS];

#include "rt_entry_bounces.h"    // the tree's (or the wavefront's) kernels, pack_frame, probes
