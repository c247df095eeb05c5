"""A scene on a device: its kd-tree and triangle data in the paper's layout (Fig. 2), uploaded once.

Buffers follow RT_SCENE_PARAMS in kernels/shared/rt_memory.h: nodes, objects, tris, normals,
tri_materials. Per-frame constants (camera, scene box, lights, materials) go to constant memory.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .accel.kdtree import KdBuildParams, KdTree
from .kernels import SceneFeatures
from .layout import FRAME_DTYPE, LIGHT_DTYPE, MATERIAL_DTYPE
from .scene.model import Camera, Scene

BACKGROUND = (0.10, 0.10, 0.12)
AMBIENT = 0.15


def scene_kdtree(scene: Scene, params: KdBuildParams | None = None, progress=None) -> KdTree:
    """The scene's kd-tree, from the on-disk cache when it was built before."""
    from .accel.cache import load_or_build_kdtree
    tree, _ = load_or_build_kdtree(scene.vertices, scene.faces, params or KdBuildParams(), progress=progress)
    return tree


def scene_features(scene: Scene, tree: KdTree) -> SceneFeatures:
    return SceneFeatures(stack_size=tree.depth + 1,
                         smooth_normals=scene.vertex_normals is not None,
                         n_lights=max(1, len(scene.lights)),
                         n_materials=max(1, len(scene.materials)))


def padded_bounds(bounds: np.ndarray) -> np.ndarray:
    """The root box grown by a few ulps of its coordinates, so float rounding in the slab test
    cannot clip away a hit on the box's faces."""
    b = np.asarray(bounds, np.float64)
    pad = np.abs(b).max() * 2.0 ** -20 + (b[1] - b[0]).max() * 1e-6 + 1e-30
    return np.stack([b[0] - pad, b[1] + pad]).astype(np.float32)


def frame_constants(camera: Camera | None, bounds: np.ndarray, n_lights: int, n_materials: int) -> np.ndarray:
    f = np.zeros(1, FRAME_DTYPE)
    if camera is not None:
        eye, u, v, w = camera.basis()
        f["eye"][0, :3], f["u"][0, :3], f["v"][0, :3], f["w"][0, :3] = eye, u, v, w
        f["width"], f["height"] = camera.width, camera.height
    box = padded_bounds(bounds)
    f["scene_min"][0, :3], f["scene_max"][0, :3] = box[0], box[1]
    f["background"][0] = (*BACKGROUND, AMBIENT)
    f["n_lights"], f["n_materials"] = n_lights, n_materials
    return f


def light_constants(scene: Scene) -> np.ndarray:
    lights = np.zeros(max(1, len(scene.lights)), LIGHT_DTYPE)
    for i, light in enumerate(scene.lights):
        lights["position"][i, :3] = light.position
        lights["color"][i, :3] = np.asarray(light.color, np.float32) * light.intensity
    return lights


def material_constants(scene: Scene) -> np.ndarray:
    mats = np.zeros(max(1, len(scene.materials)), MATERIAL_DTYPE)
    for i, m in enumerate(scene.materials):
        mats["diffuse"][i, :3] = m.diffuse
        mats["specular"][i, :3] = m.specular
        mats["specular"][i, 3] = m.shininess
        mats["reflectivity"][i], mats["transparency"][i], mats["ior"][i] = m.reflectivity, m.transparency, m.ior
    return mats


def triangle_corners(scene: Scene) -> np.ndarray:
    """(3F, 4) float32: three vertices per triangle, w = 0."""
    out = np.zeros((scene.n_triangles, 3, 4), np.float32)
    out[:, :, :3] = scene.vertices[scene.faces]
    return out.reshape(-1, 4)


def triangle_normals(scene: Scene) -> np.ndarray:
    """(3F, 4) float32 vertex normals per triangle corner, or a 1-element dummy for flat shading."""
    if scene.vertex_normals is None:
        return np.zeros((1, 4), np.float32)
    out = np.zeros((scene.n_triangles, 3, 4), np.float32)
    out[:, :, :3] = scene.vertex_normals[scene.faces]
    return out.reshape(-1, 4)


@dataclass
class DeviceScene:
    backend: object
    scene: Scene
    tree: KdTree
    features: SceneFeatures
    buffers: dict

    @classmethod
    def upload(cls, backend, scene: Scene, tree: KdTree | None = None) -> "DeviceScene":
        tree = tree if tree is not None else scene_kdtree(scene)
        buffers = {
            "nodes": backend.to_device(tree.nodes),
            "objects": backend.to_device(tree.objects if tree.objects.size else np.zeros(1, np.int32)),
            "tris": backend.to_device(triangle_corners(scene)),
            "normals": backend.to_device(triangle_normals(scene)),
            "tri_materials": backend.to_device(np.ascontiguousarray(scene.material_ids, np.int32)),
        }
        return cls(backend, scene, tree, scene_features(scene, tree), buffers)

    def scene_args(self) -> list:
        """Buffers in RT_SCENE_PARAMS order."""
        b = self.buffers
        return [b["nodes"], b["objects"], b["tris"], b["normals"], b["tri_materials"]]

    def set_constants(self, program, camera: Camera | None) -> None:
        program.set_constant("frame", frame_constants(camera, self.tree.bounds, len(self.scene.lights),
                                                      len(self.scene.materials)))
        program.set_constant("lights", light_constants(self.scene))
        program.set_constant("materials", material_constants(self.scene))
