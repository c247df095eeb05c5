"""Secondary rays from hits, safely: hit points with their rounding bounds, and origins moved off the
surface to the side the new ray leaves (pbrt-v4's OffsetRayOrigin, Pharr, Jakob & Humphreys, 4th ed.,
sec. 6.8). The same arithmetic as the kernels' own spawns (surface_at, offset_ray_origin and
spawn_origin in kernels/shared/rt_shade.h and rt_whitted.h), in float32 numpy; the bound's constant,
RT_SPAWN_ULPS, is read from rt_shade.h, so the two cannot drift apart.

    hits = rtlab.trace(scene, o, d)
    r = reflect(d, normals)                            # any new directions, one per ray
    o2, d2 = rtlab.spawn_rays(scene, hits, r)          # NaN origins where a ray missed: they miss again
    bounce = rtlab.trace(scene, o2, d2)                # tmin = 0: no hit on the triangle it left

Why not o + t d with a small tmin: t carries the error of t times the ray's length, and a fixed
tmin is too small far from the origin (rays hit the triangle they leave) and too large near small
objects (real hits are lost); the bound here follows the triangle's own coordinates.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import RtlabError
from ..kernel_constants import kernel_constant
from ..scene.model import Scene

F32_UNIT_ROUNDOFF = np.float32(5.9604645e-8)    # 2^-24, as the kernels spell it


def spawn_ulps() -> int:
    """n of gamma(n), the hit point's rounding bound: RT_SPAWN_ULPS of kernels/shared/rt_shade.h."""
    return int(kernel_constant("RT_SPAWN_ULPS"))


@dataclass
class HitPoints:
    """Surface points of hits, as the kernels compute them for shading and spawning."""
    p: np.ndarray         # (N, 3) float32 b0 v0 + b1 v1 + b2 v2 (NaN where the ray missed)
    p_err: np.ndarray     # (N,) float32: every coordinate of p is within p_err of the exact point
    normal: np.ndarray    # (N, 3) float32 unit geometric normal (v1 - v0) x (v2 - v0), not flipped (geometric_normal)
    hit: np.ndarray       # (N,) bool


def position_error(corners: np.ndarray) -> np.ndarray:
    """rt_shade.h's position_error: gamma(RT_SPAWN_ULPS) times each triangle's largest |coordinate|,
    float32. corners: (N, 3, 3) float32 (triangle, vertex, axis)."""
    m = np.abs(corners).max(axis=(1, 2)).astype(np.float32)
    u = np.float32(spawn_ulps()) * F32_UNIT_ROUNDOFF
    return (m * (u / (np.float32(1) - u))).astype(np.float32)


def _hit_arrays(hits, n_faces: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    try:
        tri = np.asarray(hits.tri)
        u, v = np.asarray(hits.u, np.float32), np.asarray(hits.v, np.float32)
    except AttributeError:
        raise RtlabError(f"hits must be what rtlab.trace returns (tri, u, v per ray), got {type(hits).__name__}") from None
    if tri.ndim != 1 or u.shape != tri.shape or v.shape != tri.shape or tri.dtype.kind not in "iu":
        raise RtlabError(f"hits must hold one integer tri and one u, v per ray, got shapes {tri.shape}, {u.shape}, {v.shape}")
    if np.any(tri >= n_faces):
        raise RtlabError(f"hits name triangle {int(tri.max())}, but the scene has {n_faces}: hits of another scene?")
    return tri.astype(np.int64), u, v


def hit_points(scene: Scene, hits) -> HitPoints:
    """Each hit's point on its triangle from the barycentrics u, v (the weights of v1, v2), in float32
    as the kernels' hit_position forms it, with its rounding bound per coordinate (position_error) and
    the triangle's unit geometric normal. A point from the barycentrics lies on the triangle up to a
    few ulps of its coordinates, wherever the ray came from; o + t d would carry t's error times the
    ray's length."""
    from .tracing import require_scene
    tri, u, v = _hit_arrays(hits, require_scene(scene).n_triangles)
    n = tri.shape[0]
    hit = tri >= 0
    p = np.full((n, 3), np.nan, np.float32)
    p_err = np.full(n, np.nan, np.float32)
    normal = np.full((n, 3), np.nan, np.float32)
    if hit.any():
        c = scene.vertices[scene.faces[tri[hit]]]                 # (H, 3, 3) float32
        uh, vh = u[hit, None], v[hit, None]
        w = (np.float32(1) - uh) - vh
        p[hit] = (c[:, 0] * w + c[:, 1] * uh) + c[:, 2] * vh
        p_err[hit] = position_error(c)
        # rt_shade.h's geometric_normal: the cross product in float64 (exact differences and products of
        # the float32 corners, one rounding), normalised in float64, rounded once to float32
        c64 = c.astype(np.float64)
        ng = np.cross(c64[:, 1] - c64[:, 0], c64[:, 2] - c64[:, 0])
        with np.errstate(divide="ignore", invalid="ignore"):
            normal[hit] = (ng * (1.0 / np.sqrt((ng * ng).sum(axis=1)))[:, None]).astype(np.float32)
    return HitPoints(p, p_err, normal, hit)


def offset_ray_origins(p: np.ndarray, p_err: np.ndarray, normal: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """rt_whitted.h's spawn_origin: p moved along the unit normal, turned to the side each direction
    leaves, by p_err (|n_x| + |n_y| + |n_z|), the distance along n that covers p's error box; each
    coordinate then one float further away, so the addition's own rounding cannot pull it back."""
    p = np.asarray(p, np.float32)
    d = np.asarray(directions, np.float32)
    n = np.asarray(normal, np.float32)
    side = np.where(((d * n).sum(axis=1, dtype=np.float32) >= 0)[:, None], n, -n)
    dist = np.asarray(p_err, np.float32) * np.abs(side).sum(axis=1, dtype=np.float32)
    o = (p + side * dist[:, None]).astype(np.float32)
    step = np.where(side > 0, np.float32(np.inf), np.where(side < 0, np.float32(-np.inf), o))
    with np.errstate(invalid="ignore"):
        away = np.nextafter(o, step)
    return np.where(np.isfinite(o), away, o).astype(np.float32)


def spawn_rays(scene: Scene, hits, directions) -> tuple[np.ndarray, np.ndarray]:
    """Rays leaving the hits of :func:`rtlab.trace` in new ``directions`` ((N, 3), one per hit):
    (origins, directions) as float32, origins offset from the hit points as the kernels' shadow,
    reflection and refraction rays are (offset_ray_origins), so ``trace(scene, origins, directions)``
    with tmin = 0 never reports the triangle a ray leaves and loses no real hit beyond a few ulps of
    the triangle's coordinates. Where a ray missed (tri < 0) the origin is NaN: the new ray misses."""
    pts = hit_points(scene, hits)
    d = np.asarray(directions)
    if d.shape != pts.p.shape:
        raise RtlabError(f"directions must have shape {pts.p.shape} (one per hit), got {d.shape}")
    d = d.astype(np.float32)
    o = np.full_like(pts.p, np.nan)
    h = pts.hit
    if h.any():
        o[h] = offset_ray_origins(pts.p[h], pts.p_err[h], pts.normal[h], d[h])
    return o, d
