"""The BVH in the layout of the wide single-ray traversal (kernels/shared/rt_bvh_wide.h): one ray a
work-item, a node's children box-tested in SIMD lanes and a leaf's triangles in blocks of as many.

The tree is rtlab.accel.bvh's binned-SAH BVH (same builder and disk cache), collapsed to ``lanes``
children a node as the packet layout collapses it (rtlab.accel.bvh_packet._collapse: each step opens
the inner child with the largest surface area). A node keeps each coordinate of its children's boxes
as one lane vector, so one ray tests all of them with a few vector instructions; a leaf's triangles
follow the nodes as blocks of ``lanes`` triangles, each coordinate of each vertex one lane vector, so
a block is one lane test. The vertices are stored as they are (not as edges): the watertight test
reads v0, v1 and v2 exactly, and Moller-Trumbore subtracts them as the scalar test does.

node_data, float4 rows (sync with rt_bvh_wide.h; L = lanes, Q = L / 4 rows a lane vector):
  node i, rows 7 Q i ..: lane vectors lo.x, hi.x, lo.y, hi.y, lo.z, hi.z, ref (int bits) of its
      children; an unused slot: lo = +inf, hi = -inf, ref EMPTY
  then the blocks, 10 Q rows each: lane vectors v0.x, v0.y, v0.z, v1.x, ..., v2.z, triangle id (int
      bits); a leaf's last block is filled up with its first triangle
A ref >= 0 is an inner node; a leaf is ~((row << LEAF_BITS) | count), count triangles in
ceil(count / L) blocks from row ``row``.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..errors import SceneError
from ..kernel_constants import kernel_constant
from .bvh import Bvh
from .bvh_packet import _collapse

LEAF_BITS = int(kernel_constant("WBVH_LEAF_BITS"))
EMPTY = int(kernel_constant("WBVH_EMPTY"))
NODE_VECTORS = 7                 # lane vectors a node: lo, hi of each axis, refs
BLOCK_VECTORS = 10               # lane vectors a block: 3 vertices x 3 axes, ids
MAX_ROW = (1 << (31 - LEAF_BITS)) - 1


def node_rows(lanes: int) -> int:
    return NODE_VECTORS * lanes // 4


def block_rows(lanes: int) -> int:
    return BLOCK_VECTORS * lanes // 4


@njit(cache=True)
def _merge_small_subtrees(child_ref, max_count):
    """child_ref with every inner child whose subtree holds at most max_count triangle references
    turned into one leaf of them: one block test costs about what a node test does, so a subtree
    that fits a block is cheaper as that block (and its leaves' blocks fill up). A subtree's leaves
    are consecutive in the object list (the builder lays leaves out depth first), so the leaf is the
    range from its first leaf's first object. Children have higher indices than their parent."""
    m = child_ref.shape[0]
    count = np.zeros(m, np.int64)
    first = np.zeros(m, np.int64)
    out = child_ref.copy()
    for node in range(m - 1, -1, -1):
        total, lo = 0, np.int64(1) << 62
        for c in range(2):
            r = out[node, c]
            if r >= 0:
                n, f = count[r], first[r]
            else:
                bits = ~np.int64(r)
                n, f = bits & ((1 << LEAF_BITS) - 1), bits >> LEAF_BITS
            if n > 0:
                total += n
                lo = min(lo, f)
        count[node], first[node] = total, lo
        for c in range(2):
            r = out[node, c]
            if r >= 0 and count[r] <= max_count:
                out[node, c] = ~((first[r] << LEAF_BITS) | count[r])
    return out


def wide_node_data(bvh: Bvh, vertices: np.ndarray, faces: np.ndarray, lanes: int) -> tuple[np.ndarray, int]:
    """(rows, stack entries the traversal needs): the BVH collapsed to ``lanes`` children a node and
    its leaves' triangles in blocks of ``lanes``, in the wide layout (module docstring)."""
    if lanes not in (4, 8, 16):
        raise ValueError(f"the wide BVH takes 4, 8 or 16 lanes, got {lanes}")
    merged = _merge_small_subtrees(bvh.child_ref, lanes)
    lo, hi, ref, depth = _collapse(bvh.child_lo, bvh.child_hi, merged, lanes)
    m = len(ref)
    ref = ref.astype(np.int64)
    empty = ref == EMPTY
    leaf = (ref < 0) & ~empty
    bits = ~ref[leaf]                                      # (first << LEAF_BITS) | count, binary layout
    first, count = bits >> LEAF_BITS, bits & ((1 << LEAF_BITS) - 1)
    n_blocks = (count + lanes - 1) // lanes
    tri_base = node_rows(lanes) * m
    block_start = tri_base + block_rows(lanes) * (np.cumsum(n_blocks) - n_blocks)
    rows = tri_base + block_rows(lanes) * int(n_blocks.sum())
    if rows - 1 > MAX_ROW:
        raise SceneError(f"wide BVH: {rows:,} rows, more than a leaf ref addresses ({MAX_ROW + 1:,})")
    out_ref = ref.copy()
    out_ref[leaf] = ~((block_start << LEAF_BITS) | count)

    out = np.zeros((rows, 4), np.float32)
    nodes = out[:tri_base].reshape(m, NODE_VECTORS, lanes)
    lo = np.where(empty[:, :, None], np.float32(np.inf), lo)
    hi = np.where(empty[:, :, None], np.float32(-np.inf), hi)
    for axis in range(3):
        nodes[:, 2 * axis] = lo[:, :, axis]
        nodes[:, 2 * axis + 1] = hi[:, :, axis]
    nodes.view(np.int32)[:, 6] = out_ref.astype(np.int32)

    # Each block's triangles: lane l of a leaf's block b is its triangle L b + l, or its first
    # triangle past its count
    leaf_of_block = np.repeat(np.arange(len(count)), n_blocks)
    block_in_leaf = np.arange(len(leaf_of_block)) - np.repeat(np.cumsum(n_blocks) - n_blocks, n_blocks)
    slot = block_in_leaf[:, None] * lanes + np.arange(lanes)[None, :]
    slot = np.where(slot < count[leaf_of_block][:, None], slot, 0)
    objects = np.asarray(bvh.objects, np.int64)
    tri = objects[first[leaf_of_block][:, None] + slot]      # (blocks, lanes) triangle ids
    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.int64)[tri]                    # (blocks, lanes, 3) vertex indices
    blocks = out[tri_base:].reshape(len(tri), BLOCK_VECTORS, lanes)
    for j in range(3):
        corner = v[f[:, :, j]]                              # (blocks, lanes, 3)
        for axis in range(3):
            blocks[:, 3 * j + axis] = corner[:, :, axis]
    blocks.view(np.int32)[:, 9] = tri.astype(np.int32)
    # a node pushes all but one of the children it enters, at most lanes - 1, on each level
    return out, (lanes - 1) * depth + 1
