// Lab step 05: reflection and refraction rays as a kernel tree (§3.2.2, Table 5) (OpenCL). Every tree
// node is one launch of trace_reflection or trace_refraction over the records of the level above;
// rtlab/device/whitted_frames.py walks the tree depth-first. The entry kernels are written once for
// both languages (kernels/shared/rt_entry_bounces.h); OpenCL takes the constants as __constant
// arguments, last (frame, lights, materials).
#include "rt_entry_bounces.h"    // the tree's (or the wavefront's) kernels, pack_frame, probes
