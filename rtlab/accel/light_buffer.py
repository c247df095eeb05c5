"""The light buffer (Haines & Greenberg, "The light buffer: a shadow-testing accelerator", IEEE CG&A
1986): for a point light, a cube of cells around it, each listing the triangles that may cross the
cone of directions it covers, nearest to the light first. A shadow ray from a surface point o to the
light lies in the cone of the cell of (o - light), and only a triangle nearer the light than o can
block it, so the shadow test reads that cell's list in order and stops at a hit or at the first
triangle farther from the light than o: a few triangle tests in place of a tree walk. A cell that a
triangle crosses whole (Haines & Greenberg's "full occlusion") answers "blocked" for every o beyond
that triangle with no test at all, and its list ends there
(kernels/shared/rt_light_buffer.h; what it gains: docs/results.md, "Shadow rays through a light buffer").

Conservative by construction, so the answer is the traversal's: a triangle enters every cell whose
cone, widened by CONE_MARGIN in the face's (u, v) coordinates (far beyond float32 rounding of the
kernel's cell lookup and of its ray), its clipped projection's bounding box overlaps, and its distance
to the light is stored rounded down by DISTANCE_MARGIN. A cell whose list would pass MAX_LIST
triangles stores none and sends its rays to the traversal.

Layout, int32 words (the constants are kernels/shared/rt_light_buffer.h's; rtlab.device.device_scene
appends a light's block to the traversal's node_data, the light's position.w carries the block's first
word and its color.w the resolution and, from bit 16, the id bits):
    [0] [1]                     the resolution R (cells a face edge); the bits of a ref's triangle id
    [2] [3]                     zero
    [4 + 2 c] [5 + 2 c]         cell c = face * R * R + row * R + col: its first ref (a word of the block)
                                above its count's COUNT_BITS (TO_TRAVERSAL: "ask the traversal"); the
                                distance from the light beyond which its rays are blocked (float bits,
                                inf for none: a triangle crosses every ray of the cone there)
    refs                        one word each: the triangle id in the low id bits, above it its distance
                                to the light (the float's bits truncated, so never above it); a list holds
                                only triangles nearer than its cell's blocking distance
Faces: 2 * axis + (0 for +axis, 1 for -axis); col along axis + 1, row along axis + 2 (mod 3), each
from (w_u / |w_axis| + 1) R / 2 with w = point - light.
"""
from __future__ import annotations

import itertools

import numpy as np

from ..geometry import moller_trumbore_t
from ..jit import njit, prange
from ..kernel_constants import kernel_constant

CONE_MARGIN = 1e-4          # widening of a cell's cone, in its face's (u, v) coordinates (-1..1)
DISTANCE_MARGIN = 1e-5      # stored distances are rounded down by this relative amount
MAX_LIST = 126              # a longer list is dropped: its rays take the traversal (below TO_TRAVERSAL)
COVER_MARGIN = 1e-6         # a triangle blocks a cell where its cone corners cross it this far inside
FULL_MARGIN = 1e-4          # ... and only past its distance there, raised by this relative amount
RESOLUTIONS = (512, 256, 128, 64, 32)
MAX_WORDS = 24 << 20        # a light's block at most 96 MiB: the finest resolution that fits
# the block's layout, from kernels/shared/rt_light_buffer.h (the module docstring says what it means)
HEADER_WORDS = kernel_constant("RT_LB_HEADER_WORDS")
CELL_WORDS = kernel_constant("RT_LB_CELL_WORDS")
COUNT_BITS = kernel_constant("RT_LB_COUNT_BITS")
TO_TRAVERSAL = kernel_constant("RT_LB_TO_TRAVERSAL")
SHADOW_GAP_ULPS = kernel_constant("RT_SHADOW_GAP_ULPS")   # where a shadow segment ends (rt_whitted.h, shadow_segment_end)
MAX_ID_BITS = 24            # a ref keeps at least 8 bits of its distance (the float's exponent)


@njit(cache=True)
def _clip(poly, n, scale, bu, bv, out):
    """Keep the part of polygon poly[:n] (rows m, u, v) where scale * m + bu * u + bv * v >= 0."""
    k = 0
    for i in range(n):
        j = (i + 1) % n
        fp = scale * poly[i, 0] + bu * poly[i, 1] + bv * poly[i, 2]
        fq = scale * poly[j, 0] + bu * poly[j, 1] + bv * poly[j, 2]
        if fp >= 0.0:
            out[k] = poly[i]
            k += 1
        if (fp >= 0.0) != (fq >= 0.0):
            s = fp / (fp - fq)
            out[k] = poly[i] + s * (poly[j] - poly[i])
            k += 1
    return k


@njit(cache=True)
def _triangle_cells(v, light, res, out):
    """The cells whose widened cones triangle v (3 x 3) may cross; writes them to out when it has
    room, returns how many."""
    count = 0
    poly = np.empty((16, 3))
    tmp = np.empty((16, 3))
    scale = 1.0 + CONE_MARGIN
    for face in range(6):
        axis, sign = face // 2, 1.0 - 2.0 * (face % 2)
        ua, va = (axis + 1) % 3, (axis + 2) % 3
        for k in range(3):
            poly[k, 0] = sign * (v[k, axis] - light[axis])
            poly[k, 1] = v[k, ua] - light[ua]
            poly[k, 2] = v[k, va] - light[va]
        n = 3
        for plane in range(4):                    # the face's pyramid: m >= |u| and m >= |v|, widened
            bu = (-1.0 if plane == 0 else 1.0) if plane < 2 else 0.0
            bv = 0.0 if plane < 2 else (-1.0 if plane == 2 else 1.0)
            n = _clip(poly, n, scale, bu, bv, tmp)
            poly[:n] = tmp[:n]
            if n == 0:
                break
        if n == 0:
            continue
        lo_u = lo_v = np.inf
        hi_u = hi_v = -np.inf
        whole = False
        for k in range(n):
            m = poly[k, 0]
            if not m > 1e-9 * (abs(poly[k, 1]) + abs(poly[k, 2])):
                whole = True                      # a corner at the light: the whole face
                break
            lo_u, hi_u = min(lo_u, poly[k, 1] / m), max(hi_u, poly[k, 1] / m)
            lo_v, hi_v = min(lo_v, poly[k, 2] / m), max(hi_v, poly[k, 2] / m)
        c0 = r0 = 0
        c1 = r1 = res - 1
        if not whole:
            pad = 2.0 * CONE_MARGIN
            c0 = max(int(np.floor((lo_u - pad + 1.0) * 0.5 * res)), 0)
            c1 = min(int(np.floor((hi_u + pad + 1.0) * 0.5 * res)), res - 1)
            r0 = max(int(np.floor((lo_v - pad + 1.0) * 0.5 * res)), 0)
            r1 = min(int(np.floor((hi_v + pad + 1.0) * 0.5 * res)), res - 1)
        for r in range(r0, r1 + 1):
            for c in range(c0, c1 + 1):
                if count < out.shape[0]:
                    out[count] = face * res * res + r * res + c
                count += 1
    return count


@njit(cache=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def _closest_point(p, a, b, c):
    """The point of triangle abc closest to p (the Voronoi regions of Ericson, Real-Time Collision
    Detection, sec. 5.1.5: a corner, a point of an edge, or of the face)."""
    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c
    d1, d2, d3, d4, d5, d6 = _dot(ab, ap), _dot(ac, ap), _dot(ab, bp), _dot(ac, bp), _dot(ab, cp), _dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    if d1 <= 0.0 and d2 <= 0.0:
        return a
    if d3 >= 0.0 and d4 <= d3:
        return b
    if d6 >= 0.0 and d5 <= d6:
        return c
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        return a + ab * (d1 / (d1 - d3))
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        return a + ac * (d2 / (d2 - d6))
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))
    return a + ab * (vb / (va + vb + vc)) + ac * (vc / (va + vb + vc))


@njit(parallel=True, cache=True)
def _distances(vertices, faces, light):
    out = np.empty(faces.shape[0])
    for i in prange(faces.shape[0]):
        f = faces[i]
        q = light - _closest_point(light, vertices[f[0]], vertices[f[1]], vertices[f[2]])
        out[i] = np.sqrt(_dot(q, q))
    return out


@njit(parallel=True, cache=True)
def _cells_per_triangle(vertices, faces, light, res):
    out = np.empty(faces.shape[0], np.int64)
    none = np.empty(0, np.int64)
    for i in prange(faces.shape[0]):
        v = np.empty((3, 3))
        for k in range(3):
            v[k] = vertices[faces[i, k]]
        out[i] = _triangle_cells(v, light, res, none)
    return out


@njit(cache=True)
def _cover_distance(inner, light, cell, res):
    """How far from the light a triangle blocks every ray of the cell's widened cone: the largest
    distance at the cone's four corner rays (a plane's distance over a convex cone peaks at a corner),
    inf unless all four cross ``inner``, the triangle shrunk about its centroid (_shrunk), so that they
    cross the triangle itself inside by a margin."""
    face, rc = cell // (res * res), cell % (res * res)
    axis, sign = face // 2, 1.0 - 2.0 * (face % 2)
    ua, va = (axis + 1) % 3, (axis + 2) % 3
    pad = 2.0 * CONE_MARGIN
    worst = 0.0
    direction = np.empty(3)
    for corner in range(4):
        u = (rc % res + corner % 2) * 2.0 / res - 1.0 + (pad if corner % 2 else -pad)
        w = (rc // res + corner // 2) * 2.0 / res - 1.0 + (pad if corner // 2 else -pad)
        direction[axis], direction[ua], direction[va] = sign, u, w
        t = moller_trumbore_t(light, direction, inner[0], inner[1], inner[2])
        if not t > 0.0:
            return np.inf
        worst = max(worst, t * np.sqrt(_dot(direction, direction)))
    return worst


@njit(cache=True)
def _shrunk(v):
    """Triangle v shrunk about its centroid so that its points are those of v whose barycentrics are all
    at least COVER_MARGIN."""
    centre = (v[0] + v[1] + v[2]) / 3.0
    return centre + (v - centre) * (1.0 - 3.0 * COVER_MARGIN)


# Why many parameters: one numba pass over the triangles takes the geometry, its order and per-triangle
# figures made in numpy beforehand, and the build's settings, as arrays and scalars (no objects in nopython).
@njit(cache=True)
def _fill(vertices, faces, order, per_triangle, light, res, exact, cover_min, refs, max_list):
    n_cells = 6 * res * res
    cells = np.empty(max(per_triangle.max(), 1), np.int64)
    v = np.empty((3, 3))
    full = np.full(n_cells, np.inf)              # beyond this distance the cell's rays are blocked
    for i in order:
        for k in range(3):
            v[k] = vertices[faces[i, k]]
        inner = _shrunk(v)
        m = _triangle_cells(v, light, res, cells)
        for j in range(m):
            c = cells[j]
            if exact[i] < full[c] and exact[i] >= cover_min:
                full[c] = min(full[c], _cover_distance(inner, light, c, res) * (1.0 + FULL_MARGIN))
    counts = np.zeros(n_cells, np.int64)
    for i in order:
        for k in range(3):
            v[k] = vertices[faces[i, k]]
        m = _triangle_cells(v, light, res, cells)
        for j in range(m):
            if exact[i] <= full[cells[j]]:
                counts[cells[j]] += 1
    kept = counts <= max_list
    header = HEADER_WORDS + CELL_WORDS * n_cells
    words = np.zeros(header + (counts * kept).sum(), np.int32)
    words[0] = res
    full32 = np.minimum(full, 3.0e38).astype(np.float32)
    full_bits = np.where(full < 3.0e38, full32.view(np.int32), np.int32(0x7F800000))
    at = header
    fill = np.empty(n_cells, np.int64)
    for c in range(n_cells):
        words[HEADER_WORDS + CELL_WORDS * c] = (at << COUNT_BITS) | (counts[c] if kept[c] else TO_TRAVERSAL)
        words[HEADER_WORDS + CELL_WORDS * c + 1] = full_bits[c]
        fill[c] = at
        if kept[c]:
            at += counts[c]
    for i in order:
        for k in range(3):
            v[k] = vertices[faces[i, k]]
        m = _triangle_cells(v, light, res, cells)
        for j in range(m):
            c = cells[j]
            if kept[c] and exact[i] <= full[c]:
                words[fill[c]] = refs[i]
                fill[c] += 1
    return words


def build_light_buffer(vertices, faces, light, max_words: int = MAX_WORDS) -> np.ndarray | None:
    """A point light's block of int32 words (the layout above) at the finest of RESOLUTIONS that fits
    max_words, or None when none does."""
    if not MAX_LIST < TO_TRAVERSAL:
        raise ValueError(f"light buffer lists of {MAX_LIST} refs: a count must stay below {TO_TRAVERSAL}")
    max_words = min(max_words, 1 << (32 - COUNT_BITS))      # a cell's first ref fits above its count
    v = np.asarray(vertices, np.float64)
    f = np.ascontiguousarray(faces, np.int64)
    p = np.asarray(light, np.float64)
    exact = _distances(v, f, p)
    # float32 rounded down, never above the exact distance less its margin
    distances = (exact * (1.0 - DISTANCE_MARGIN)).astype(np.float32)
    distances = np.where(distances > exact, np.nextafter(distances, np.float32(0)), distances).astype(np.float32)
    order = np.argsort(exact, kind="stable")
    # A shadow segment stops short of the light by SHADOW_GAP_ULPS ulps of its largest |component| and the
    # light's (shadow_segment_end): at most that many times u sqrt(3) (segment + light) in distance. A
    # triangle that near the light blocks no segment there, so it covers a cell ("blocked beyond") only
    # beyond the gap of the longest segment in the scene, to the farthest corner of its bounds (with room
    # for spawn offsets)
    corners = np.array(list(itertools.product(*zip(v.min(0), v.max(0))))) if len(v) else p[None]
    reach = float(np.linalg.norm(corners - p, axis=1).max())
    cover_min = SHADOW_GAP_ULPS * 2.0 ** -24 * np.sqrt(3.0) * (reach + float(np.abs(p).max())) * (1.0 + 1e-2)
    id_bits = max(int(len(f) - 1).bit_length(), 1)
    if id_bits > MAX_ID_BITS:
        return None
    # a ref: the triangle id in the low id_bits, above it the distance's float bits truncated (rounded down)
    code = distances.view(np.uint32).astype(np.uint64) >> np.uint64(id_bits - 1)
    refs = ((code << np.uint64(id_bits)) | np.arange(len(f), dtype=np.uint64)).astype(np.uint32).view(np.int32)
    for res in RESOLUTIONS:
        per_triangle = _cells_per_triangle(v, f, p, res)
        if HEADER_WORDS + 6 * CELL_WORDS * res * res <= max_words or res == RESOLUTIONS[-1]:
            words = _fill(v, f, order, per_triangle, p, res, exact, cover_min, refs, MAX_LIST)
            words[1] = id_bits
            if len(words) <= max_words:
                return words
    return None


def cell_records(words: np.ndarray) -> np.ndarray:
    """The block's cells, (6 R², 3) int64: first ref (a word of the block), count (-1: the traversal),
    blocking distance bits."""
    res = int(words[0])
    raw = words[HEADER_WORDS:HEADER_WORDS + 6 * CELL_WORDS * res * res].view(np.uint32).astype(np.int64)
    raw = raw.reshape(-1, CELL_WORDS)          # unsigned: a first ref past 2^24 fills the word's sign bit
    count = raw[:, 0] & TO_TRAVERSAL
    return np.stack([raw[:, 0] >> COUNT_BITS, np.where(count == TO_TRAVERSAL, -1, count), raw[:, 1]], axis=1)


def decode_refs(words: np.ndarray, at: int, count: int) -> tuple[np.ndarray, np.ndarray]:
    """The triangle ids and the distances (float32, never above the true ones) of refs words[at:at+count]."""
    id_bits = int(words[1])
    raw = words[at:at + count].view(np.uint32)
    ids = (raw & np.uint32((1 << id_bits) - 1)).astype(np.int64)
    dist = ((raw >> np.uint32(id_bits)) << np.uint32(id_bits - 1)).view(np.float32)
    return ids, dist


def light_buffer_stats(words: np.ndarray) -> dict:
    """Resolution, cells, the traversal's share of cells, mean list length, MiB."""
    res = int(words[0])
    cells = cell_records(words)
    kept = cells[cells[:, 1] >= 0, 1]
    blocked = np.isfinite(cells[:, 2].astype(np.int32).view(np.float32))
    return {"resolution": res, "cells": len(cells), "cells_to_traversal": int((cells[:, 1] < 0).sum()),
            "cells_blocked_beyond": int(blocked.sum()), "mean_list": float(kept.mean()) if kept.size else 0.0,
            "mib": words.nbytes / 2**20}
