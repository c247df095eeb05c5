"""Host geometry shared by the acceleration structures' tools, their statistics and the inspector:
the slab test of a ray against a box and Moller-Trumbore's triangle test, in numba (callable from
Python too).

The float64 reference (rtlab.reference) keeps its own, deliberately independent implementation of
both: it is what these and the kernels are checked against. Imports nothing from rtlab.
"""
from __future__ import annotations

import numpy as np
from .jit import njit


@njit(cache=True, inline="always")
def slab_interval(o, inv, lo, hi, t0, t1):
    """The part [entry, exit] of the segment [t0, t1] of the ray o + t d inside the box [lo, hi]
    (Kay & Kajiya 1986), with inv = 1/d (inf for a zero component). Empty when entry > exit. A
    zero component keeps the ray in its slab or out of it: (b - o) * inf is +-inf outside the slab,
    and NaN only when o lies on the plane, which constrains nothing (the ray lies in it)."""
    for a in range(3):
        n = (lo[a] - o[a]) * inv[a]
        f = (hi[a] - o[a]) * inv[a]
        if n > f:
            n, f = f, n
        if n == n:
            t0 = max(t0, n)
        if f == f:
            t1 = min(t1, f)
    return t0, t1


@njit(cache=True, inline="always")
def ray_scene_interval(o, d, scene_lo, scene_hi, tmin):
    """A ray's inverse direction (inf for a zero component) and the part [t0, t1] of [tmin, inf)
    inside the scene box; t0 > t1 (empty) for a ray with a non-finite part or a zero direction."""
    inv = np.empty(3)
    if not (np.all(np.isfinite(o)) and np.all(np.isfinite(d)) and d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > 0.0):
        return inv, np.inf, -np.inf
    for a in range(3):
        inv[a] = 1.0 / d[a] if d[a] != 0.0 else np.inf
    t0, t1 = slab_interval(o, inv, scene_lo, scene_hi, tmin, np.inf)
    return inv, t0, t1


@njit(cache=True, inline="always")
def moller_trumbore_t(o, d, v0, v1, v2):
    """t of the ray's hit on the triangle (v0, v1, v2) by Moller & Trumbore 1997 (edges inclusive,
    two-sided), NaN when there is none."""
    e1x, e1y, e1z = v1[0] - v0[0], v1[1] - v0[1], v1[2] - v0[2]
    e2x, e2y, e2z = v2[0] - v0[0], v2[1] - v0[1], v2[2] - v0[2]
    px, py, pz = d[1] * e2z - d[2] * e2y, d[2] * e2x - d[0] * e2z, d[0] * e2y - d[1] * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return np.nan
    inv_det = 1.0 / det
    sx, sy, sz = o[0] - v0[0], o[1] - v0[1], o[2] - v0[2]
    u = (sx * px + sy * py + sz * pz) * inv_det
    if u < 0.0 or u > 1.0:
        return np.nan
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    w = (d[0] * qx + d[1] * qy + d[2] * qz) * inv_det
    if w < 0.0 or u + w > 1.0:
        return np.nan
    return (e2x * qx + e2y * qy + e2z * qz) * inv_det
