"""Per-triangle data precomputed on the host for the intersection tests of the paper's Table 3.

Layouts (sync with ``TriWald`` / ``TriPlucker`` in kernels/shared/rt_intersect.h), float4 rows per
triangle, uploaded as the ``tri_data`` buffer:

* ``wald`` (Wald 2004, PhD thesis §7.1.3, "TriAccel"), 3 rows = 48 bytes:
  ``(n_u, n_v, n_d, k bits)``, ``(eu_u, eu_v, eu_d, 0)``, ``(ev_u, ev_v, ev_d, 0)``.
  k is the dominant axis of the normal N = (v1 - v0) x (v2 - v0), (ku, kv) = (k+1, k+2) mod 3;
  the plane is p_k + n_u p_ku + n_v p_kv = n_d; the barycentric weight of v1 at a point (hu, hv)
  projected along k is u = eu_u hu + eu_v hv + eu_d, that of v2 likewise with ev.
* ``plucker`` (Erickson 1997, Shoemake 1998), 6 rows = 96 bytes: per edge v0->v1, v1->v2, v2->v0
  a row with its direction b - a and a row with its moment a x b; the w lanes of the first three
  rows hold the normal N, that of the fourth N . v0.

Everything is computed in float64 from the float32 vertices, then rounded once to float32. The two
triangles of a shared edge then store exactly negated Plücker coordinates (the float64 products
of float32 inputs are exact, and rounding is symmetric). Triangles the float64 reference cannot
hit (non-finite corners, zero area: :func:`rtlab.reference.usable_triangle_mask`), and those whose
data overflow float32, are stored as NaN, which every test rejects.

The data are a few vectorised numpy passes: measured 0.5-0.8 s per million triangles on the 2-core
CI machine (DRAGON: well under a second, against tens of seconds for its kd-tree), so they are
computed on upload, once per scene and device, rather than cached on disk with the tree.
"""
from __future__ import annotations

import numpy as np

from ..errors import VariantError
from ..kernel_constants import kernel_constant

WALD_ROWS = int(kernel_constant("RT_WALD_ROWS"))
PLUCKER_ROWS = int(kernel_constant("RT_PLUCKER_ROWS"))
_F4_BYTES = 16

# Bytes each test reads per triangle, and what it adds to the scene's memory. Möller–Trumbore and
# the watertight test read the three vertices (float4 rows, 36 of 48 bytes used) that the scene
# keeps anyway for shading; Wald and Plücker read only their own data.
_PRECOMPUTED_BYTES = {"moller": 0, "wald": WALD_ROWS * _F4_BYTES, "plucker": PLUCKER_ROWS * _F4_BYTES,
                      "watertight": 0}
_READ_BYTES = {"moller": 3 * _F4_BYTES, "wald": WALD_ROWS * _F4_BYTES,
               "plucker": PLUCKER_ROWS * _F4_BYTES, "watertight": 3 * _F4_BYTES}


def _check_test(test: str) -> None:
    if test not in _PRECOMPUTED_BYTES:
        raise VariantError(f"unknown intersection test '{test}'; choose one of: {', '.join(_PRECOMPUTED_BYTES)}")


def tri_data_bytes(test: str) -> int:
    """Bytes of precomputed data per triangle that ``test`` needs on top of the vertices."""
    _check_test(test)
    return _PRECOMPUTED_BYTES[test]


def tri_bytes_read(test: str) -> int:
    """Bytes ``test`` loads from device memory for one ray/triangle test."""
    _check_test(test)
    return _READ_BYTES[test]


def _corners_f64(vertices, faces):
    v = np.asarray(vertices, np.float32).astype(np.float64)
    f = np.asarray(faces, np.int64)
    return v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]


def _usable(v0, v1, v2) -> np.ndarray:
    from ..reference import usable_triangle_mask
    return usable_triangle_mask(v0, v1, v2)


def _to_f32_rows(data: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """(F, R, 4) float64 -> (F*R, 4) float32; unusable or overflowing triangles become NaN."""
    with np.errstate(over="ignore", invalid="ignore"):
        out = data.astype(np.float32)
    finite = np.isfinite(out).all(axis=(1, 2))
    out[~(usable & finite)] = np.nan
    return out.reshape(-1, 4)


def wald_tri_data(vertices, faces) -> np.ndarray:
    """(3F, 4) float32 TriAccel rows (layout in the module docstring)."""
    a, b, c = _corners_f64(vertices, faces)
    n_tris = a.shape[0]
    usable = _usable(a, b, c)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        e1, e2 = b - a, c - a                     # v1 - v0, v2 - v0
        normal = np.cross(e1, e2)
        k = np.argmax(np.abs(normal), axis=1)
        # columns in the order (k, ku, kv), ku = k + 1, kv = k + 2 (mod 3)
        order = (k[:, None] + np.arange(3)[None, :]) % 3
        n, e1, e2, a = (np.take_along_axis(x, order, axis=1) for x in (normal, e1, e2, a))
        inv_nk = 1.0 / n[:, 0]                    # N_k = e1_u e2_v - e1_v e2_u: also the 2D determinant
        data = np.zeros((n_tris, WALD_ROWS, 4))
        data[:, 0, 0] = n[:, 1] * inv_nk
        data[:, 0, 1] = n[:, 2] * inv_nk
        data[:, 0, 2] = (n[:, 0] * a[:, 0] + n[:, 1] * a[:, 1] + n[:, 2] * a[:, 2]) * inv_nk
        # Solve (hu - a_u, hv - a_v) = u e1 + v e2 in the projection plane
        data[:, 1, 0] = e2[:, 2] * inv_nk
        data[:, 1, 1] = -e2[:, 1] * inv_nk
        data[:, 1, 2] = (a[:, 2] * e2[:, 1] - a[:, 1] * e2[:, 2]) * inv_nk
        data[:, 2, 0] = -e1[:, 2] * inv_nk
        data[:, 2, 1] = e1[:, 1] * inv_nk
        data[:, 2, 2] = (a[:, 1] * e1[:, 2] - a[:, 2] * e1[:, 1]) * inv_nk
    out = _to_f32_rows(data, usable)
    out.reshape(n_tris, WALD_ROWS, 4)[:, 0, 3] = k.astype(np.int32).view(np.float32)
    return out


def plucker_tri_data(vertices, faces) -> np.ndarray:
    """(6F, 4) float32 Plücker rows (layout in the module docstring)."""
    a, b, c = _corners_f64(vertices, faces)
    n_tris = a.shape[0]
    usable = _usable(a, b, c)
    with np.errstate(invalid="ignore", over="ignore"):
        normal = np.cross(b - a, c - a)
        data = np.zeros((n_tris, PLUCKER_ROWS, 4))
        for i, (p, q) in enumerate(((a, b), (b, c), (c, a))):
            data[:, 2 * i, :3] = q - p
            data[:, 2 * i + 1, :3] = np.cross(p, q)
        data[:, 0, 3], data[:, 1, 3], data[:, 2, 3] = normal[:, 0], normal[:, 1], normal[:, 2]
        data[:, 3, 3] = np.einsum("ij,ij->i", normal, a)
    return _to_f32_rows(data, usable)


def leaf_tris(corners: np.ndarray, objects: np.ndarray) -> np.ndarray:
    """The BVH leaves' triangles in the order of ``objects`` (rt_bvh.h's RT_BVH_LEAF_TRIS): for each
    reference, three float4 rows, the corners of ``corners`` ((3F, 4) float32, as uploaded as tris)
    with the triangle id's int32 bits in the first row's w. A leaf's triangles are then consecutive
    rows, read with no objects[] read between."""
    objects = np.asarray(objects, np.int32)
    out = np.asarray(corners, np.float32).reshape(-1, 3, 4)[objects].copy()
    out[:, 0, 3] = objects.view(np.float32)
    return out.reshape(-1, 4)
