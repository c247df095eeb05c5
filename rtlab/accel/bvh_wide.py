"""A 4-wide BVH for the library's fast path (kernels/shared/rt_bvh_wide.h): the binary SAH BVH of
rtlab.accel.bvh collapsed so that each node holds up to four children.

Why: on a GPU without ray-tracing cores, a closest-hit traversal is bound by the latency of its
chain of dependent node fetches, not by arithmetic (ncu on the H100: 37 % of stalls wait on L1TEX,
half the warp slots idle). A 4-wide node halves the chain: one fetch tests four boxes.

Collapse (greedy, as in Wald et al.'s "Getting rid of packets" and Embree's BVH4 from a binary
build): a wide node starts from a binary node's two children and repeatedly opens the inner child
with the largest surface area until it has four children or only leaves.

Device layout (sync with rt_bvh_wide.h), node_data float4 rows, BVH_WIDE_ROWS = 7 per node:
  [7 i + 0..5] = lo.x, hi.x, lo.y, hi.y, lo.z, hi.z of children 0..3 (one float4 a component)
  [7 i + 6]    = child refs 0..3 as int bits
ref >= 0: inner node index; BVH_WIDE_EMPTY: no child in this slot; other negative refs are leaves,
encoded and laid out inline after the nodes exactly as in the binary BVH (rtlab.accel.bvh).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..errors import SceneError
from .bvh import LEAF_BITS, MAX_LEAF, TRI_FLOAT4S, Bvh, load_or_build_bvh

WIDTH = 4
ROWS = 7                      # float4 rows of a node (module docstring)
EMPTY = np.int32(-2 ** 31)    # an unused child slot (BVH_WIDE_EMPTY)


@dataclass
class WideBvh:
    lo: np.ndarray            # (N, WIDTH, 3) float32 child boxes (+inf/-inf in empty slots)
    hi: np.ndarray
    ref: np.ndarray           # (N, WIDTH) int32: inner index, binary-BVH leaf ref, or EMPTY
    objects: np.ndarray       # the binary BVH's leaf triangle list
    bounds: np.ndarray
    depth: int                # most inner nodes on a root-to-leaf path

    @property
    def n_nodes(self) -> int:
        return int(self.ref.shape[0])

    @property
    def stack_size(self) -> int:
        """Entries the traversal's stack can hold at most: each node visited pushes up to WIDTH - 1."""
        return (WIDTH - 1) * self.depth + 1

    def node_data(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """(7 N + 3 K, 4) float32: the nodes, then the K leaf triangles inline (as rtlab.accel.bvh)."""
        n = self.n_nodes
        out = np.zeros((n, ROWS, 4), np.float32)
        for axis in range(3):
            out[:, 2 * axis] = self.lo[:, :, axis]
            out[:, 2 * axis + 1] = self.hi[:, :, axis]
        k = len(self.objects)
        if ROWS * n + TRI_FLOAT4S * k >= 1 << (31 - LEAF_BITS):
            raise SceneError(f"4-wide BVH of {k:,} triangles is too large for the device's leaf refs")
        ref = self.ref.astype(np.int64)
        leaf = (ref < 0) & (ref != -1) & (ref != EMPTY)
        bits = ~ref[leaf]
        first, count = bits >> LEAF_BITS, bits & MAX_LEAF
        ref[leaf] = ~(((ROWS * n + TRI_FLOAT4S * first) << LEAF_BITS) | count)
        out.view(np.int32)[:, 6, :] = ref.astype(np.int32)
        tris = np.zeros((k, TRI_FLOAT4S, 4), np.float32)
        tris[:, :, :3] = np.asarray(vertices, np.float32)[np.asarray(faces)[self.objects]]
        tris.view(np.int32)[:, 0, 3] = self.objects
        return np.concatenate([out.reshape(-1, 4), tris.reshape(-1, 4)])


@njit(cache=True)
def _half_area(lo, hi):
    dx, dy, dz = hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]
    return dx * dy + dy * dz + dz * dx


@njit(cache=True)
def _collapse(child_lo, child_hi, child_ref, width, empty):
    n2 = child_ref.shape[0]
    lo = np.full((n2, width, 3), np.inf, np.float32)
    hi = np.full((n2, width, 3), -np.inf, np.float32)
    ref = np.full((n2, width), empty, np.int32)
    # children of the wide node being filled: (lo, hi, binary ref)
    c_lo = np.empty((width, 3), np.float32)
    c_hi = np.empty((width, 3), np.float32)
    c_ref = np.empty(width, np.int64)
    work = np.empty((n2 + 1, 3), np.int64)         # (binary node, wide node, inner nodes above)
    work[0, 0], work[0, 1], work[0, 2] = 0, 0, 1
    top, n_wide, depth = 1, 1, 1
    while top > 0:
        top -= 1
        b, w, above = work[top, 0], work[top, 1], work[top, 2]
        depth = max(depth, above)
        count = 0
        for s in range(2):
            if child_ref[b, s] == -1:             # an empty binary leaf: no child
                continue
            c_lo[count], c_hi[count], c_ref[count] = child_lo[b, s], child_hi[b, s], child_ref[b, s]
            count += 1
        while count < width:
            # open the inner child with the largest surface area
            best, best_area = -1, -1.0
            for j in range(count):
                if c_ref[j] >= 0:
                    area = _half_area(c_lo[j], c_hi[j])
                    if area > best_area:
                        best, best_area = j, area
            if best < 0:
                break
            inner = c_ref[best]
            opened = 0
            for s in range(2):
                if child_ref[inner, s] == -1:
                    continue
                j = best if opened == 0 else count
                c_lo[j], c_hi[j], c_ref[j] = child_lo[inner, s], child_hi[inner, s], child_ref[inner, s]
                if opened == 1:
                    count += 1
                opened += 1
            if opened == 0:                       # both children empty: drop the slot
                c_lo[best], c_hi[best], c_ref[best] = c_lo[count - 1], c_hi[count - 1], c_ref[count - 1]
                count -= 1
        for j in range(count):
            lo[w, j], hi[w, j] = c_lo[j], c_hi[j]
            if c_ref[j] >= 0:
                ref[w, j] = n_wide
                work[top, 0], work[top, 1], work[top, 2] = c_ref[j], n_wide, above + 1
                top += 1
                n_wide += 1
            else:
                ref[w, j] = c_ref[j]
    return lo[:n_wide].copy(), hi[:n_wide].copy(), ref[:n_wide].copy(), depth


def collapse(bvh: Bvh, width: int = WIDTH) -> WideBvh:
    """The binary BVH with up to ``width`` children a node (module docstring)."""
    lo, hi, ref, depth = _collapse(bvh.child_lo, bvh.child_hi, bvh.child_ref, width, EMPTY)
    return WideBvh(lo, hi, ref, bvh.objects, bvh.bounds, int(depth))


def bvh4_accel(scene, tree=None):
    """ACCEL_BUILDERS["bvh4"]: the scene's 4-wide BVH in the device layout."""
    from ..device_scene import AccelArrays
    bvh, _ = load_or_build_bvh(scene.vertices, scene.faces)
    wide = collapse(bvh)
    nodes = np.zeros((1, 2), np.int32)     # unused by the BVH traversal
    return AccelArrays(nodes, wide.node_data(scene.vertices, scene.faces), wide.objects, wide.bounds,
                       wide.stack_size)


def _register():
    from .. import device_scene
    device_scene.ACCEL_BUILDERS["bvh4"] = bvh4_accel


_register()
