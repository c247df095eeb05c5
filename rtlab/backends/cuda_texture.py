"""CUDA texture objects over linear device memory, without pycuda (which has no texture-object API).

``create_texture_object(ptr, dtype, channels, count)`` calls the driver's ``cuTexObjectCreate``:
through cuda-python (``cuda.bindings.driver``) when it is installed and works, else through ctypes on
``libcuda.so.1`` with the descriptor structs mirrored below (layout of CUDA 12/13's cuda.h; checked
against the header by tests/test_memory.py where the toolkit is installed). Either way the texture
reads the allocation in place: point sampling, element fetches by integer index (tex1Dfetch), and
integer formats returned as integers (CU_TRSF_READ_AS_INTEGER).
"""
from __future__ import annotations

import ctypes

import numpy as np

from ..errors import BackendError

CU_RESOURCE_TYPE_LINEAR = 0x02
CU_AD_FORMAT_SIGNED_INT32 = 0x0A
CU_AD_FORMAT_FLOAT = 0x20
CU_TRSF_READ_AS_INTEGER = 0x01
CU_TR_FILTER_MODE_POINT = 0
CU_TR_ADDRESS_MODE_CLAMP = 1


class _Linear(ctypes.Structure):
    _fields_ = [("devPtr", ctypes.c_uint64), ("format", ctypes.c_int), ("numChannels", ctypes.c_uint),
                ("sizeInBytes", ctypes.c_size_t)]


class _ResUnion(ctypes.Union):
    _fields_ = [("linear", _Linear), ("reserved", ctypes.c_int * 32)]


class CudaResourceDesc(ctypes.Structure):
    """CUDA_RESOURCE_DESC: 144 bytes; res at 8, flags at 136."""
    _fields_ = [("resType", ctypes.c_int), ("res", _ResUnion), ("flags", ctypes.c_uint)]


class CudaTextureDesc(ctypes.Structure):
    """CUDA_TEXTURE_DESC: 104 bytes; filterMode at 12, flags at 16, borderColor at 40."""
    _fields_ = [("addressMode", ctypes.c_int * 3), ("filterMode", ctypes.c_int), ("flags", ctypes.c_uint),
                ("maxAnisotropy", ctypes.c_uint), ("mipmapFilterMode", ctypes.c_int),
                ("mipmapLevelBias", ctypes.c_float), ("minMipmapLevelClamp", ctypes.c_float),
                ("maxMipmapLevelClamp", ctypes.c_float), ("borderColor", ctypes.c_float * 4),
                ("reserved", ctypes.c_int * 12)]


def texture_format(dtype, channels: int) -> tuple[int, int]:
    """(CUarray_format, texture flags) for ``channels`` x ``dtype`` elements."""
    dtype = np.dtype(dtype)
    if channels not in (1, 2, 4):
        raise BackendError(f"a texture element has 1, 2 or 4 channels, not {channels}")
    if dtype == np.float32:
        return CU_AD_FORMAT_FLOAT, 0
    if dtype == np.int32:
        return CU_AD_FORMAT_SIGNED_INT32, CU_TRSF_READ_AS_INTEGER
    raise BackendError(f"no texture format for {dtype} (float32 or int32)")


def descriptors(ptr: int, dtype, channels: int, count: int) -> tuple[CudaResourceDesc, CudaTextureDesc]:
    fmt, flags = texture_format(dtype, channels)
    res = CudaResourceDesc()
    res.resType = CU_RESOURCE_TYPE_LINEAR
    res.res.linear.devPtr = int(ptr)
    res.res.linear.format = fmt
    res.res.linear.numChannels = channels
    res.res.linear.sizeInBytes = int(count) * channels * np.dtype(dtype).itemsize
    tex = CudaTextureDesc()
    tex.addressMode[0] = tex.addressMode[1] = tex.addressMode[2] = CU_TR_ADDRESS_MODE_CLAMP
    tex.filterMode = CU_TR_FILTER_MODE_POINT
    tex.flags = flags
    return res, tex


_libcuda = None


def _driver():
    global _libcuda
    if _libcuda is None:
        try:
            lib = ctypes.CDLL("libcuda.so.1")
        except OSError as e:
            raise BackendError(f"cannot load libcuda.so.1 for texture objects ({e})") from None
        lib.cuTexObjectCreate.argtypes = [ctypes.POINTER(ctypes.c_uint64), ctypes.POINTER(CudaResourceDesc),
                                          ctypes.POINTER(CudaTextureDesc), ctypes.c_void_p]
        lib.cuTexObjectCreate.restype = ctypes.c_int
        lib.cuTexObjectDestroy.argtypes = [ctypes.c_uint64]
        lib.cuTexObjectDestroy.restype = ctypes.c_int
        lib.cuGetErrorString.argtypes = [ctypes.c_int, ctypes.POINTER(ctypes.c_char_p)]
        lib.cuGetErrorString.restype = ctypes.c_int
        _libcuda = lib
    return _libcuda


def _error_text(lib, code: int) -> str:
    msg = ctypes.c_char_p()
    lib.cuGetErrorString(code, ctypes.byref(msg))
    return f"CUDA error {code}" + (f" ({msg.value.decode()})" if msg.value else "")


def _create_ctypes(ptr: int, dtype, channels: int, count: int):
    lib = _driver()
    res, tex = descriptors(ptr, dtype, channels, count)
    handle = ctypes.c_uint64(0)
    code = lib.cuTexObjectCreate(ctypes.byref(handle), ctypes.byref(res), ctypes.byref(tex), None)
    if code != 0:
        raise BackendError(f"cuTexObjectCreate failed for {count:,} x {channels} x {np.dtype(dtype)}: "
                           f"{_error_text(lib, code)}")
    value = handle.value
    return value, lambda: lib.cuTexObjectDestroy(value)


def _create_cuda_python(ptr: int, dtype, channels: int, count: int):
    """Through cuda-python; None when it is missing or its API differs from the one written here."""
    try:
        from cuda.bindings import driver as cu
    except ImportError:
        try:
            from cuda import cuda as cu  # cuda-python < 12.6
        except ImportError:
            return None
    fmt, flags = texture_format(dtype, channels)
    try:
        res = cu.CUDA_RESOURCE_DESC()
        res.resType = cu.CUresourcetype.CU_RESOURCE_TYPE_LINEAR
        res.res.linear.devPtr = cu.CUdeviceptr(int(ptr))
        res.res.linear.format = cu.CUarray_format(fmt)
        res.res.linear.numChannels = channels
        res.res.linear.sizeInBytes = int(count) * channels * np.dtype(dtype).itemsize
        tex = cu.CUDA_TEXTURE_DESC()
        tex.filterMode = cu.CUfilter_mode.CU_TR_FILTER_MODE_POINT
        tex.flags = flags
        err, handle = cu.cuTexObjectCreate(res, tex, None)
    except (AttributeError, TypeError, ValueError):
        return None
    if err != cu.CUresult.CUDA_SUCCESS:
        raise BackendError(f"cuTexObjectCreate failed for {count:,} x {channels} x {np.dtype(dtype)}: {err}")
    value = int(handle)
    return value, lambda: cu.cuTexObjectDestroy(handle)


def create_texture_object(ptr: int, dtype, channels: int, count: int):
    """(64-bit texture object handle, destroy callable) over ``count`` elements at device address ``ptr``."""
    made = _create_cuda_python(ptr, dtype, channels, count)
    return made if made is not None else _create_ctypes(ptr, dtype, channels, count)
