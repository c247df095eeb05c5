"""A scene on a device: its acceleration structure and triangle data in the paper's layout (Fig. 2),
uploaded once per backend.

Buffers follow RT_SCENE_PARAMS in kernels/shared/rt_memory.h: nodes, node_data, objects, tris,
tri_data, normals, tri_materials. What a variant needs beyond the kd-tree (ropes, a BVH, data
precomputed for an intersection test) comes from the registries below, built on first use and kept.
Per-frame constants (camera, scene box, lights, materials) go to constant memory.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .accel.kdtree import KdBuildParams, KdTree
from .kernels import SceneFeatures
from .layout import FRAME_DTYPE, LIGHT_DTYPE, MATERIAL_DTYPE
from .scene.model import Camera, Scene

BACKGROUND = (0.10, 0.10, 0.12)
AMBIENT = 0.15
DUMMY_F4 = np.zeros((1, 4), np.float32)


@dataclass
class AccelArrays:
    """What one traversal family reads: nodes (int2), node_data (float4), objects (int)."""
    nodes: np.ndarray
    node_data: np.ndarray
    objects: np.ndarray
    bounds: np.ndarray          # (2, 3) root box
    stack_size: int


# Element type and channels of each RT_SCENE_PARAMS buffer, in order (kernels/shared/rt_memory.h)
SCENE_ELEMENTS = ((np.int32, 2), (np.float32, 4), (np.int32, 1), (np.float32, 4), (np.float32, 4), (np.float32, 4),
                  (np.int32, 1))


def kd_accel(scene, tree) -> AccelArrays:
    return AccelArrays(tree.nodes, DUMMY_F4, tree.objects, tree.bounds, tree.depth + 1)


# traversal name -> builder(scene, kd_tree) -> AccelArrays. Variants that read more than the plain
# kd-tree (ropes, BVH) register theirs; every other traversal reads the kd-tree as built.
ACCEL_BUILDERS: dict[str, Callable] = {}
# intersection test name -> builder(scene) -> (3F or F, 4) float32 precomputed per-triangle data
TRI_DATA_BUILDERS: dict[str, Callable] = {}


def scene_fingerprint(scene: Scene) -> bytes:
    """Digest of what a device upload holds: vertices, faces, material ids and vertex normals
    (dtype, shape and bytes). The device-scene cache is keyed by it, so an edited scene is uploaded
    again. sha1 for speed, not security: about 15 ms for the 871K-triangle dragon."""
    h = hashlib.sha1(usedforsecurity=False)
    for a in (scene.vertices, scene.faces, scene.material_ids, scene.vertex_normals):
        if a is None:
            h.update(b"none|")
            continue
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}|".encode())
        h.update(a.reshape(-1).view(np.uint8))
    return h.digest()


def scene_kdtree(scene: Scene, params: KdBuildParams | None = None, progress=None) -> KdTree:
    """The scene's kd-tree, from the on-disk cache when it was built before."""
    from .accel.cache import load_or_build_kdtree
    tree, _ = load_or_build_kdtree(scene.vertices, scene.faces, params or KdBuildParams(), progress=progress)
    return tree


# A scene whose coordinates stay within this many times its own extent of the origin may use the
# BVH's fused box test (rt_bvh.h, RT_BVH_BOX_FMA). Since issue 13 that test pads o inv by its
# rounding bound, so it keeps every box the exact test keeps, at any distance (family 1's sphere at
# 1.5e5 leaks less with it than with the exact test); far from the origin the pad, 2^-22 |o| / |d|,
# only loosens its culling. The gate stays until that is measured on the GPU.
NEAR_ORIGIN_EXTENTS = 4.0
# ... and whose coordinates times the largest inverse direction (2^64, rt_bvh.h) stay finite in
# float32, so that b inv cannot overflow and b inv - o inv cannot be inf - inf
FUSED_BOX_MAX_COORD = 1e18


def near_origin(scene: Scene) -> bool:
    """Whether the scene lies near the origin compared with its size (NEAR_ORIGIN_EXTENTS) and its
    coordinates are below FUSED_BOX_MAX_COORD."""
    if scene.vertices.size == 0:
        return False
    b = scene.bounds().astype(np.float64)
    extent = float((b[1] - b[0]).max())
    return bool(np.all(np.isfinite(b)) and extent > 0
                and np.abs(b).max() <= min(NEAR_ORIGIN_EXTENTS * extent, FUSED_BOX_MAX_COORD))


def scene_features(scene: Scene, stack_size: int) -> SceneFeatures:
    from .scene.materials import shading_features
    return SceneFeatures(stack_size=stack_size,
                         smooth_normals=scene.vertex_normals is not None,
                         n_lights=max(1, len(scene.lights)),
                         n_materials=max(1, len(scene.materials)),
                         near_origin=near_origin(scene),
                         **shading_features(scene))


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
    buffers: dict                                   # per-scene buffers: tris, normals, tri_materials
    accel: dict = field(default_factory=dict)       # family -> (AccelArrays, [device buffers])
    tri_data: dict = field(default_factory=dict)    # intersection test -> device buffer
    textures: dict = field(default_factory=dict)    # id(buffer) -> (buffer, Texture): texture placement
    counts: dict = field(default_factory=dict)      # id(buffer) -> elements (texture extents)
    max_material_id: int = 0                        # checked against the scene's materials each use

    @classmethod
    def upload(cls, backend, scene: Scene, tree: KdTree | None = None) -> "DeviceScene":
        tree = tree if tree is not None else scene_kdtree(scene)
        arrays = {"tris": triangle_corners(scene), "normals": triangle_normals(scene),
                  "tri_materials": np.ascontiguousarray(scene.material_ids, np.int32)}
        buffers = {name: backend.to_device(a) for name, a in arrays.items()}
        ds = cls(backend, scene, tree, buffers, max_material_id=int(arrays["tri_materials"].max(initial=0)))
        for name, a in arrays.items():
            ds.counts[id(buffers[name])] = len(a)
        return ds

    def _accel(self, traversal: str):
        family = traversal if traversal in ACCEL_BUILDERS else "kd"
        if family not in self.accel:
            arrays = ACCEL_BUILDERS[family](self.scene, self.tree) if family != "kd" else kd_accel(self.scene, self.tree)
            objects = arrays.objects if arrays.objects.size else np.zeros(1, np.int32)
            bufs = [self.backend.to_device(arrays.nodes), self.backend.to_device(arrays.node_data),
                    self.backend.to_device(objects)]
            for buf, a in zip(bufs, (arrays.nodes, arrays.node_data, objects)):
                self.counts[id(buf)] = len(a)
            self.accel[family] = (arrays, bufs)
        return self.accel[family]

    def _tri_data(self, intersection: str):
        if intersection not in self.tri_data:
            builder = TRI_DATA_BUILDERS.get(intersection)
            data = np.ascontiguousarray(builder(self.scene) if builder else DUMMY_F4, np.float32)
            self.tri_data[intersection] = self.backend.to_device(data)
            self.counts[id(self.tri_data[intersection])] = len(data)
        return self.tri_data[intersection]

    def features(self, variant) -> SceneFeatures:
        return scene_features(self.scene, self._accel(variant.traversal)[0].stack_size)

    def scene_args(self, variant) -> list:
        """Buffers in RT_SCENE_PARAMS order for this variant; with the texture placement, textures
        (CUDA) or images (OpenCL) over them, made on first use and kept."""
        _, (nodes, node_data, objects) = self._accel(variant.traversal)
        b = self.buffers
        args = [nodes, node_data, objects, b["tris"], self._tri_data(variant.intersection), b["normals"],
                b["tri_materials"]]
        if variant.node_memory == "texture":
            return [self.texture(buf, dtype, channels).arg for buf, (dtype, channels) in zip(args, SCENE_ELEMENTS)]
        return args

    def texture(self, buffer, dtype, channels):
        """The texture/image over one of this scene's buffers (made once)."""
        entry = self.textures.get(id(buffer))
        if entry is None or entry[0] is not buffer:
            entry = (buffer, self.backend.texture(buffer, dtype, channels, self.counts[id(buffer)]))
            self.textures[id(buffer)] = entry
        return entry[1]

    def set_constants(self, program, camera: Camera | None, variant) -> None:
        bounds = self._accel(variant.traversal)[0].bounds
        program.set_constant("frame", frame_constants(camera, bounds, len(self.scene.lights),
                                                      len(self.scene.materials)))
        program.set_constant("lights", light_constants(self.scene))
        program.set_constant("materials", material_constants(self.scene))


from .accel import tri_data as _tri_data  # noqa: E402,F401  registers TRI_DATA_BUILDERS["wald"], ["plucker"]
from .accel import bvh as _bvh, bvh_packet as _bvh_packet, ropes as _ropes  # noqa: E402,F401  ACCEL_BUILDERS
