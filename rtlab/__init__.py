"""rtlab: a GPU ray-tracing teaching lab reproducing "Real-Time Ray Tracing with CUDA"
(Shih, Chiu, Chen, Chang, ICA3PP 2009), with CUDA and OpenCL kernels from one source.

    import rtlab
    scene = rtlab.load_scene("bunny")                   # or rtlab.scene_from_arrays(vertices, faces)
    hits = rtlab.trace(scene, origins, directions, backend="opencl")
    o2, d2 = rtlab.spawn_rays(scene, hits, new_directions)   # secondary rays off the hits
    result = rtlab.render(scene, size=256)
"""
from .errors import RtlabError

__version__ = "0.1.0"


def __getattr__(name):
    # Lazy: importing rtlab is cheap and changes nothing in the process (no numba, trimesh, pyopencl,
    # kernel headers or cache folders until needed; tests/test_architecture.py checks)
    if name in ("load_scene", "list_scenes", "scene_from_arrays"):
        from . import scene
        return getattr(scene, name)
    if name in ("spawn_rays", "hit_points"):
        from .device import spawn
        return getattr(spawn, name)
    if name == "trace":
        from .device.tracing import trace
        return trace
    if name == "camera_rays":
        from .scene.model import camera_rays
        return camera_rays
    if name == "render":
        from .device.rendering import render
        return render
    if name == "Variant":
        from .device.kernels import Variant
        return Variant
    if name == "get_backend":
        from .backends import get_backend
        return get_backend
    raise AttributeError(name)


__all__ = ["RtlabError", "Variant", "load_scene", "list_scenes", "scene_from_arrays", "trace", "spawn_rays",
           "hit_points", "camera_rays", "render", "get_backend"]
