"""Ropes and leaf boxes for the stackless kd traversal of Popov et al. 2007 (the paper's §3.1.2,
Table 4 "ropes"; device side: kernels/shared/rt_kd_ropes.h).

Every leaf gets its cell box and six ropes, one per face (slots -x, +x, -y, +y, -z, +z): the node on
the other side of that face whose box covers the whole face, or -1 on the scene boundary. Ropes are
built top-down in node order (children follow their parent in the kd-tree's level order): a child
inherits its parent's ropes, its inner face gets its sibling, and each rope is pushed down the tree
while a single child still covers the face (Popov's rope optimisation, section 4.1), so the
traversal's descent after following a rope is short.

Device layout (sync with rt_kd_ropes.h), node_data float4, 4 per leaf = 64 B:
  [4 L + 0] = (box min x, y, z, rope -x)      ropes as int32 bits
  [4 L + 1] = (box max x, y, z, rope +x)
  [4 L + 2] = (rope -y, rope +y, rope -z, rope +z)
  [4 L + 3] = (first object, 0, 0, 0)
and the rope tree's nodes are the kd-tree's with each leaf's y word replaced by its record index L.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..jit import njit
from ..errors import RtlabError
from ..kernel_constants import kernel_constant
from .kdtree import LEAF_TAG, KdTree

RECORD_FLOAT4S = int(kernel_constant("KD_ROPES_LEAF_STRIDE"))
NO_ROPE = -1


@dataclass
class KdRopes:
    nodes: np.ndarray        # (N, 2) int32: kd nodes, leaf y = record index
    records: np.ndarray      # (4 L, 4) float32: the node_data layout above
    leaf_nodes: np.ndarray   # (L,) int32: kd node index of each record
    boxes: np.ndarray        # (N, 6) float32 cell box of every node (lo xyz, hi xyz)
    ropes: np.ndarray        # (N, 6) int32 ropes of every node (after optimisation)


@njit(cache=True)
def _optimize_rope(words, splits, rope, face, box):
    """Popov's rope optimisation: go down from the rope while one child covers the face."""
    axis_face = face >> 1
    while rope >= 0:
        w = words[rope]
        if (w & 3) == LEAF_TAG:
            break
        axis, lower = w & 3, w >> 2
        s = splits[rope]
        if axis == axis_face:
            # Split parallel to the face: the child on the face's side touches it
            rope = lower + 1 if (face & 1) == 0 else lower
        elif s >= box[3 + axis]:
            rope = lower
        elif s <= box[axis]:
            rope = lower + 1
        else:
            break
    return rope


@njit(cache=True)
def _build_ropes(words, splits, bounds):
    n = words.shape[0]
    boxes = np.empty((n, 6), np.float32)
    ropes = np.full((n, 6), NO_ROPE, np.int32)
    boxes[0, :3] = bounds[0]
    boxes[0, 3:] = bounds[1]
    for i in range(n):
        w = words[i]
        if (w & 3) == LEAF_TAG:
            continue
        axis, lower = w & 3, w >> 2
        for c in range(2):
            child = lower + c
            boxes[child] = boxes[i]
            ropes[child] = ropes[i]
        boxes[lower, 3 + axis] = splits[i]
        boxes[lower + 1, axis] = splits[i]
        ropes[lower, 2 * axis + 1] = lower + 1
        ropes[lower + 1, 2 * axis] = lower
        for c in range(2):
            child = lower + c
            for f in range(6):
                ropes[child, f] = _optimize_rope(words, splits, ropes[child, f], f, boxes[child])
    return boxes, ropes


def build_ropes(tree: KdTree) -> KdRopes:
    """Ropes and leaf boxes of a kd-tree, in the device layout."""
    nodes = np.ascontiguousarray(tree.nodes, np.int32)
    words = np.ascontiguousarray(nodes[:, 0])
    splits = np.ascontiguousarray(nodes[:, 1]).view(np.float32)
    bounds = np.asarray(tree.bounds, np.float32)
    inner = np.flatnonzero((words & 3) != LEAF_TAG)
    if np.any((words[inner] >> 2) <= inner):
        raise RtlabError("ropes need every kd node's children after it in the node list (top-down layout)")
    boxes, ropes = _build_ropes(words, splits, bounds)
    leaf_nodes = np.flatnonzero((words & 3) == LEAF_TAG).astype(np.int32)
    n_leaves = len(leaf_nodes)
    records = np.zeros((n_leaves, RECORD_FLOAT4S, 4), np.float32)
    bits = records.view(np.int32)
    records[:, 0, :3] = boxes[leaf_nodes, :3]
    records[:, 1, :3] = boxes[leaf_nodes, 3:]
    leaf_ropes = ropes[leaf_nodes]
    bits[:, 0, 3] = leaf_ropes[:, 0]
    bits[:, 1, 3] = leaf_ropes[:, 1]
    bits[:, 2, :] = leaf_ropes[:, 2:]
    bits[:, 3, 0] = nodes[leaf_nodes, 1]
    rope_nodes = nodes.copy()
    rope_nodes[leaf_nodes, 1] = np.arange(n_leaves, dtype=np.int32)
    return KdRopes(rope_nodes, records.reshape(-1, 4), leaf_nodes, boxes, ropes)
