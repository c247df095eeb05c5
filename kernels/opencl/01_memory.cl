// Lab step 01: memory placement (§3.1.1) (OpenCL). Same entry kernels and arguments as step 00 (written
// once, kernels/shared/rt_entry_*.h); the defines choose where each kind of data lives:
//   RT_NODE_MEM   tree, object list, vertices, normals: __global buffers, or image1d_buffer images
//                 (the fetch functions in kernels/shared/rt_memory.h)
//   RT_CONST_MEM  camera, lights, materials: __constant or __global arguments (RT_CONST, rt_port.h)
//   RT_RAY_MEM    the ray: registers, or arrays indexed by the split axis (get3 in rt_port.h)
// The paper's third placement, the ray in shared (OpenCL: local) memory, is CUDA only: the shared
// functions take the ray through an unqualified pointer, which OpenCL C 1.2 makes __private, and
// the generic address space that would take a __local ray is optional in OpenCL 3.0 - neither
// PoCL 3.1 nor NVIDIA's driver has it.
// fetch_scene reads any scene buffer element through the placement compiled in, so a test can check
// a placement against the host arrays bit for bit.
#include "rt_port.h"

#if RT_RAY_MEM == RT_MEM_SHARED
#error "RT_RAY_MEM == RT_MEM_SHARED (ray in local memory) needs the generic address space; CUDA only"
#endif

#include "rt_entry_trace.h"      // trace_rays, render_primary
#include "rt_entry_fetch.h"      // fetch_scene
