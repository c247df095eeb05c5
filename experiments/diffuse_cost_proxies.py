"""Could a cheap per-ray estimate start the costliest diffuse rays first (and so shorten the ray fetch's
tail, docs/results.md "The ray fetch's tail")? Host-only: each diffuse ray's cost from the float64 mirror
of the 4-wide walk (node visits x NODE_INSTR + triangle tests x TRI_INSTR: about the SASS instructions
of a node visit and a triangle test, `nvcc_kernel_report.py --node-loop 7`), against proxies a device could compute before the walk, and what ordering
warps (groups of 32 consecutive rays, as the fetch takes them) by each would leave at the end of the
launch, where the tail is.

    python experiments/diffuse_cost_proxies.py --views dragon/fill,conference/inside --size 256

Proxies: the segment's length in the scene box (t_exit); the triangles in the grid cell of the origin;
the triangles in the grid cells at 8 steps along the ray (a 32^3 grid of triangle centroids, one step a
cell). "oracle" ranks by the mirror's own cost: the bound of any estimate.
"""
from __future__ import annotations

import argparse

import numpy as np

from rtlab.accel.bvh4 import load_or_build_bvh4
from rtlab.accel.bvh_wide_stats import traversal_counts_bvh4
from rtlab.benches.rays import diffuse_rays, view_scene
from rtlab.reference import reference_trace
from rtlab.scene.model import camera_rays

NODE_INSTR, TRI_INSTR = 109, 70
GRID = 32
WARP = 32


def proxies(scene, origins, directions) -> dict[str, np.ndarray]:
    lo, hi = scene.vertices.min(0).astype(np.float64), scene.vertices.max(0).astype(np.float64)
    d = np.where(np.abs(directions) > 1e-12, directions, 1e-12)
    t_exit = np.maximum((lo - origins) / d, (hi - origins) / d).min(1)
    cells = np.clip(((scene.vertices[scene.faces].mean(1) - lo) / (hi - lo) * GRID).astype(int), 0, GRID - 1)
    grid = np.zeros((GRID,) * 3)
    np.add.at(grid, tuple(cells.T), 1)

    def at(p):
        return grid[tuple(np.clip(((p - lo) / (hi - lo) * GRID).astype(int), 0, GRID - 1).T)]
    step = (hi - lo).max() / GRID
    along = sum(at(origins + directions * step * k) for k in range(1, 9))
    return {"t_exit": t_exit, "triangles at origin": at(origins), "triangles along ray": along}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", default="dragon/fill,conference/inside")
    ap.add_argument("--size", type=int, default=256)
    args = ap.parse_args()
    for view in args.views.split(","):
        scene = view_scene(view, args.size)
        o, d = camera_rays(scene.camera)
        ref = reference_trace(scene.vertices, scene.faces, o, d)
        O, D = (np.asarray(a, np.float64) for a in diffuse_rays(scene, o, d, ref.t, ref.tri))
        b4, _ = load_or_build_bvh4(scene.vertices, scene.faces)
        nodes, _, tris = traversal_counts_bvh4(b4, scene.vertices, scene.faces, O, D)[:3]
        cost = NODE_INSTR * np.asarray(nodes, np.float64) + TRI_INSTR * np.asarray(tris, np.float64)
        top = cost >= np.percentile(cost, 99)
        print(f"\n{view}, {len(O)} diffuse rays at {args.size}²: cost mean {cost.mean():.0f}, "
              f"99th percentile {np.percentile(cost, 99):.0f}, max {cost.max():.0f}")
        keys = proxies(scene, O, D)
        print("| proxy | correlation with cost | costliest 1 % in its top 10 % |")
        print("|---|---:|---:|")
        for name, p in keys.items():
            print(f"| {name} | {np.corrcoef(p, cost)[0, 1]:+.2f} | {np.mean((p >= np.percentile(p, 90))[top]):.2f} |")
        m = len(O) // WARP * WARP
        group_cost = cost[:m].reshape(-1, WARP).max(1)
        ranks = {"as given": None, "oracle": group_cost,
                 **{f"{k} (warp's sum)": p[:m].reshape(-1, WARP).sum(1) for k, p in keys.items()}}
        print("\n| warps ordered by | first | costliest warp in the last 20 % of the launch "
              "(x the costliest warp) | in the last 10 % |")
        print("|---|---:|---:|---:|")
        for name, key in ranks.items():
            for pct in ((10, 30) if key is not None else (0,)):
                order = np.arange(len(group_cost))
                if key is not None:
                    heavy = np.argsort(-key, kind="stable")[:int(len(group_cost) * pct / 100)]
                    order = np.concatenate([heavy, np.setdiff1d(order, heavy)])
                last = group_cost[order]
                print(f"| {name} | {pct} % | {last[-len(last) // 5:].max() / group_cost.max():.2f} | "
                      f"{last[-len(last) // 10:].max() / group_cost.max():.2f} |")


if __name__ == "__main__":
    main()
