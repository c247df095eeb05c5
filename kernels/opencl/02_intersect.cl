// Lab step 02: triangle intersection tests (the paper's Table 3, OpenCL). Each work-item takes the
// camera ray of its pixel and tests it against the first n_tris triangles of the scene in a loop, no
// acceleration structure; RT_ISECT picks the test. The entry kernels are written once for both
// languages (kernels/shared/rt_entry_loop.h); OpenCL takes the frame as a __constant argument, last.
#include "rt_entry_loop.h"       // intersect_triangles, trace_rays_loop
