"""What each tile of a camera's image will cost to trace, known before any ray is: the 4-wide BVH's
boxes projected with the camera (rtlab.device.tile_orders launches the costliest tiles first).

A camera ray enters a box only if the pixel lies in the box's projection, so a tile's cost is
estimated as the cost of a walk that entered every box whose screen rectangle covers it: 121 for an
inner node (the SASS of one 4-wide visit, as in rtlab.accel.bvh_wide_stats) and 75 a triangle for a
leaf. Occlusion is ignored (an overdraw). A box that reaches behind the eye is clipped to the half
space in front of it, so a box beside the camera covers the side of the image it reaches into, and
one around the eye covers all of it. The ranking it gives is what matters, not the figure (how well
it ranks the benchmark views' tiles: experiments/probe_tile_costs.py overlap, docs/results.md).

Why many parameters: numba's compiled functions take arrays and scalars one by one (no objects in
nopython mode), so the camera's rows and the image's sizes are parameters.
"""
from __future__ import annotations

import numpy as np

from ..jit import njit
from .bvh4 import Bvh4, LEAF_BITS

NODE_COST, TRI_COST = 121.0, 75.0     # instructions of a 4-wide visit and of a triangle test (SASS)
_NEAR = 1e-6                          # the clip plane in front of the eye, in units of the view axis


@njit(cache=True, inline="always")
def _dot(a, b0, b1, b2):
    return a[0] * b0 + a[1] * b1 + a[2] * b2


@njit(cache=True)
def _accumulate(lo, hi, weight, eye, u, v, w, width, height, tile_w, tile_h, grid):
    """Add each box's weight to the difference grid over the tiles its projection covers."""
    nx, ny = grid.shape[1] - 1, grid.shape[0] - 1
    uu, vv, ww = _dot(u, u[0], u[1], u[2]), _dot(v, v[0], v[1], v[2]), _dot(w, w[0], w[1], w[2])
    pts = np.empty((20, 3))
    for b in range(lo.shape[0]):
        if not (lo[b, 0] <= hi[b, 0] and lo[b, 1] <= hi[b, 1] and lo[b, 2] <= hi[b, 2]):
            continue                                   # an empty slot
        # The box's corners and, where an edge crosses the clip plane, the crossing
        depth = np.empty(8)
        corner = np.empty((8, 3))
        for c in range(8):
            for k in range(3):
                corner[c, k] = hi[b, k] if (c >> k) & 1 else lo[b, k]
            depth[c] = _dot(w, corner[c, 0] - eye[0], corner[c, 1] - eye[1], corner[c, 2] - eye[2]) / ww
        n = 0
        for c in range(8):
            if depth[c] > _NEAR:
                pts[n] = corner[c]
                n += 1
            for k in range(3):                        # the edges from c along +k
                if (c >> k) & 1:
                    continue
                e = c | (1 << k)
                if (depth[c] > _NEAR) != (depth[e] > _NEAR):
                    s = (_NEAR - depth[c]) / (depth[e] - depth[c])
                    pts[n] = corner[c] + s * (corner[e] - corner[c])
                    n += 1
        if n == 0:
            continue                                   # wholly behind the eye
        x0, x1, y0, y1 = np.inf, -np.inf, np.inf, -np.inf
        for i in range(n):
            q0, q1, q2 = pts[i, 0] - eye[0], pts[i, 1] - eye[1], pts[i, 2] - eye[2]
            a = max(_dot(w, q0, q1, q2) / ww, _NEAR)
            x = (_dot(u, q0, q1, q2) / uu / a + 1.0) * 0.5 * width
            y = (1.0 - _dot(v, q0, q1, q2) / vv / a) * 0.5 * height
            x0, x1, y0, y1 = min(x0, x), max(x1, x), min(y0, y), max(y1, y)
        if x1 < 0.0 or y1 < 0.0 or x0 >= width or y0 >= height:
            continue
        tx0 = int(max(x0, 0.0) // tile_w)
        tx1 = min(int(min(x1, width - 1.0) // tile_w), nx - 1)
        ty0 = int(max(y0, 0.0) // tile_h)
        ty1 = min(int(min(y1, height - 1.0) // tile_h), ny - 1)
        grid[ty0, tx0] += weight[b]
        grid[ty0, tx1 + 1] -= weight[b]
        grid[ty1 + 1, tx0] -= weight[b]
        grid[ty1 + 1, tx1 + 1] += weight[b]


def tile_boxes(bvh4: Bvh4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lo, hi, weight): every child box of the 4-wide tree in float64 and its cost, NODE_COST for an
    inner node and TRI_COST a triangle for a leaf; an empty slot's box is (+inf, -inf)."""
    planes, refs = bvh4.planes(), bvh4.refs().reshape(-1)
    lo = np.stack([planes[:, 0], planes[:, 2], planes[:, 4]], -1).reshape(-1, 3).astype(np.float64)
    hi = np.stack([planes[:, 1], planes[:, 3], planes[:, 5]], -1).reshape(-1, 3).astype(np.float64)
    count = np.where(refs < 0, (~refs) & ((1 << LEAF_BITS) - 1), 0)
    return lo, hi, np.where(refs < 0, TRI_COST * np.maximum(count, 1), NODE_COST)


def tile_costs(boxes: tuple, basis: np.ndarray, width: int, height: int, tile: tuple[int, int]) -> np.ndarray:
    """(tiles high, tiles wide) float64: each tile's estimated cost (the module docstring) from the
    ``boxes`` of tile_boxes, for the camera of ``basis`` (rtlab.scene.Camera.basis: eye, u, v, w) on a
    width x height image cut into tiles of ``tile`` = (w, h) pixels."""
    lo, hi, weight = boxes
    tw, th = tile
    nx, ny = -(-width // tw), -(-height // th)
    grid = np.zeros((ny + 1, nx + 1))
    eye, u, v, w = (np.asarray(r, np.float64) for r in basis)
    _accumulate(lo, hi, weight, eye, u, v, w, float(width), float(height), float(tw), float(th), grid)
    return grid.cumsum(0).cumsum(1)[:ny, :nx]
