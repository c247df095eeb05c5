"""The float64 reference's triangle test: the watertight test of Woop, Benthin & Wald, "Watertight
Ray/Triangle Intersection", JCGT 2(1), 2013, in float64 (rtlab.reference.tracer's contract), as numpy
over arrays and as numba over one triangle. Both do the same float operations in the same order, so
the BVH tracer and brute force give bit-identical t. The edge functions decide whether a ray hits;
t is the distance to the triangle's plane (:func:`plane_t_numpy`), not Woop's scaled barycentrics,
whose rounding grows with the triangle's depth range along the ray (slivers seen at grazing angles).
Which triangles can be hit at all is :func:`usable_triangle_mask`'s decision.

Why many parameters: numba's compiled functions take arrays and scalars one by one (no objects in
nopython mode), so a step's inputs are its parameters.
"""
from __future__ import annotations

import math

import numpy as np
from ..jit import njit

UNIT_ROUNDOFF = 2.0 ** -53


def mesh_f64(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """The float32 scene values promoted to float64, and faces as int64, validated."""
    v32 = np.asarray(vertices, dtype=np.float32)
    f = np.asarray(faces)
    if v32.ndim != 2 or v32.shape[1] != 3:
        raise ValueError(f"vertices must be (V, 3), got {v32.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must be (F, 3), got {f.shape}")
    f = f.astype(np.int64, copy=False)
    if f.size and (f.min() < 0 or f.max() >= v32.shape[0]):
        raise ValueError("faces index outside vertices")
    return v32.astype(np.float64), f


def usable_triangle_mask(v0: np.ndarray, v1: np.ndarray, v2: np.ndarray) -> np.ndarray:
    """(F,) bool: corners finite and area certainly non-zero.

    The normal (v1-v0) x (v2-v0) is computed in float64 with a forward error bound per component
    (a Shewchuk-style filter: two differences, two products and a subtraction, each rounding once,
    stay below 8 u (|a b| + |c d|)). A triangle is usable when some component exceeds its bound,
    i.e. its exact area is provably non-zero. Exactly collinear or repeated corners always fail;
    so do slivers thinner than float64 can resolve, which no test could hit reliably anyway.
    """
    finite = np.isfinite(v0).all(1) & np.isfinite(v1).all(1) & np.isfinite(v2).all(1)
    with np.errstate(invalid="ignore", over="ignore"):
        e1 = v1 - v0
        e2 = v2 - v0
        usable = np.zeros(v0.shape[0], dtype=bool)
        for a, b in ((1, 2), (2, 0), (0, 1)):
            p = e1[:, a] * e2[:, b]
            q = e1[:, b] * e2[:, a]
            bound = 8.0 * UNIT_ROUNDOFF * (np.abs(p) + np.abs(q))
            usable |= np.abs(p - q) > bound
    return usable & finite


def ray_shear_numpy(d: np.ndarray):
    """Woop 2013 section 3: axis permutation (kx, ky, kz) and shear (sx, sy, sz) per ray."""
    absd = np.abs(d)
    # first maximum wins, like the strict '>' chain in ray_shear below
    kz = np.where(absd[:, 1] > absd[:, 0], 1, 0)
    kz = np.where(absd[:, 2] > absd[np.arange(d.shape[0]), kz], 2, kz)
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    dz = d[np.arange(d.shape[0]), kz]
    flip = dz < 0.0  # keep the winding; irrelevant for two-sided hits but matches the paper
    kx, ky = np.where(flip, ky, kx), np.where(flip, kx, ky)
    with np.errstate(divide="ignore", invalid="ignore"):
        sx = d[np.arange(d.shape[0]), kx] / dz
        sy = d[np.arange(d.shape[0]), ky] / dz
        sz = 1.0 / dz
    valid = np.isfinite(d).all(1) & np.isfinite(sx) & np.isfinite(sy) & np.isfinite(sz)
    return valid, kx, ky, kz, sx, sy, sz


def _lex_less(p, q):
    """p < q in lexicographic order of their (x, y, z), elementwise over (..., 3) arrays."""
    return (p[..., 0] < q[..., 0]) | ((p[..., 0] == q[..., 0]) & (
        (p[..., 1] < q[..., 1]) | ((p[..., 1] == q[..., 1]) & (p[..., 2] < q[..., 2]))))


def canonical_corners(a, b, c):
    """The corners in the cyclic order that starts at the lexicographically least: the plane's t is
    then a function of the triangle's corners, not of which one the mesh lists first, so two copies of
    a triangle (rotated or reversed) get the same t to the bit and the tie rule (the lower id at equal
    t) decides between them. A rotation keeps the winding; a reversed copy flips n, and n.a / n.d with
    it, exactly."""
    b_first = _lex_less(b, a) & _lex_less(b, c)
    c_first = _lex_less(c, a) & _lex_less(c, b)
    pick = lambda x, y, z: np.where(b_first[..., None], y, np.where(c_first[..., None], z, x))  # noqa: E731
    return pick(a, b, c), pick(b, c, a), pick(c, a, b)


def plane_t_numpy(a, b, c, d):
    """Distance along d from the origin to the plane of the corner-minus-origin points a, b, c:
    n.a / n.d with n = (b - a) x (c - a), from the corners in their canonical order
    (:func:`canonical_corners`). The float32 scene's differences are exact in float64, so n
    is exact but for a rounding a component and t errs by a few float64 ulps over the cosine of the
    incidence angle, whatever the triangle's shape (the kernels' plane_t_fp64, rt_intersect.h)."""
    a, b, c = canonical_corners(np.asarray(a), np.asarray(b), np.asarray(c))
    e1x, e1y, e1z = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1], b[..., 2] - a[..., 2]
    e2x, e2y, e2z = c[..., 0] - a[..., 0], c[..., 1] - a[..., 1], c[..., 2] - a[..., 2]
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    num = nx * a[..., 0] + ny * a[..., 1] + nz * a[..., 2]
    den = nx * d[..., 0] + ny * d[..., 1] + nz * d[..., 2]
    return num / den


# Why many parameters: vertex and ray components apart, as its numba twin woop_hit takes them.
def woop_numpy(a, b, c, d, kx, ky, kz, sx, sy, sz):
    """Woop's watertight test on corner-minus-origin arrays a, b, c of shape (..., 3) and the ray
    directions d (broadcast against them).

    kx..sz broadcast against a[..., 0]. Returns (t, b0, b1, b2, inside): t (plane_t_numpy) and the
    barycentric weights of v0, v1, v2 (garbage where not inside), and inside = edge functions of one
    sign with a non-zero determinant (edges inclusive).
    """
    def pick(x, k):
        return np.take_along_axis(x, np.broadcast_to(k, x.shape[:-1])[..., None], -1)[..., 0]

    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        akx, aky, akz = pick(a, kx), pick(a, ky), pick(a, kz)
        bkx, bky, bkz = pick(b, kx), pick(b, ky), pick(b, kz)
        ckx, cky, ckz = pick(c, kx), pick(c, ky), pick(c, kz)
        ax = akx - sx * akz
        ay = aky - sy * akz
        bx = bkx - sx * bkz
        by = bky - sy * bkz
        cx = ckx - sx * ckz
        cy = cky - sy * ckz
        eu = cx * by - cy * bx
        ev = ax * cy - ay * cx
        ew = bx * ay - by * ax
        # one sign, zeros included (a NaN, from products beyond double's range, has none)
        one_sign = ((eu >= 0) & (ev >= 0) & (ew >= 0)) | ((eu <= 0) & (ev <= 0) & (ew <= 0))
        det = eu + ev + ew
        inside = one_sign & (det != 0.0)
        t = plane_t_numpy(a, b, c, d)
        return t, eu / det, ev / det, ew / det, inside


@njit(cache=True, inline="always")
def ray_shear(dx, dy, dz):
    """Woop 2013 section 3, scalar: (valid, kx, ky, kz, sx, sy, sz)."""
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    kz = 0
    m = ax
    if ay > m:
        kz = 1
        m = ay
    if az > m:
        kz = 2
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    d = (dx, dy, dz)
    dkz = d[kz]
    if dkz < 0.0:
        kx, ky = ky, kx
    if dkz == 0.0 or not (math.isfinite(dx) and math.isfinite(dy) and math.isfinite(dz)):
        return False, kx, ky, kz, 0.0, 0.0, 0.0
    sx = d[kx] / dkz
    sy = d[ky] / dkz
    sz = 1.0 / dkz
    valid = math.isfinite(sx) and math.isfinite(sy) and math.isfinite(sz)
    return valid, kx, ky, kz, sx, sy, sz


@njit(cache=True, inline="always")
def _lex_less3(px, py, pz, qx, qy, qz):
    """(px, py, pz) < (qx, qy, qz) lexicographically (_lex_less)."""
    return px < qx or (px == qx and (py < qy or (py == qy and pz < qz)))


@njit(cache=True, inline="always")
def plane_t(tv, j, ox, oy, oz, dx, dy, dz):
    """plane_t_numpy on triangle row j of tv, the same operations in the same order. A ray parallel to
    the plane (that the rounded shear let through the edges) gets NaN, a miss, where plane_t_numpy
    divides by zero to inf or NaN, a miss too (numba's division would raise)."""
    ax, ay, az = tv[j, 0] - ox, tv[j, 1] - oy, tv[j, 2] - oz
    bx, by, bz = tv[j, 3] - ox, tv[j, 4] - oy, tv[j, 5] - oz
    cx, cy, cz = tv[j, 6] - ox, tv[j, 7] - oy, tv[j, 8] - oz
    # canonical_corners: the least corner first, the cyclic order kept
    if _lex_less3(bx, by, bz, ax, ay, az) and _lex_less3(bx, by, bz, cx, cy, cz):
        ax, ay, az, bx, by, bz, cx, cy, cz = bx, by, bz, cx, cy, cz, ax, ay, az
    elif _lex_less3(cx, cy, cz, ax, ay, az) and _lex_less3(cx, cy, cz, bx, by, bz):
        ax, ay, az, bx, by, bz, cx, cy, cz = cx, cy, cz, ax, ay, az, bx, by, bz
    e1x, e1y, e1z = bx - ax, by - ay, bz - az
    e2x, e2y, e2z = cx - ax, cy - ay, cz - az
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    num = nx * ax + ny * ay + nz * az
    den = nx * dx + ny * dy + nz * dz
    if den == 0.0:
        return math.nan
    return num / den


@njit(cache=True, inline="always")
def woop_hit(tv, j, ox, oy, oz, dx, dy, dz, kx, ky, kz, sx, sy, sz):
    """Woop 2013 on triangle row j of tv (v0xyz v1xyz v2xyz) -> (inside, t, u, v).

    Same operations in the same order as woop_numpy: the brute-force check compares bit for bit.
    """
    o = (ox, oy, oz)
    akx = tv[j, kx] - o[kx]
    aky = tv[j, ky] - o[ky]
    akz = tv[j, kz] - o[kz]
    bkx = tv[j, 3 + kx] - o[kx]
    bky = tv[j, 3 + ky] - o[ky]
    bkz = tv[j, 3 + kz] - o[kz]
    ckx = tv[j, 6 + kx] - o[kx]
    cky = tv[j, 6 + ky] - o[ky]
    ckz = tv[j, 6 + kz] - o[kz]
    ax = akx - sx * akz
    ay = aky - sy * akz
    bx = bkx - sx * bkz
    by = bky - sy * bkz
    cx = ckx - sx * ckz
    cy = cky - sy * ckz
    # edge functions: each uses only the two corners of its edge, so a neighbour sharing the edge
    # computes exactly the negated value (the watertightness argument of Woop 2013)
    eu = cx * by - cy * bx
    ev = ax * cy - ay * cx
    ew = bx * ay - by * ax
    if not ((eu >= 0.0 and ev >= 0.0 and ew >= 0.0) or (eu <= 0.0 and ev <= 0.0 and ew <= 0.0)):
        return False, 0.0, 0.0, 0.0
    det = eu + ev + ew
    if det == 0.0:
        return False, 0.0, 0.0, 0.0
    return True, plane_t(tv, j, ox, oy, oz, dx, dy, dz), ev / det, ew / det
