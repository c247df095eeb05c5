// Grader harness (CUDA): the kernel is camera_rays.h's; CUDA reads the frame from a constant symbol.
#include "rt_types.h"

__constant__ RtFrame c_frame;

#include "camera_rays.h"
