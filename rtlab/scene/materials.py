"""Materials for secondary rays: what a scene's MTL means for reflection and refraction, the paper's
Fig. 6 overrides, the shading features a scene needs compiled in, and a small test scene.

The loader reads MTL values as they are (Kd, Ks, Ns, d or Tr as transparency, Ni as index of
refraction) and sets no reflectivity: MTL has no mirror term. The decisions it leaves open are made
here, by name (``MATERIAL_PRESETS``):

``file``
    as loaded: no mirrors; MTL transparency and Ni as given.
``mtl``
    metals mirror: a material with no diffuse colour (Kd = 0) and a specular colour (Ks > 0)
    reflects mean(Ks). This is how BART (the KITCHEN's source; its AFF "fm" lines are kept as
    comments in kitchen.mtl) describes metal, and it gives KITCHEN's metals 0.9/0.8/0.5. Its glass
    comes out of the MTL as is: d 0.15 -> transparency 0.85, Ni 1.55.
``bart``
    the NFF/AFF convention BART was written for: Ks is the mirror fraction of *every* material
    (Haines' NFF: "Ks the specular ... fraction of reflected light"), so KITCHEN's floor (0.5) and
    marble (0.55) mirror too.
``paper``
    overrides in the spirit of the paper's Fig. 6 (the paper does not list its materials):
    SPONZA gets a mirroring floor, glass lower columns and reflecting upper ones; KITCHEN follows
    ``bart``; the default scene gets its chrome and glass spheres (``with_secondary_materials``);
    other scenes fall back to ``mtl``.
``paper-refraction``
    Fig. 6 right, "refraction only": KITCHEN's glass as in its MTL, no mirrors anywhere. Render it
    with ``fresnel="fixed"``, so the only reflection rays left are those of total internal reflection.
``auto``
    ``paper`` for the procedural default scene (it has no MTL), ``mtl`` for files.

A material's reflectivity + transparency is kept at most 1 (the local term gets what is left).
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from rtlab.errors import SceneError
from rtlab.kernel_constants import kernel_constant
from rtlab.scene.model import Camera, Light, Material, Scene

# Children lighter than this are not spawned: RT_MIN_WEIGHT of kernels/shared/rt_whitted.h.
MIN_WEIGHT = float(kernel_constant("RT_MIN_WEIGHT"))
# What every shading model (kernels, float64 references) lights a miss and a surface with: the rgb of
# the background, and the ambient term (the host passes both in RtFrame.background)
BACKGROUND = (0.10, 0.10, 0.12)
AMBIENT = 0.15
# The RT_MAX_DEPTH a scene can need at most (rtlab.device.kernels.SceneFeatures.max_bounces default).
MAX_BOUNCES_CAP = 16
# Relative headroom on the float64 weight bound: float32 products of weights round up by ulps.
WEIGHT_ROUNDING = 1e-5


def _copy(materials: list[Material]) -> list[Material]:
    return [Material(**vars(m)) for m in materials]


def _with_materials(scene: Scene, materials: list[Material]) -> Scene:
    return Scene(**{**vars(scene), "materials": materials})


def _clamp_shares(m: Material) -> Material:
    r = min(max(float(m.reflectivity), 0.0), 1.0)
    t = min(max(float(m.transparency), 0.0), 1.0)
    if r + t > 1.0:
        r = 1.0 - t
    m.reflectivity, m.transparency = r, t
    return m


def is_metal(m: Material) -> bool:
    """No diffuse colour, a specular one: BART's (and many MTL exporters') way to say metal."""
    return max(m.diffuse) <= 0.0 and max(m.specular) > 0.0


def mtl_materials(materials: list[Material], mirror_all_specular: bool = False) -> list[Material]:
    """Reflectivity from Ks for metals (or, NFF style, for every material), clamped shares."""
    out = _copy(materials)
    for m in out:
        if mirror_all_specular or is_metal(m):
            m.reflectivity = float(np.mean(m.specular))
        _clamp_shares(m)
    return out


def _set(materials: list[Material], names: tuple[str, ...], **values) -> None:
    for m in materials:
        if m.name in names:
            for key, value in values.items():
                setattr(m, key, value)


def _paper_sponza(scene: Scene) -> list[Material]:
    mats = mtl_materials(scene.materials)
    _set(mats, ("sp_00_pod",), reflectivity=0.5)                                   # floor
    _set(mats, ("sp_00_stup",), transparency=0.8, ior=1.5, specular=(0.6, 0.6, 0.6), shininess=64.0)
    _set(mats, ("sp_01_stup",), reflectivity=0.6)                                  # upper columns
    return [_clamp_shares(m) for m in mats]


def _paper_kitchen(scene: Scene) -> list[Material]:
    return mtl_materials(scene.materials, mirror_all_specular=True)


def _paper_default(scene: Scene) -> list[Material]:
    from rtlab.scene.procedural import with_secondary_materials
    return with_secondary_materials(scene).materials


def _paper(scene: Scene) -> list[Material]:
    special = {"sponza": _paper_sponza, "kitchen": _paper_kitchen, "default": _paper_default}
    return special.get(scene.name, lambda s: mtl_materials(s.materials))(scene)


def _paper_refraction(scene: Scene) -> list[Material]:
    mats = _copy(scene.materials)
    for m in mats:
        m.reflectivity = 0.0
        _clamp_shares(m)
    return mats


MATERIAL_PRESETS: dict[str, Callable[[Scene], list[Material]]] = {
    "file": lambda s: [_clamp_shares(m) for m in _copy(s.materials)],
    "mtl": lambda s: mtl_materials(s.materials),
    "bart": lambda s: mtl_materials(s.materials, mirror_all_specular=True),
    "paper": _paper,
    "paper-refraction": _paper_refraction,
    "auto": lambda s: _paper(s) if s.source == "procedural" else mtl_materials(s.materials),
}


def apply_materials(scene: Scene, preset: str = "auto") -> Scene:
    """A copy of ``scene`` with the materials of ``preset`` (see the module docstring)."""
    builder = MATERIAL_PRESETS.get(preset)
    if builder is None:
        raise SceneError(f"unknown material preset {preset!r}; choose one of: {', '.join(MATERIAL_PRESETS)}")
    return _with_materials(scene, builder(scene))


# ---- features: what a scene needs compiled in --------------------------------------------------

def used_materials(scene: Scene) -> list[Material]:
    """Materials some triangle refers to."""
    ids = np.unique(np.asarray(scene.material_ids))
    ids = ids[(ids >= 0) & (ids < len(scene.materials))]
    return [scene.materials[i] for i in ids]


def reachable_bounces(materials: list[Material], min_weight: float = MIN_WEIGHT, cap: int = MAX_BOUNCES_CAP) -> int:
    """Deepest level of the kernel tree that can still hold a ray: a child gets at most
    (reflectivity + transparency) of its parent's weight and is not spawned below ``min_weight``."""
    w = max((m.reflectivity + m.transparency for m in materials), default=0.0)
    if w <= 0.0:
        return 0
    w *= 1.0 + WEIGHT_ROUNDING
    if w >= 1.0:
        return cap
    return min(cap, int(math.floor(math.log(min_weight) / math.log(w))))


def shading_features(scene: Scene) -> dict:
    """SceneFeatures fields for shading (rtlab.device.kernels.SceneFeatures): lights present, any material
    that reflects (a mirror; or a transparent one: Fresnel and total internal reflection reflect
    too), any that transmits, and the deepest bounce with weight left."""
    used = used_materials(scene)
    transparent = any(m.transparency > 0.0 for m in used)
    return {
        "has_lights": len(scene.lights) > 0,
        "reflective": transparent or any(m.reflectivity > 0.0 for m in used),
        "transparent": transparent,
        "max_bounces": reachable_bounces(used),
    }


# ---- a small scene for secondary rays ----------------------------------------------------------

GLASS = Material("glass", diffuse=(0.9, 0.95, 1.0), specular=(0.8, 0.8, 0.8), shininess=80.0,
                 transparency=0.9, ior=1.5)


def glass_scene(size: int = 64, lights: int = 1, cube: bool = True, chrome: bool = True) -> Scene:
    """A glass sphere over a checker plane, with a chrome sphere and a glass cube: about 3,300
    triangles, for tests and the float64 reference. The cube shows total internal reflection: a ray
    entering its top face meets a side face beyond the critical angle (41.8 deg for ior 1.5).
    ``lights`` 0 gives a scene without lights; ``cube``/``chrome`` False leave those out."""
    import trimesh

    from rtlab.scene.mesh import smooth_vertex_normals

    materials = [Material("light", diffuse=(0.85, 0.85, 0.8), specular=(0.1, 0.1, 0.1), shininess=16.0),
                 Material("dark", diffuse=(0.2, 0.25, 0.35)),
                 Material(**vars(GLASS)),
                 Material("chrome", diffuse=(0.7, 0.7, 0.72), specular=(0.9, 0.9, 0.9), shininess=120.0,
                          reflectivity=0.85),
                 Material("glass_cube", diffuse=(0.9, 1.0, 0.9), specular=(0.8, 0.8, 0.8), shininess=80.0,
                          transparency=0.85, ior=1.5)]
    parts = []   # (vertices, faces, normals, material ids)
    n, half = 8, 4.0
    xs = np.linspace(-half, half, n + 1)
    gx, gz = np.meshgrid(xs, xs, indexing="xy")
    v = np.stack([gx.ravel(), np.zeros(gx.size), gz.ravel()], 1)
    r, c = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    v00 = (r * (n + 1) + c).ravel()
    f = np.stack([np.stack([v00, v00 + n + 1, v00 + 1], 1), np.stack([v00 + 1, v00 + n + 1, v00 + n + 2], 1)], 1)
    cell = ((r + c) % 2).ravel()
    parts.append((v, f.reshape(-1, 3), np.tile([0.0, 1.0, 0.0], (len(v), 1)), np.repeat(cell, 2)))

    def smooth(mesh, material):
        vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        return vertices, faces, smooth_vertex_normals(vertices, faces), np.full(len(faces), material)

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    sphere.apply_translation([0.0, 1.05, 0.4])
    parts.append(smooth(sphere, 2))
    if chrome:
        ball = trimesh.creation.icosphere(subdivisions=2, radius=0.7)
        ball.apply_translation([1.9, 0.72, -1.3])
        parts.append(smooth(ball, 3))
    if cube:
        box = trimesh.creation.box(extents=[1.2, 1.2, 1.2])
        box.apply_transform(trimesh.transformations.rotation_matrix(np.radians(30.0), [0, 1, 0]))
        box.apply_translation([-1.9, 0.62, -0.9])   # off the plane: no coplanar faces
        faces = np.asarray(box.faces)
        corners = np.asarray(box.vertices)[faces].reshape(-1, 3)   # flat: own vertices per face
        parts.append((corners, np.arange(len(corners)).reshape(-1, 3),
                      np.repeat(np.asarray(box.face_normals), 3, axis=0), np.full(len(faces), 4)))
    offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
    normals = np.concatenate([p[2] for p in parts])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return Scene(
        name="glass",
        vertices=np.concatenate([p[0] for p in parts]).astype(np.float32),
        faces=np.concatenate([p[1] + o for p, o in zip(parts, offsets)]).astype(np.int32),
        material_ids=np.concatenate([p[3] for p in parts]).astype(np.int32),
        materials=materials,
        camera=Camera(eye=(0.4, 3.2, 6.4), target=(0.0, 0.7, -0.2), fov_deg=45.0, width=int(size), height=int(size)),
        lights=[Light(position=(3.0, 6.0, 4.0), intensity=0.9), Light(position=(-4.0, 5.0, 1.0), intensity=0.4)][:lights],
        vertex_normals=normals.astype(np.float32),
        source="procedural",
    )
