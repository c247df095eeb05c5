"""The BVH in the layout of the packet traversal (kernels/shared/rt_bvh_packet.h): the CPU's traversal.

The tree is rtlab.accel.bvh's binned-SAH BVH (same build, same disk cache); only the device layout
differs. A packet tests each child box and each triangle on all its rays at once, so a node keeps
each child's box in two rows (lo, hi) beside its ref, and each leaf's triangles follow the nodes
as (v0, e1 = v1 - v0, e2 = v2 - v0) rows in leaf order: a leaf reads its triangles straight, without
the object list's indirection, and Möller-Trumbore needs no subtraction for the edges.

node_data, float4 rows (sync with rt_bvh_packet.h):
  node i, rows 4 i .. 4 i + 3: (c0.lo.xyz, ref c0), (c0.hi.xyz, 0), (c1.lo.xyz, ref c1), (c1.hi.xyz, 0)
  triangle rows from 4 M: (v0.xyz, triangle id), (e1.xyz, 0), (e2.xyz, 0) for each leaf's triangles
A ref >= 0 is an inner node; a leaf is ~((row << 4) | count), its triangles from row ``row``.
"""
from __future__ import annotations

import numpy as np

from ..errors import SceneError
from .bvh import LEAF_BITS, Bvh, load_or_build_bvh

NODE_ROWS = 4
TRI_ROWS = 3
MAX_ROW = (1 << (31 - LEAF_BITS)) - 1      # largest row a leaf ref addresses


def packet_node_data(bvh: Bvh, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(4 M + 3 K, 4) float32: the BVH's nodes and its leaves' triangles in the packet layout."""
    m = bvh.n_nodes
    objects = np.asarray(bvh.objects, np.int64)
    tri_base = NODE_ROWS * m
    rows = tri_base + TRI_ROWS * len(objects)
    if rows - 1 > MAX_ROW:
        raise SceneError(f"packet BVH: {rows:,} rows, more than a leaf ref addresses ({MAX_ROW + 1:,})")
    ref = np.asarray(bvh.child_ref, np.int64)
    leaf = ref < 0
    bits = ~ref                                            # (first << LEAF_BITS) | count for leaves
    first, count = bits >> LEAF_BITS, bits & ((1 << LEAF_BITS) - 1)
    packet_ref = np.where(leaf, ~(((tri_base + TRI_ROWS * first) << LEAF_BITS) | count), ref).astype(np.int32)

    out = np.zeros((rows, 4), np.float32)
    nodes = out[:tri_base].reshape(m, 2, 2, 4)             # node, child, (lo, hi), xyzw
    nodes[:, :, 0, :3] = bvh.child_lo
    nodes[:, :, 1, :3] = bvh.child_hi
    nodes.view(np.int32)[:, :, 0, 3] = packet_ref

    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.int64)[objects]
    v0, v1, v2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    tris = out[tri_base:].reshape(len(objects), TRI_ROWS, 4)
    tris[:, 0, :3] = v0
    tris.view(np.int32)[:, 0, 3] = objects.astype(np.int32)
    tris[:, 1, :3] = v1 - v0                               # float32, as the scalar test computes them
    tris[:, 2, :3] = v2 - v0
    return out


def bvh_packet_accel(scene, tree=None):
    """ACCEL_BUILDERS["bvh-packet"]: the scene's BVH in the packet layout (the kd-tree is not used)."""
    from ..device_scene import AccelArrays
    bvh, _ = load_or_build_bvh(scene.vertices, scene.faces)
    nodes = np.zeros((1, 2), np.int32)                     # unused by the BVH traversals
    return AccelArrays(nodes, packet_node_data(bvh, scene.vertices, scene.faces), bvh.objects, bvh.bounds,
                       bvh.depth + 1)


def _register():
    from .. import device_scene
    device_scene.ACCEL_BUILDERS["bvh-packet"] = bvh_packet_accel


_register()
