"""kd-tree with and without flat cells against the BVH, on the paper's scenes and the default scene:
Table 2 columns, SAH cost, build time, and primary-ray Mrays/s of the same rays in the same run.

    python experiments/bench_kd_vs_bvh.py [--scenes default,bunny,sponza,kitchen,dragon] [--size 512]
                                         [--repeats 7] [--backend opencl]

For each scene: both kd-trees (KdBuildParams(flat_cells=False), the build without flat cells, and the
default) and the BVH are built first; then the preset camera's rays are rendered (render_primary,
stack traversal on each kd-tree, and the BVH traversal) in rounds, so that load on a shared machine
hits every variant alike; the median over rounds of each variant's launch time is reported.
The flat-cell tree's image is compared pixel by pixel with the other kd-tree's.
"""
from __future__ import annotations

import argparse
import statistics
import time


from rtlab import load_scene
from rtlab.accel.bvh import build_bvh
from rtlab.accel.kdtree import KdBuildParams, build_kdtree, kd_stats
from rtlab.backends import get_backend
from rtlab.device.kernels import Variant
from rtlab.device.rendering import render
from rtlab.device.device_scene import device_scene
from rtlab.scene.model import Scene

BUILDS = {"kd, no flat cells": KdBuildParams(flat_cells=False), "kd, flat cells": KdBuildParams()}


def bench_scene(name: str, size: int, repeats: int, backend) -> list[str]:
    scene = load_scene(name, size=size)
    trees, rows = {}, []
    for label, params in BUILDS.items():
        t0 = time.perf_counter()
        tree = build_kdtree(scene.vertices, scene.faces, params)
        seconds = time.perf_counter() - t0
        trees[label] = tree
        s = kd_stats(tree, scene.n_triangles)
        rows.append([name, label, f"{s['triangles']:,}", f"{s['nodes']:,}", f"{s['nonempty_leaves']:,}",
                     f"{s['refs_per_nonempty_leaf']:.2f}", f"{s['size_bytes'] / 1e6:.1f}", str(s["depth"]),
                     f"{s['sah_cost']:.1f}", f"{seconds:.2f}"])
    t0 = time.perf_counter()
    build_bvh(scene.vertices, scene.faces)
    rows.append([name, "bvh", f"{scene.n_triangles:,}", "", "", "", "", "", "", f"{time.perf_counter() - t0:.2f}"])
    # One scene object per tree, so that each upload keeps its own tree
    runs = {}
    for label, tree in trees.items():
        copy = Scene(**vars(scene))
        device_scene(copy, backend, tree)
        runs[label] = (copy, Variant.paper(traversal="stack"))
    runs["bvh"] = (Scene(**vars(scene)), Variant.paper(traversal="bvh"))
    times = {label: [] for label in runs}
    images = {}
    for _ in range(repeats):
        for label, (sc, variant) in runs.items():
            result = render(sc, backend, variant, repeats=1, warmup=0 if label in images else 1)
            times[label].append(result.kernel_ms[0])
            images[label] = result.image
    differ = int((images["kd, flat cells"] != images["kd, no flat cells"]).any(axis=2).sum())
    for row in rows:
        ms = statistics.median(times[row[1]])
        row += [f"{ms:.1f}", f"{size * size / ms / 1e3:.2f}"]
    rows[1].append(f"{differ} px differ")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="default,bunny,sponza,kitchen,dragon")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--backend", default="opencl")
    args = ap.parse_args()
    backend = get_backend(args.backend)
    cols = ["scene", "structure", "triangles", "nodes", "non-empty leaves", "refs/leaf", "size MB", "depth",
            "SAH cost", "build s", "median ms", "Mrays/s", "image"]
    print(f"{backend.name}: {backend.device_name}; {args.size}x{args.size}, preset cameras, median of "
          f"{args.repeats} rounds")
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for name in [s for s in args.scenes.split(",") if s]:
        for row in bench_scene(name, args.size, args.repeats, backend):
            print("| " + " | ".join(row + [""] * (len(cols) - len(row))) + " |", flush=True)


if __name__ == "__main__":
    main()
