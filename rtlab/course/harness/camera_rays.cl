// Grader harness (OpenCL): the kernel is camera_rays.h's; OpenCL takes the frame as a __constant argument.
#include "camera_rays.h"
