"""A scene from numpy arrays or a trimesh in one call: :func:`scene_from_arrays`.

    scene = rtlab.scene_from_arrays(vertices, faces)              # (V, 3) floats, (F, 3) ints
    scene = rtlab.scene_from_arrays(trimesh.load("part.stl"))     # anything with .vertices and .faces
    hits = rtlab.trace(scene, origins, directions)

What trimesh, Embree, Warp and Open3D take, (vertices, faces), is enough: one grey material, a
camera looking at the mesh from above and in front with all of it in view, and a point light above
it are made for you; each can be given instead.
"""
from __future__ import annotations

import warnings

import numpy as np

from ..errors import SceneError
from .mesh import degenerate_mask
from .model import Camera, Light, Material, Scene, ScaleWarning, _array
from .scale import float32_spacing

DEFAULT_MATERIAL = Material("default", diffuse=(0.8, 0.8, 0.8))
VIEW_DIRECTION = np.array([0.35, 0.45, 1.0])    # from the mesh's centre towards the eye: above, right, in front
FOV_DEG = 40.0


def framing_camera_for(vertices: np.ndarray, size: int = 512, fov_deg: float = FOV_DEG) -> Camera:
    """A camera from above, right of and in front of the vertices' box (+Y up) at the distance where
    the box's bounding sphere just fits the vertical field of view."""
    v = np.asarray(vertices, np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre, radius = (lo + hi) / 2.0, max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-30)
    distance = radius / np.sin(np.radians(fov_deg) / 2.0)
    eye = centre + VIEW_DIRECTION / np.linalg.norm(VIEW_DIRECTION) * distance
    return Camera(tuple(map(float, eye)), tuple(map(float, centre)), fov_deg=fov_deg, width=size, height=size)


def light_above(vertices: np.ndarray) -> Light:
    """A white point light above, right of and in front of the vertices' box (rtlab.scene.presets'
    model_light), so the camera sees shading and shadows."""
    from .presets import model_light
    v = np.asarray(vertices, np.float64)
    return model_light(np.stack([v.min(axis=0), v.max(axis=0)]))


def _mesh_arrays(vertices, faces):
    """(vertices, faces) from arrays, or from a mesh object (trimesh) given as ``vertices``."""
    if faces is None:
        if hasattr(vertices, "vertices") and hasattr(vertices, "faces"):
            return np.asarray(vertices.vertices), np.asarray(vertices.faces)
        raise SceneError("scene_from_arrays needs faces: scene_from_arrays(vertices, faces), or a mesh with "
                         ".vertices and .faces (a trimesh.Trimesh)")
    return vertices, faces


def _checked_vertices(vertices, where: str) -> np.ndarray:
    try:
        v = np.asarray(vertices)
    except (TypeError, ValueError) as e:
        raise SceneError(f"{where}: vertices are not an array ({e})") from None
    if v.dtype.kind not in "fiu":
        raise SceneError(f"{where}: vertices must hold real numbers, got dtype {v.dtype}")
    if v.ndim != 2 or v.shape[1] != 3:
        raise SceneError(f"{where}: vertices must have shape (V, 3), got {v.shape}")
    v = v.astype(np.float64)
    bad = np.flatnonzero(~np.isfinite(v).all(axis=1))
    if bad.size:
        raise SceneError(f"{where}: vertex {bad[0]} is {tuple(v[bad[0]].tolist())}: vertices must be finite "
                         f"({bad.size} of {len(v)} are not)")
    # finite here, inf once stored in float32 (the kernels' precision): its triangles would vanish unseen
    beyond = np.flatnonzero((np.abs(v) > np.finfo(np.float32).max).any(axis=1))
    if beyond.size:
        raise SceneError(f"{where}: vertex {beyond[0]} is {tuple(v[beyond[0]].tolist())}: beyond float32's range "
                         f"(3.4e38), in which vertices are stored ({beyond.size} of {len(v)} are)")
    return v


def _collapsed_warning(v64: np.ndarray, faces: np.ndarray, where: str) -> str | None:
    """How many triangles that have an area in the caller's coordinates lose it in float32."""
    from .mesh import degenerate_mask
    f = np.asarray(faces, np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or f.size == 0 or f.min() < 0 or f.max() >= len(v64):
        return None                                 # the Scene's own checks name what is wrong
    before = degenerate_mask(v64, f)
    after = degenerate_mask(v64.astype(np.float32), f)
    lost = np.flatnonzero(after & ~before)
    if lost.size == 0:
        return None
    m = float(np.abs(v64[f[lost]]).max())
    return (f"{where}: {lost.size} of {len(f)} triangles (the first is triangle {lost[0]}) have an area in the "
            f"given coordinates but none once rounded to float32, which the kernels trace (spacing "
            f"{float(float32_spacing(m)):.3g} at {m:.3g} from the origin): rays pass through them. Move the mesh nearer "
            f"the origin or scale it up")


# Why many parameters: the public call's keyword options, each with a default; a call names one or two.
def scene_from_arrays(vertices, faces=None, *, name: str = "mesh", material: Material | None = None,
                      materials: list[Material] | None = None, material_ids=None, vertex_normals=None,
                      camera: Camera | None = None, lights: list[Light] | None = None, size: int = 512) -> Scene:
    """A Scene from a triangle mesh: ``vertices`` (V, 3) real numbers and ``faces`` (F, 3) vertex indices
    (numpy arrays, lists, or a trimesh.Trimesh given alone as ``vertices``), ready for rtlab.trace,
    render and render_whitted.

    Defaults, each replaceable: one grey ``material`` for every face (or ``materials`` with one
    ``material_ids`` entry per face); flat shading (``vertex_normals`` (V, 3) for smooth); a ``size`` x
    ``size`` camera from above, right of and in front of the mesh with all of it in view; one white
    point light above it. Vertices are stored in float32, the kernels' precision: a ScaleWarning says
    so when triangles lose their area in that rounding, and when an object is small for its distance
    from the origin (rtlab.scene.scale). Bad input is a SceneError naming what is wrong."""
    vertices, faces = _mesh_arrays(vertices, faces)
    where = f"scene {name!r}"
    v64 = _checked_vertices(vertices, where)
    if v64.shape[0] == 0:
        raise SceneError(f"{where}: no vertices")
    if materials is None:
        if material_ids is not None:
            raise SceneError(f"{where}: material_ids need the materials they index (materials=[...])")
        materials = [material or DEFAULT_MATERIAL]
    elif material is not None:
        raise SceneError(f"{where}: give material (one for every face) or materials with material_ids, not both")
    f = _array(faces, "i", "faces", where)
    if material_ids is None:
        material_ids = np.zeros(f.shape[0] if f.ndim >= 1 else 0, np.int32)
    collapsed = _collapsed_warning(v64, f, where)
    if collapsed:
        warnings.warn(collapsed, ScaleWarning, stacklevel=2)
    if lights is None:
        lights = [light_above(v64)]
    elif isinstance(lights, (list, tuple)):        # anything else (a Light, a string) is Scene.validate's error
        lights = list(lights)
    scene = Scene(name, v64.astype(np.float32), f, material_ids, list(materials),
                  camera if camera is not None else framing_camera_for(v64, size), lights, vertex_normals, "arrays")
    # in the given coordinates, as the file loader refuses it (one lost in float32 is the ScaleWarning's)
    degenerate = degenerate_mask(v64, scene.faces)
    if degenerate.all():
        raise SceneError(f"{where}: all {len(degenerate)} triangles have zero area (first: triangle 0 = "
                         f"{scene.faces[0].tolist()}); there is nothing to hit")
    return scene
