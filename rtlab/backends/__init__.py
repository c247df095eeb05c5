"""Backends: OpenCL (pyopencl; PoCL or NVIDIA) and CUDA (pycuda, optional), behind one interface.

``get_backend(name, device)``: name "opencl", "cuda" or None/"auto" (``$RTLAB_BACKEND``, else CUDA when
it works, else OpenCL); device by name substring or index (``$RTLAB_DEVICE``; ``$PYOPENCL_CTX`` too).
"""
from __future__ import annotations

from .. import settings
from ..errors import BackendError
from .base import Backend, KernelResources, Program

BACKEND_NAMES = ("opencl", "cuda")
_cache: dict = {}


def get_backend(name: str | None = None, device: str | None = None) -> Backend:
    name = (name or settings.get("RTLAB_BACKEND") or "auto").lower()
    device = device if device is not None else settings.get("RTLAB_DEVICE")
    if name not in BACKEND_NAMES + ("auto",):
        raise BackendError(f"unknown backend '{name}'; choose one of: {', '.join(BACKEND_NAMES)}, auto")
    key = (name, device)
    if key in _cache:
        return _cache[key]
    if name == "auto":
        try:
            backend = get_backend("cuda", device)
        except BackendError:
            backend = get_backend("opencl", device)
    elif name == "cuda":
        from .cuda import CudaBackend
        backend = CudaBackend(device)
    else:
        from .opencl import OpenCLBackend
        backend = OpenCLBackend(device)
    _cache[key] = backend
    return backend


def backend_spec(backend: Backend) -> tuple[str, str | None]:
    """(name, device) that :func:`get_backend` turns back into this backend in another process (a
    child that traces a case which may crash)."""
    for (name, device), cached in _cache.items():
        if cached is backend and name != "auto":
            return name, device
    return backend.name, backend.device_name


def backend_status() -> list[dict]:
    """One row per backend: available or why not, and its devices (for ``rtlab info``)."""
    rows = []
    try:
        from .opencl import list_devices
        devs = list_devices()
        if devs:
            rows += [{"backend": "opencl", "id": f"{pi}:{di}", "platform": f"{p.name.strip()} {p.version.split(',')[0].strip()}",
                      "device": d.name.strip(), "ok": True, "why": ""} for pi, di, p, d in devs]
        else:
            from .opencl import POCL_HINT
            rows.append({"backend": "opencl", "id": "-", "platform": "-", "device": "-", "ok": False, "why": POCL_HINT})
    except BackendError as e:
        rows.append({"backend": "opencl", "id": "-", "platform": "-", "device": "-", "ok": False, "why": str(e)})
    try:
        from .cuda import list_devices as cuda_devices
        rows += [{"backend": "cuda", "id": str(i), "platform": "CUDA", "device": n, "ok": True, "why": ""}
                 for i, n in enumerate(cuda_devices())]
    except BackendError as e:
        rows.append({"backend": "cuda", "id": "-", "platform": "-", "device": "-", "ok": False, "why": str(e)})
    return rows


__all__ = ["Backend", "Program", "KernelResources", "get_backend", "backend_spec", "backend_status", "BACKEND_NAMES"]
