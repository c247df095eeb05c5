"""Whether float32 can hold a scene's objects where they are: the scale warnings.

The kernels trace float32 coordinates. Far from the origin float32's spacing grows (8 at 1e8), and a
secondary ray leaves a surface at a distance that grows with it: the spawn offset, gamma(RT_SPAWN_ULPS)
times the triangle's largest |coordinate| along each axis of the normal (rt_shade.h's position_error,
rtlab.device.spawn). An object is warned about when that offset exceeds SPAWN_OFFSET_FRACTION of
its size (a unit box at 1e6 is left 0.7 units away: reflections off the floor it stands on miss it),
and the warning counts its triangles that rounding to float32 has collapsed to zero area (a unit
object at 1e8). An object is a set of triangles joined by shared corners: vertices at the same float32
position count as one (flat-shaded and STL meshes repeat them per face).
"""
from __future__ import annotations

import numpy as np

from ..kernel_constants import kernel_constant

# An object whose spawn offset exceeds this share of its size is warned about
SPAWN_OFFSET_FRACTION = 0.01
MAX_OBJECT_WARNINGS = 1           # the worst objects named; the rest counted, in the same message
_F32_EPS = float(np.finfo(np.float32).eps)   # spacing of float32 at 1: 2^-23


def spawn_offset(magnitude) -> np.ndarray:
    """Largest distance a spawned ray's origin is moved off a surface whose coordinates reach
    ``magnitude``: gamma(RT_SPAWN_ULPS) magnitude times sqrt(3), the largest |n_x| + |n_y| + |n_z| of a
    unit normal (rt_whitted.h's offset_ray_origin)."""
    u = float(kernel_constant("RT_SPAWN_ULPS")) * 2.0 ** -24
    return np.asarray(magnitude, np.float64) * (u / (1.0 - u)) * np.sqrt(3.0)


def float32_spacing(magnitude) -> np.ndarray:
    """Distance between neighbouring float32 values near ``magnitude`` (an upper bound: the binade's)."""
    m = np.asarray(magnitude, np.float64)
    return np.where(m > 0, 2.0 ** np.floor(np.log2(np.maximum(m, 1e-300))) * _F32_EPS, 0.0)


def vertex_components(n_vertices: int, faces: np.ndarray) -> np.ndarray:
    """(V,) component label of each vertex (the smallest vertex index of its component): hooking of
    roots along the triangles' edges and full path compression (Shiloach & Vishkin), all in numpy."""
    parent = np.arange(n_vertices)
    f = np.asarray(faces, np.int64)
    a = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    b = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    while True:
        ra, rb = parent[a], parent[b]
        differ = ra != rb
        if not differ.any():
            return parent
        np.minimum.at(parent, np.maximum(ra[differ], rb[differ]), np.minimum(ra[differ], rb[differ]))
        while True:
            grand = parent[parent]
            if np.array_equal(grand, parent):
                break
            parent = grand


def object_scale_warnings(vertices: np.ndarray, faces: np.ndarray, where: str) -> list[str]:
    """One message for the objects whose spawn offset exceeds SPAWN_OFFSET_FRACTION of their size (the
    worst MAX_OBJECT_WARNINGS named with their numbers, the rest counted in it: a scene warns once). Cheap for scenes without
    such objects: components are only formed when some triangle is smaller than the largest offset
    allows."""
    v = np.asarray(vertices, np.float32).astype(np.float64)
    f = np.asarray(faces, np.int64)
    finite = np.isfinite(v).all(axis=1)
    if f.size == 0 or not finite.any():
        return []
    corners = v[f]                                                   # (F, 3, 3)
    ok = np.isfinite(corners).all(axis=(1, 2))
    tri_size = np.zeros(len(f))
    tri_size[ok] = np.linalg.norm(corners[ok].max(axis=1) - corners[ok].min(axis=1), axis=1)
    limit = spawn_offset(np.abs(v[finite]).max()) / SPAWN_OFFSET_FRACTION
    if not np.any(ok & (tri_size < limit)):
        return []
    _, at = np.unique(np.asarray(vertices, np.float32), axis=0, return_inverse=True)   # weld by position
    welded = at.reshape(-1)[f]
    label = vertex_components(int(welded.max()) + 1, welded)[welded[:, 0]]   # component of each triangle
    objects, tri_object = np.unique(label[ok], return_inverse=True)
    fo = f[ok]
    n_obj = len(objects)
    lo = np.full((n_obj, 3), np.inf)
    hi = np.full((n_obj, 3), -np.inf)
    c = corners[ok]
    np.minimum.at(lo, tri_object, c.min(axis=1))
    np.maximum.at(hi, tri_object, c.max(axis=1))
    size = np.linalg.norm(hi - lo, axis=1)
    magnitude = np.maximum(np.abs(lo), np.abs(hi)).max(axis=1)
    offset = spawn_offset(magnitude)
    flagged = np.flatnonzero(offset > SPAWN_OFFSET_FRACTION * size)
    if flagged.size == 0:
        return []
    from .mesh import degenerate_mask
    zero_area = degenerate_mask(v, fo)
    n_tris = np.bincount(tri_object, minlength=n_obj)
    n_zero = np.bincount(tri_object, weights=zero_area, minlength=n_obj).astype(int)
    first_tri = np.full(n_obj, len(f))
    np.minimum.at(first_tri, tri_object, np.flatnonzero(ok))
    with np.errstate(divide="ignore"):
        ratio = np.where(size > 0, offset / np.where(size > 0, size, 1.0), np.inf)
    worst = flagged[np.argsort(-ratio[flagged], kind="stable")]
    out = []
    for k in worst[:MAX_OBJECT_WARNINGS]:
        share = "more than its size" if not np.isfinite(ratio[k]) or ratio[k] >= 1 else f"{100 * ratio[k]:.2g} % of its size"
        text = (f"{where}: an object of {n_tris[k]} triangle{'s' if n_tris[k] > 1 else ''} (the first is triangle "
                f"{first_tri[k]}), {size[k]:.3g} across, "
                f"reaches {magnitude[k]:.3g} from the origin, where float32 spacing is {float(float32_spacing(magnitude[k])):.3g}: "
                f"a ray leaving it starts up to {offset[k]:.3g} off its surface ({share}; more than "
                f"{100 * SPAWN_OFFSET_FRACTION:g} % is warned), so shadow and reflection rays near it can miss it")
        if n_zero[k]:
            text += f"; {n_zero[k]} of its {n_tris[k]} triangles have collapsed to zero area in float32"
        out.append(text)
    if flagged.size > MAX_OBJECT_WARNINGS:
        out.append(f"{flagged.size - MAX_OBJECT_WARNINGS} more objects are as small for their distance from the origin")
    return ["; ".join(out) + ". Move the scene nearer the origin or scale it up"]
