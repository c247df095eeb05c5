"""The CPU's BVH: the layout the wide single-ray traversal (kernels/shared/rt_bvh_wide.h) and the
packet traversal (rt_bvh_packet.h) both read, so one upload serves coherent and incoherent rays.

The tree is rtlab.accel.bvh's binned-SAH BVH (same builder and disk cache, CPU_BUILD's costs), with
spatial splits where they lower its SAH cost as for the GPU's "bvh" traversal (cpu_bvh), then:
  * every subtree of at most ``lanes`` triangles made one leaf (_merge_small_subtrees): a leaf's
    triangles are tested ``lanes`` at a time, so such a subtree costs one block test as a leaf and at
    least a node test and a block test as a subtree;
  * collapsed to ``lanes`` children a node (Wald, Benthin & Boulos 2008, "Getting rid of packets":
    each collapse step opens the inner child with the largest surface area; a wider node cuts the
    depth by about log2(lanes)).
A node keeps each coordinate of its children's boxes as one lane vector, so one ray tests all of
them with a few vector instructions (a packet reads one lane of each); a leaf's triangles follow the
nodes as blocks of ``lanes`` triangles, each coordinate of each vertex one lane vector, so a block is
one lane test for a ray (and a packet reads triangle by triangle). The vertices are stored as they
are, not as edges: the watertight test reads v0, v1 and v2 exactly, and Moller-Trumbore subtracts
them as the scalar test does.

node_data, float4 rows (sync with rt_bvh_wide.h; L = lanes, Q = L / 4 rows a lane vector):
  node i, rows 7 Q i ..: lane vectors lo.x, hi.x, lo.y, hi.y, lo.z, hi.z, ref (int bits) of its
      children, used slots first; an unused slot: lo = +inf, hi = -inf, ref EMPTY
  then the blocks, 10 Q rows each: lane vectors v0.x, v0.y, v0.z, v1.x, ..., v2.z, triangle id (int
      bits); a leaf's last block is filled up with its first triangle
A ref >= 0 is an inner node; a leaf is ~((row << LEAF_BITS) | count), count triangles in
ceil(count / L) blocks from row ``row``.
"""
from __future__ import annotations

import numpy as np

from ..jit import njit
from ..errors import SceneError
from ..kernel_constants import kernel_constant
from .bvh import Bvh, BvhBuildParams, load_or_build_bvh

LEAF_BITS = int(kernel_constant("WBVH_LEAF_BITS"))
EMPTY = int(kernel_constant("WBVH_EMPTY"))
NODE_VECTORS = int(kernel_constant("WBVH_NODE_VECTORS"))     # lane vectors a node: lo, hi of each axis, refs
BLOCK_VECTORS = int(kernel_constant("WBVH_BLOCK_VECTORS"))   # lane vectors a block: 3 vertices x 3 axes, ids
MAX_ROW = (1 << (31 - LEAF_BITS)) - 1
# SAH costs of the binary tree before it is collapsed: a binary node (two box tests) costs two
# triangle tests, leaves of up to 8 triangles (a block); leaves of 15 and node costs of 1 or 3 were
# within 5 % on the benchmark views on PoCL, so the simplest stays (the A/B is in CHANGELOG.md)
CPU_BUILD = BvhBuildParams(max_leaf_size=8, cost_traversal=2.0)
# ... and the same with spatial splits (SBVH, as the GPU BVH's SPLIT_BUILD), kept where its SAH cost
# is SPLIT_MIN_GAIN lower (rtlab.accel.bvh_stats)
CPU_SPLIT_BUILD = BvhBuildParams(max_leaf_size=8, cost_traversal=2.0, spatial_alpha=1e-5)


def cpu_bvh(vertices, faces, cache_dir=None) -> Bvh:
    """The binary BVH the CPU traversals read, before its layout (wide_node_data): both builds from
    the on-disk cache or built, the spatial-split one kept where its SAH cost is SPLIT_MIN_GAIN
    lower, as the GPU's "bvh" traversal chooses (rtlab.accel.bvh_stats.traversal_bvh)."""
    from .bvh_stats import SPLIT_MIN_GAIN, sah_cost
    plain, _ = load_or_build_bvh(vertices, faces, CPU_BUILD, cache_dir)
    split, _ = load_or_build_bvh(vertices, faces, CPU_SPLIT_BUILD, cache_dir)
    return split if sah_cost(split) <= (1.0 - SPLIT_MIN_GAIN) * sah_cost(plain) else plain


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
