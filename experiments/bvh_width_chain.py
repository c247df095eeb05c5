"""How long a ray's chain of dependent node reads is, 4 children a node against 8, counted on the host.

The ray fetch's tail on DRAGON is the drain of the rays in flight, each a chain of node reads that wait
on each other (docs/results.md, "The ray fetch's tail"). A wider node makes the chain shorter. This
collapses the same binary tree (rtlab.accel.bvh_collapse, as rtlab/accel/bvh4.py does) to 4 and to 8
children a node with float boxes, and walks the benchmark views' rays through the float64 mirror of
rt_bvh4.h's order at either width (nearest child first, the others pushed with their entry distances,
pop culling: rtlab.accel.bvh_wide_stats): node visits a ray (the chain), child boxes tested (the
work), triangle tests, and node bytes read (112 B for 4 float children, 224 B for 8).

    python experiments/bvh_width_chain.py --size 128 [--views dragon/fill,...] [--kinds diffuse,primary]

A count, not a time: an 8-wide visit tests twice the boxes and sorts 8 keys instead of 4.
"""
from __future__ import annotations

import argparse

import numpy as np

from rtlab.accel.bvh4 import LEAF_BITS, Bvh4BuildParams
from rtlab.accel.bvh8 import TRI_ROWS
from rtlab.accel.bvh_collapse import collapse_best
from rtlab.accel.bvh_wide_stats import WideWalkArrays, traversal_counts_wide
from rtlab.benches.rays import make_rays, view_scene

NODE_BYTES = {4: 112, 8: 224}     # six float planes a child and an int ref a child


def wide_walk_arrays(vertices, faces, width: int, params: Bvh4BuildParams = Bvh4BuildParams()):
    """The scene's binary tree collapsed to ``width`` float children a node, laid out as rt_bvh4.h lays
    its 4."""
    _, binary, wide, _ = collapse_best(vertices, faces, params.binary, width, params.leaf_max, params.cost_node,
                                       params.cost_prim)
    (_, _, kind, c_lo, c_hi, c_node, c_count, c_offset, _, tri_base, tris, depth) = wide
    m = len(kind)
    node_rows = 2 * width - 1                 # any stride: the mirror only divides by it
    planes = np.empty((m, 6, width))
    valid = kind > 0
    for a in range(3):
        planes[:, 2 * a, :] = np.where(valid, c_lo[:, :, a], np.inf)
        planes[:, 2 * a + 1, :] = np.where(valid, c_hi[:, :, a], -np.inf)
    tri_row0 = node_rows * m
    first = tri_row0 + TRI_ROWS * (tri_base[:, None] + c_offset)
    refs = np.where(kind == 1, node_rows * c_node, ~((first << LEAF_BITS) | c_count))
    refs = np.where(valid, refs, ~0).astype(np.int64)
    return WideWalkArrays(planes, refs, np.asarray(tris, np.int64), tri_row0, int(depth), binary.bounds, node_rows)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", default="bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside")
    ap.add_argument("--kinds", default="diffuse,primary")
    ap.add_argument("--size", type=int, default=128)
    args = ap.parse_args()
    print("| view | rays | node visits a ray (4, 8 children) | boxes tested | triangle tests | node bytes read a ray "
          "| same t on every ray |")
    print("|---|---|---|---|---|---|---|")
    for view in args.views.split(","):
        scene = view_scene(view, args.size)
        arrays = {w: wide_walk_arrays(scene.vertices, scene.faces, w) for w in (4, 8)}
        for kind in args.kinds.split(","):
            rays = make_rays(view, kind, args.size, check_rays=1, scene=scene)
            c4, c8 = (traversal_counts_wide(arrays[w], scene.vertices, scene.faces, rays.origins, rays.directions)
                      for w in (4, 8))
            v4, v8 = c4[0].mean(), c8[0].mean()
            bytes4, bytes8 = NODE_BYTES[4] * v4, NODE_BYTES[8] * v8
            print(f"| {view} | {kind} | {v4:.1f} → {v8:.1f} ({(v8 / v4 - 1) * 100:+.0f} %) | "
                  f"{c4[1].mean():.1f} → {c8[1].mean():.1f} ({(c8[1].mean() / c4[1].mean() - 1) * 100:+.0f} %) | "
                  f"{c4[2].mean():.2f} → {c8[2].mean():.2f} | {bytes4:.0f} → {bytes8:.0f} "
                  f"({(bytes8 / bytes4 - 1) * 100:+.0f} %) | {'yes' if np.array_equal(c4[4], c8[4]) else 'NO'} |")


if __name__ == "__main__":
    main()
