"""float64 reference of the simple shading in kernels/shared/rt_shade.h (Lambert from point lights,
constant ambient, no shadows), evaluated on reference hits. Shares no code with the kernels."""
from __future__ import annotations

import numpy as np

from ..scene.materials import AMBIENT, BACKGROUND
from ..scene.model import Scene


def reference_shade(scene: Scene, origins: np.ndarray, directions: np.ndarray, tri: np.ndarray,
                    t: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N, 3) float64 linear colours in [0, 1] (clamped) for rays with the given hits."""
    n_rays = tri.shape[0]
    color = np.tile(np.asarray(BACKGROUND, np.float64), (n_rays, 1))
    hit = tri >= 0
    if not hit.any():
        return color
    o = origins[hit].astype(np.float64)
    d = directions[hit].astype(np.float64)
    ids = tri[hit]
    p = o + d * t[hit, None].astype(np.float64)
    if scene.vertex_normals is not None:
        nv = scene.vertex_normals[scene.faces[ids]].astype(np.float64)        # (H, 3, 3)
        uu, vv = u[hit].astype(np.float64), v[hit].astype(np.float64)
        n = nv[:, 0] * (1 - uu - vv)[:, None] + nv[:, 1] * uu[:, None] + nv[:, 2] * vv[:, None]
    tv = scene.vertices[scene.faces[ids]].astype(np.float64)
    flat = np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0])
    if scene.vertex_normals is None:
        n = flat
    else:       # no direction (a file's "vn 0 0 0", normals that cancel): the flat normal, as rt_shade.h
        n = np.where((np.linalg.norm(n, axis=1) > 0.0)[:, None], n, flat)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n[(n * d).sum(axis=1) > 0] *= -1.0
    kd = np.array([m.diffuse for m in scene.materials], np.float64)[scene.material_ids[ids]]
    c = kd * AMBIENT
    for light in scene.lights:
        l = np.asarray(light.position, np.float64) - p
        l /= np.linalg.norm(l, axis=1, keepdims=True)
        lambert = np.maximum((n * l).sum(axis=1), 0.0)
        c += kd * (np.asarray(light.color, np.float64) * light.intensity) * lambert[:, None]
    color[hit] = c
    return np.clip(color, 0.0, 1.0)


def to_rgb8(color: np.ndarray) -> np.ndarray:
    """Quantise like pack_rgba8(): clamp, scale by 255, round half up."""
    return np.floor(np.clip(color, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
