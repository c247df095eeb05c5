"""The procedural default scene: needs no file, so ``rtlab render`` works on a fresh machine.

A checkerboard ground of many small quads (so the kd-tree has real work), smooth icospheres in
several materials, a torus and a few boxes; about 57K triangles, one point light, a 1024x1024 camera.
Everything is built from fixed numbers: the scene is identical on every run and machine.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from rtlab.scene.mesh import smooth_vertex_normals
from rtlab.scene.model import Camera, Light, Material, Scene

GROUND_HALF_SIZE = 8.0
GROUND_QUADS_PER_SIDE = 128          # 32,768 ground triangles
QUADS_PER_CHECKER_CELL = 8           # 16 x 16 checker cells

# Reflectivity and transparency stay 0 here; lab steps on secondary rays turn them on for
# "chrome" and "glass" (see with_secondary_materials).
MATERIALS = [
    Material("checker_light", diffuse=(0.85, 0.85, 0.80)),
    Material("checker_dark", diffuse=(0.22, 0.24, 0.28)),
    Material("red", diffuse=(0.80, 0.12, 0.10), specular=(0.3, 0.3, 0.3), shininess=32.0),
    Material("green", diffuse=(0.15, 0.65, 0.20), specular=(0.2, 0.2, 0.2), shininess=16.0),
    Material("blue", diffuse=(0.12, 0.25, 0.80), specular=(0.3, 0.3, 0.3), shininess=32.0),
    Material("chrome", diffuse=(0.75, 0.75, 0.78), specular=(0.9, 0.9, 0.9), shininess=96.0),
    Material("glass", diffuse=(0.85, 0.92, 0.95), specular=(0.9, 0.9, 0.9), shininess=96.0, ior=1.5),
    Material("gold", diffuse=(0.85, 0.62, 0.15), specular=(0.6, 0.5, 0.3), shininess=48.0),
    Material("ivory", diffuse=(0.90, 0.87, 0.78)),
    Material("teal", diffuse=(0.10, 0.55, 0.55)),
]
MATERIAL_ID = {m.name: i for i, m in enumerate(MATERIALS)}


@dataclass
class _Part:
    vertices: np.ndarray      # (V, 3) float64
    faces: np.ndarray         # (F, 3) int64
    normals: np.ndarray       # (V, 3) float64
    material_ids: np.ndarray  # (F,) int32


def _ground() -> _Part:
    n = GROUND_QUADS_PER_SIDE
    coords = np.linspace(-GROUND_HALF_SIZE, GROUND_HALF_SIZE, n + 1)
    xs, zs = np.meshgrid(coords, coords, indexing="xy")
    vertices = np.stack([xs.ravel(), np.zeros(xs.size), zs.ravel()], axis=1)
    row, col = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    v00 = (row * (n + 1) + col).ravel()
    v01, v10, v11 = v00 + 1, v00 + n + 1, v00 + n + 2
    # Counter-clockwise seen from +Y, so the geometric normal points up.
    faces = np.stack([np.stack([v00, v10, v01], 1), np.stack([v01, v10, v11], 1)], 1).reshape(-1, 3)
    cell = (row // QUADS_PER_CHECKER_CELL + col // QUADS_PER_CHECKER_CELL).ravel() % 2
    quad_material = np.where(cell == 0, MATERIAL_ID["checker_light"], MATERIAL_ID["checker_dark"])
    normals = np.tile([0.0, 1.0, 0.0], (len(vertices), 1))
    return _Part(vertices, faces, normals, np.repeat(quad_material, 2).astype(np.int32))


def _smooth_part(mesh: trimesh.Trimesh, material: str) -> _Part:
    # rtlab's own area-weighted normals: trimesh's vertex_normals wants scipy, and without it
    # prints a traceback before falling back
    vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
    return _Part(vertices, faces, smooth_vertex_normals(vertices, faces).astype(np.float64),
                 np.full(len(mesh.faces), MATERIAL_ID[material], np.int32))


def _flat_part(mesh: trimesh.Trimesh, material: str) -> _Part:
    """Every triangle gets its own three vertices, so interpolated normals equal the face normal."""
    faces = np.asarray(mesh.faces, np.int64)
    vertices = np.asarray(mesh.vertices, np.float64)[faces].reshape(-1, 3)
    normals = np.repeat(np.asarray(mesh.face_normals, np.float64), 3, axis=0)
    return _Part(vertices, np.arange(len(vertices)).reshape(-1, 3), normals,
                 np.full(len(faces), MATERIAL_ID[material], np.int32))


def _sphere(centre, radius: float, subdivisions: int, material: str) -> _Part:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    mesh.apply_translation(centre)
    return _smooth_part(mesh, material)


def _torus() -> _Part:
    # Standing on its rim, turned towards the camera, so both the hole and the tube read clearly.
    mesh = trimesh.creation.torus(major_radius=1.0, minor_radius=0.35,
                                  major_sections=64, minor_sections=32)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.radians(-35.0), [0, 1, 0]))
    mesh.apply_translation([3.4, 1.35, -0.6])
    return _smooth_part(mesh, "gold")


def _box(extents, centre, yaw_deg: float, material: str) -> _Part:
    transform = trimesh.transformations.rotation_matrix(np.radians(yaw_deg), [0, 1, 0])
    transform[:3, 3] = centre
    return _flat_part(trimesh.creation.box(extents=extents, transform=transform), material)


def _parts() -> list[_Part]:
    return [
        _ground(),
        _sphere([0.0, 1.5, 0.0], 1.5, 4, "chrome"),
        _sphere([-3.4, 1.0, 0.8], 1.0, 4, "red"),
        _sphere([-1.2, 0.7, 3.2], 0.7, 4, "glass"),
        _sphere([1.7, 0.55, 2.8], 0.55, 3, "blue"),
        _sphere([-3.0, 0.45, 3.5], 0.45, 3, "green"),
        _torus(),
        _box([1.6, 1.6, 1.6], [-2.4, 0.8, -3.2], 25.0, "ivory"),
        _box([1.0, 2.4, 1.0], [2.0, 1.2, -4.2], -15.0, "teal"),
        _box([0.8, 0.8, 0.8], [3.6, 0.4, 2.6], 40.0, "ivory"),
    ]


def default_scene(size: int = 1024) -> Scene:
    """The procedural default scene (about 57K triangles), framed at ``size`` x ``size`` pixels."""
    parts = _parts()
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    vertices = np.concatenate([p.vertices for p in parts]).astype(np.float32)
    faces = np.concatenate([p.faces + off for p, off in zip(parts, offsets)]).astype(np.int32)
    normals = np.concatenate([p.normals for p in parts])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return Scene(
        name="default",
        vertices=vertices,
        faces=faces,
        material_ids=np.concatenate([p.material_ids for p in parts]),
        materials=[Material(**vars(m)) for m in MATERIALS],
        camera=Camera(eye=(0.0, 5.0, 14.0), target=(0.0, 0.8, 0.0), fov_deg=40.0,
                      width=size, height=size),           # unconverted: Camera refuses 2.5 rather than take 2
        lights=[Light(position=(5.0, 9.0, 6.5))],
        vertex_normals=normals.astype(np.float32),
        source="procedural",
    )


def with_secondary_materials(scene: Scene, reflectivity: float = 0.8, transparency: float = 0.9) -> Scene:
    """The default scene with a mirror-like "chrome" sphere and a refracting "glass" sphere
    (for the secondary-ray lab steps); ``scene`` is left unchanged."""
    materials = [Material(**vars(m)) for m in scene.materials]
    for m in materials:
        if m.name == "chrome":
            m.reflectivity = reflectivity
        elif m.name == "glass":
            m.transparency = transparency
    return Scene(**{**vars(scene), "materials": materials})
