"""Family 11 of the robustness suite: spawn offsets of secondary and shadow rays, on the glass scene
moved far from the origin and on a large mirror floor at it, rendered against the float64 Whitted
reference (pixels more than PIXEL_OFF/255 off)."""
from __future__ import annotations

import numpy as np

from ..scene.model import Camera, Light, Material, Scene
from .cases import GLASS_BOUNCES, GLASS_OFFSETS, Case, f32, merge_meshes, quads_mesh

def moved_scene(scene: Scene, offset) -> Scene:
    """The scene, its camera and its lights moved by ``offset`` (float64, rounded to float32 once)."""
    off = np.asarray(offset, np.float64)
    cam = scene.camera
    camera = Camera(tuple(np.asarray(cam.eye) + off), tuple(np.asarray(cam.target) + off), cam.up, cam.fov_deg,
                    cam.width, cam.height)
    lights = [Light(tuple(np.asarray(light.position) + off), light.color, light.intensity) for light in scene.lights]
    return Scene(f"{scene.name}_at_{off.max():g}", f32(scene.vertices.astype(np.float64) + off), scene.faces,
                 scene.material_ids, scene.materials, camera, lights, scene.vertex_normals, scene.source)


def mirror_floor_scene(size: int, half: float = 1000.0) -> Scene:
    """Spheres (glass, chrome) and a box on a 2 half-wide floor of two triangles that half-mirrors,
    lit from low and from high: shadow and reflection rays leave points of huge triangles near the
    origin, where a spawn offset below the triangle test's t error shows as acne."""
    import trimesh
    floor = quads_mesh(np.array([[[-half, 0, -half], [-half, 0, half], [half, 0, half], [half, 0, -half]]], float))
    glass = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    glass.apply_translation([0.0, 1.0, 0.0])
    chrome = trimesh.creation.icosphere(subdivisions=3, radius=0.7)
    chrome.apply_translation([1.8, 0.7, -0.5])
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    box.apply_translation([-1.7, 0.5, -0.3])
    parts = [floor, (glass.vertices, glass.faces), (chrome.vertices, chrome.faces), (box.vertices, box.faces)]
    v, f = merge_meshes(parts)
    ids = np.concatenate([np.full(len(p[1]), i) for i, p in enumerate(parts)]).astype(np.int32)
    materials = [Material("floor", diffuse=(0.7, 0.7, 0.7), specular=(0.3, 0.3, 0.3), shininess=30.0, reflectivity=0.5),
                 Material("glass", diffuse=(0.9, 0.95, 1.0), specular=(0.8, 0.8, 0.8), shininess=80.0,
                          transparency=0.9, ior=1.5),
                 Material("chrome", diffuse=(0.7, 0.7, 0.7), reflectivity=0.85),
                 Material("red", diffuse=(0.8, 0.2, 0.2))]
    camera = Camera((0.3, 1.6, 5.5), (0.0, 0.6, 0.0), fov_deg=50.0, width=size, height=size)
    return Scene(f"mirror_floor_{2 * half:g}", f32(v), f.astype(np.int32), ids, materials, camera,
                 [Light((6.0, 0.8, 3.0), intensity=0.9), Light((-5.0, 6.0, 2.0), intensity=0.5)], None, "procedural")


def family_spawn_offsets(size: int, offsets=GLASS_OFFSETS) -> list[Case]:
    """11. The glass scene (a glass sphere and cube, a chrome ball, a checker floor) moved by
    (s, s/2, -s) for s in ``offsets``, and the mirror floor scene at the origin, rendered size x size
    with shadows and GLASS_BOUNCES bounces: pixels more than PIXEL_OFF/255 off the float64 Whitted
    reference."""
    from ..scene.materials import glass_scene
    from ..scene.model import camera_rays
    base = glass_scene(size)
    scenes = [(f"glass scene at {s:g}", moved_scene(base, (s, 0.5 * s, -s))) for s in offsets]
    scenes.append(("mirror floor 2000 wide at the origin", mirror_floor_scene(size)))
    cases = []
    for label, scene in scenes:
        o, d = camera_rays(scene.camera)
        cases.append(Case(11, label, scene, o, d, ("px_off",), render={"bounces": GLASS_BOUNCES}))
    return cases
