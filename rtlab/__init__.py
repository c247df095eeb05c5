"""rtlab: a GPU ray-tracing teaching lab reproducing "Real-Time Ray Tracing with CUDA"
(Shih, Chiu, Chen, Chang, ICA3PP 2009), with CUDA and OpenCL kernels from one source.

    import rtlab
    scene = rtlab.load_scene("bunny")
    hits = rtlab.trace(scene, origins, directions, backend="opencl")
    result = rtlab.render(scene, size=256)
"""
from .errors import RtlabError
from .kernels import Variant

__version__ = "0.1.0"


def __getattr__(name):
    # Lazy: importing rtlab stays cheap (no numba, trimesh or pyopencl until needed)
    if name in ("load_scene", "list_scenes"):
        from . import scene
        return getattr(scene, name)
    if name in ("trace", "camera_rays"):
        from . import tracing
        return getattr(tracing, name)
    if name == "render":
        from .rendering import render
        return render
    if name == "get_backend":
        from .backends import get_backend
        return get_backend
    raise AttributeError(name)


__all__ = ["RtlabError", "Variant", "load_scene", "list_scenes", "trace", "camera_rays", "render", "get_backend"]
