"""numpy mirrors of the device structs in kernels/shared/rt_types.h (sync with that file).

Only float4 and 4-byte scalars cross to the device: float3 is 12 bytes in CUDA and 16 in OpenCL.
tests/test_kernel_sources.py checks these sizes against sizeof() on the device.
"""
from __future__ import annotations

import numpy as np

F4 = (np.float32, 4)

FRAME_DTYPE = np.dtype([
    ("eye", F4), ("u", F4), ("v", F4), ("w", F4),
    ("scene_min", F4), ("scene_max", F4),
    ("background", F4),                       # rgb of a miss, w = ambient term
    ("width", np.int32), ("height", np.int32), ("n_lights", np.int32), ("n_materials", np.int32),
])
LIGHT_DTYPE = np.dtype([("position", F4), ("color", F4)])
MATERIAL_DTYPE = np.dtype([
    ("diffuse", F4), ("specular", F4),        # specular.w = shininess
    ("reflectivity", np.float32), ("transparency", np.float32), ("ior", np.float32), ("pad", np.float32),
])
# A hit as the kernels write it: float4 (t, u, v, triangle id bits); tri = -1 for a miss.
HIT_DTYPE = np.dtype([("t", np.float32), ("u", np.float32), ("v", np.float32), ("tri", np.int32)])

STRUCT_SIZES = {"RtFrame": 128, "RtLight": 32, "RtMaterial": 48}
assert FRAME_DTYPE.itemsize == STRUCT_SIZES["RtFrame"]
assert LIGHT_DTYPE.itemsize == STRUCT_SIZES["RtLight"]
assert MATERIAL_DTYPE.itemsize == STRUCT_SIZES["RtMaterial"]


def float4_rows(xyz: np.ndarray, w: float | np.ndarray = 0.0) -> np.ndarray:
    """(N, 3) -> (N, 4) float32 with the given w."""
    xyz = np.asarray(xyz, np.float32).reshape(-1, 3)
    out = np.empty((xyz.shape[0], 4), np.float32)
    out[:, :3] = xyz
    out[:, 3] = w
    return out
