"""The BVH in the layout of the packet traversal (kernels/shared/rt_bvh_packet.h): the CPU's traversal.

The tree is rtlab.accel.bvh's binned-SAH BVH (same builder and disk cache; PACKET_BUILD's costs: a
node's boxes are tested on a whole packet, so larger leaves pay), collapsed to ``width``
children a node (Wald, Benthin & Boulos 2008, "Getting rid of packets": a wider node halves the
depth; each collapse step opens the inner child with the largest surface area). A packet tests
each child box and each triangle on all its rays at once, so a node keeps each child's box in two
rows (lo, hi) beside its ref, and each leaf's triangles follow the nodes as (v0, v1, v2) rows in leaf order: a leaf reads its
triangles straight, without the object list's indirection, and exactly the vertices the scalar
tests read (the watertight test needs them as they are; Möller-Trumbore subtracts them once a
triangle for the whole packet).

node_data, float4 rows (sync with rt_bvh_packet.h; W = width, RT_PACKET_WIDTH there):
  node i, rows 2 W i + 2 c, 2 W i + 2 c + 1 for child c < W: (lo.xyz, ref), (hi.xyz, 0)
  triangle rows from 2 W M: (v0.xyz, triangle id), (v1.xyz, 0), (v2.xyz, 0) for each leaf's triangles
A ref >= 0 is an inner node; a leaf is ~((row << 4) | count), its triangles from row ``row``. A node
fills its children first; an unused slot has ref EMPTY (a leaf of no triangles).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..errors import SceneError
from ..kernel_constants import kernel_constant
from .bvh import Bvh, BvhBuildParams

LEAF_BITS = int(kernel_constant("PBVH_LEAF_BITS"))
TRI_ROWS = int(kernel_constant("PBVH_TRI_ROWS"))
# SAH costs for packets: a binary node (two box tests on every lane) costs two triangle tests, and
# leaves may hold up to 15 triangles (2-8 % more Mrays per CPU-second than the GPU BVH's 1.0 and 8
# on the issue 15 views, most at 256²); no spatial splits (BvhBuildParams.spatial_alpha): the packet
# traversal is not checked with triangles referenced by several leaves
PACKET_BUILD = BvhBuildParams(max_leaf_size=15, cost_traversal=2.0, spatial_alpha=0.0)
EMPTY = int(kernel_constant("PBVH_EMPTY"))  # ~0: a leaf of no triangles
MAX_ROW = (1 << (31 - LEAF_BITS)) - 1      # largest row a leaf ref addresses


def node_rows(width: int) -> int:
    return 2 * width


@njit(cache=True)
def _collapse(child_lo, child_hi, child_ref, width):
    """The binary BVH with up to ``width`` children a node: (lo, hi, ref) per node and slot, with
    leaf refs as the binary BVH encodes them, and the number of nodes on the longest root-to-leaf
    path. Children of a node get consecutive indices; nodes are laid out depth first."""
    m2 = child_ref.shape[0]
    out_lo = np.zeros((m2, width, 3), np.float32)
    out_hi = np.zeros((m2, width, 3), np.float32)
    out_ref = np.full((m2, width), EMPTY, np.int32)
    lo = np.empty((width, 3), np.float32)
    hi = np.empty((width, 3), np.float32)
    ref = np.empty(width, np.int64)
    work = np.empty((m2 + 1, 3), np.int64)       # (binary node, collapsed node, depth)
    work[0, 0], work[0, 1], work[0, 2] = 0, 0, 1
    top, n_out, depth = 1, 1, 1
    while top > 0:
        top -= 1
        src, dst, d = work[top, 0], work[top, 1], work[top, 2]
        depth = max(depth, d)
        for c in range(2):
            lo[c], hi[c], ref[c] = child_lo[src, c], child_hi[src, c], child_ref[src, c]
        k = 2
        while k < width:
            best, best_area = -1, -1.0
            for i in range(k):
                if ref[i] >= 0:
                    e = hi[i] - lo[i]
                    area = e[0] * e[1] + e[1] * e[2] + e[2] * e[0]
                    if area > best_area:
                        best, best_area = i, area
            if best < 0:
                break
            r = ref[best]
            lo[best], hi[best], ref[best] = child_lo[r, 0], child_hi[r, 0], child_ref[r, 0]
            lo[k], hi[k], ref[k] = child_lo[r, 1], child_hi[r, 1], child_ref[r, 1]
            k += 1
        first_child = n_out
        for i in range(k):
            out_lo[dst, i], out_hi[dst, i] = lo[i], hi[i]
            if ref[i] >= 0:
                out_ref[dst, i] = n_out
                n_out += 1
            else:
                out_ref[dst, i] = ref[i]
        # Push in reverse, so that the first inner child is laid out (and its children numbered) next
        for i in range(k - 1, -1, -1):
            if ref[i] >= 0:
                work[top, 0], work[top, 1], work[top, 2] = ref[i], out_ref[dst, i], d + 1
                top += 1
        assert n_out - first_child <= width
    return out_lo[:n_out].copy(), out_hi[:n_out].copy(), out_ref[:n_out].copy(), depth


def packet_node_data(bvh: Bvh, vertices: np.ndarray, faces: np.ndarray, width: int) -> tuple[np.ndarray, int]:
    """(rows, stack entries the traversal needs): the BVH's nodes collapsed to ``width`` children
    and its leaves' triangles in the packet layout (module docstring)."""
    if width < 2:
        raise ValueError(f"a packet BVH node has at least 2 children, got width {width}")
    lo, hi, ref, depth = _collapse(bvh.child_lo, bvh.child_hi, bvh.child_ref, width)
    m = len(ref)
    objects = np.asarray(bvh.objects, np.int64)
    tri_base = node_rows(width) * m
    rows = tri_base + TRI_ROWS * len(objects)
    if rows - 1 > MAX_ROW:
        raise SceneError(f"packet BVH: {rows:,} rows, more than a leaf ref addresses ({MAX_ROW + 1:,})")
    ref = ref.astype(np.int64)
    leaf = (ref < 0) & (ref != EMPTY)
    bits = ~ref                                            # (first << LEAF_BITS) | count for leaves
    first, count = bits >> LEAF_BITS, bits & ((1 << LEAF_BITS) - 1)
    packet_ref = np.where(leaf, ~(((tri_base + TRI_ROWS * first) << LEAF_BITS) | count), ref).astype(np.int32)

    out = np.zeros((rows, 4), np.float32)
    nodes = out[:tri_base].reshape(m, width, 2, 4)         # node, child, (lo, hi), xyzw
    nodes[:, :, 0, :3] = lo
    nodes[:, :, 1, :3] = hi
    nodes.view(np.int32)[:, :, 0, 3] = packet_ref

    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.int64)[objects]
    v0, v1, v2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    tris = out[tri_base:].reshape(len(objects), TRI_ROWS, 4)
    tris[:, 0, :3] = v0
    tris.view(np.int32)[:, 0, 3] = objects.astype(np.int32)
    tris[:, 1, :3] = v1
    tris[:, 2, :3] = v2
    # a node pushes all but one of the children it enters, at most width - 1, on each level
    return out, (width - 1) * depth + 1
