"""Host counts of the binary BVH ("bvh"), the compressed 8-wide one ("bvh8") and the 4-wide one ("bvh4")
on the benchmark views: node visits, child boxes tested, triangle tests per ray, each from a host mirror
of its traversal (rtlab.accel.bvh_stats, bvh_wide_stats), and an instruction estimate from the SASS of each
traversal's node loop and triangle test (sm_90, nvcc 13.0, CUDA trace_rays with the watertight test:
rtlab's own count, not a measurement on the GPU; rerun with --node-instr after kernel changes).

    python experiments/bench_wide_bvh_quality.py --size 128 [--views sponza/inside,...]
"""
from __future__ import annotations

import argparse

import numpy as np

from rtlab.accel.bvh4 import load_or_build_bvh4
from rtlab.accel.bvh8 import load_or_build_bvh8
from rtlab.accel.bvh_wide_stats import traversal_counts_bvh4, traversal_counts_bvh8
from rtlab.accel.bvh_stats import traversal_bvh, traversal_counts
from rtlab.benches.rays import diffuse_rays, view_scene
from rtlab.reference import reference_trace
from rtlab.scene.model import camera_rays

# SASS instructions of one node visit (first to last instruction of the node loop) and, for every
# traversal alike, of one watertight triangle test's common path (no double fallback)
NODE_INSTR = {"bvh": 71, "bvh8": 268, "bvh4": 135}
TRI_INSTR = 75


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", default="bunny/far,bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--node-instr", default=",".join(f"{k}={v}" for k, v in NODE_INSTR.items()))
    args = ap.parse_args()
    cost = {k: float(v) for k, v in (kv.split("=") for kv in args.node_instr.split(","))}
    print(f"{'view':18} {'kind':8} | {'nodes':>17} {'boxes':>17} {'tris':>14} | est. instructions a ray "
          f"(bvh8, bvh4 / bvh)")
    for view in args.views.split(","):
        scene = view_scene(view, args.size)
        o, d = camera_rays(scene.camera)
        ref = reference_trace(scene.vertices, scene.faces, o, d)
        kinds = {"primary": (o, d), "diffuse": diffuse_rays(scene, o, d, ref.t, ref.tri)}
        b2 = traversal_bvh(scene.vertices, scene.faces)
        b8, _ = load_or_build_bvh8(scene.vertices, scene.faces)
        b4, _ = load_or_build_bvh4(scene.vertices, scene.faces)
        for kind, (O, D) in kinds.items():
            n2, t2, h2, _ = traversal_counts(b2, scene.vertices, scene.faces, O, D)
            n8, x8, t8, h8, _ = traversal_counts_bvh8(b8, scene.vertices, scene.faces, O, D)
            n4, x4, t4, h4, _ = traversal_counts_bvh4(b4, scene.vertices, scene.faces, O, D)
            est = {k: cost[k] * n.mean() + TRI_INSTR * t.mean() for k, n, t in (("bvh", n2, t2), ("bvh8", n8, t8),
                                                                                   ("bvh4", n4, t4))}
            same = min(np.mean(h8 == h2), np.mean(h4 == h2))
            print(f"{view:18} {kind:8} | {n2.mean():5.1f} {n8.mean():5.1f} {n4.mean():5.1f} "
                  f"{2 * n2.mean():5.1f} {x8.mean():5.1f} {x4.mean():5.1f} {t2.mean():4.1f} {t8.mean():4.1f} "
                  f"{t4.mean():4.1f} | {est['bvh']:5.0f} {est['bvh8']:5.0f} {est['bvh4']:5.0f} "
                  f"({est['bvh8'] / est['bvh']:.2f}, {est['bvh4'] / est['bvh']:.2f})"
                  + ("" if same > 0.999 else f"  ids agree on {same:.4f} only"), flush=True)


if __name__ == "__main__":
    main()
