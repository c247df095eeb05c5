"""Scenes: the model, file loading, presets and the procedural default scene.

The loader and the default scene need trimesh, whose import takes most of a second; they are
imported on first use, so that importing the scene model stays cheap for every other module.
"""
from __future__ import annotations

import importlib

from rtlab.scene.model import Camera, Light, Material, Scene
from rtlab.scene.presets import PRESETS, Preset, bench_camera, bench_view_names, list_scenes

_LAZY = {
    "load_scene": "loader", "load_mesh_file": "loader", "MeshData": "mesh",
    "mesh_warnings": "mesh", "scene_warnings": "mesh", "smooth_vertex_normals": "mesh",
    "default_scene": "procedural", "scene_from_arrays": "arrays",
}

__all__ = ["Camera", "Light", "Material", "Scene", "PRESETS", "Preset", "bench_camera",
           "bench_view_names", "list_scenes", *_LAZY]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value
