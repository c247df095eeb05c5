"""Build time, cached reload time and Table 2 statistics of the SAH kd-tree on the paper's scenes.

    python experiments/bench_kdtree_build.py [--scenes bunny,dragon] [--repeat 3] [--dragon-repeat 1]

For each scene found by rtlab.paths.find_scene_file: a JIT warm-up, the median of --repeat builds
(--dragon-repeat for DRAGON), then the median of 3 reloads from a fresh on-disk cache (hashing the
mesh included), printed beside the paper's Table 2 row (Shih et al. 2009). Size counts 8 B a
node, 4 B an object-list entry and 96 B a triangle (3 float4 vertices + 3 float4 normals), in MB
of 10^6 bytes, as the paper's sizes do.
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time

import numba
import numpy as np
import trimesh

from rtlab.accel.cache import load_or_build_kdtree
from rtlab.accel.kdtree import KdBuildParams, build_kdtree, kd_stats
from rtlab.paths import find_scene_file

# name -> (file, paper's Table 2 row: triangles, nodes, non-empty leaves, links, size MB)
SCENES = {
    "bunny": ("bunny.ply", (69_451, 379_713, 120_511, 2.72, 11)),
    "sponza": ("sponza/sponza.obj", (66_454, 292_195, 124_059, 2.63, 10)),
    "kitchen": ("kitchen/kitchen.obj", (103_343, 362_585, 146_253, 2.63, 14)),
    "dragon": ("dragon.ply", (871_414, 1_687_237, 607_852, 2.59, 103)),
    "conference": ("conference/conference.obj", None),
}

COLUMNS = ["scene", "triangles", "nodes", "non-empty leaves", "refs/leaf", "size MB", "depth",
           "SAH cost", "build s", "reload s"]


def load_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.load(path, process=False, force="mesh")
    return np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.int32)


def time_median(fn, repeat: int) -> tuple[float, object]:
    times, result = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), result


def bench_scene(name: str, path, repeat: int, params: KdBuildParams) -> list[list[str]]:
    vertices, faces = load_mesh(path)
    build_s, tree = time_median(lambda: build_kdtree(vertices, faces, params), repeat)
    with tempfile.TemporaryDirectory() as cache_dir:
        load_or_build_kdtree(vertices, faces, params, cache_dir=cache_dir)
        reload_s, (cached, from_cache) = time_median(
            lambda: load_or_build_kdtree(vertices, faces, params, cache_dir=cache_dir), 3)
    assert from_cache and np.array_equal(cached.nodes, tree.nodes)
    s = kd_stats(tree, len(faces))
    rows = [[name.upper(), f"{s['triangles']:,}", f"{s['nodes']:,}", f"{s['nonempty_leaves']:,}",
             f"{s['refs_per_nonempty_leaf']:.2f}", f"{s['size_bytes'] / 1e6:.1f}", str(s["depth"]),
             f"{s['sah_cost']:.1f}", f"{build_s:.2f}", f"{reload_s:.3f}"]]
    paper = SCENES[name][1]
    if paper:
        tris, nodes, nonempty, links, size = paper
        rows.append(["  paper", f"{tris:,}", f"{nodes:,}", f"{nonempty:,}", f"{links:.2f}", f"{size}",
                     "", "", "", ""])
    return rows


def print_table(rows: list[list[str]], title: str) -> None:
    try:
        from rich.console import Console
        from rich.table import Table
    except ImportError:
        widths = [max(len(r[i]) for r in [COLUMNS] + rows) for i in range(len(COLUMNS))]
        print(title)
        for r in [COLUMNS] + rows:
            print("  ".join(c.rjust(w) for c, w in zip(r, widths)))
        return
    table = Table(title=title)
    for i, col in enumerate(COLUMNS):
        table.add_column(col, justify="left" if i == 0 else "right")
    for r in rows:
        table.add_row(*r, style="dim" if r[0].startswith("  ") else None)
    Console(width=160).print(table)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=",".join(SCENES), help="comma-separated subset of " + ",".join(SCENES))
    ap.add_argument("--repeat", type=int, default=3, help="builds per scene (median reported)")
    ap.add_argument("--dragon-repeat", type=int, default=3, help="builds of DRAGON")
    args = ap.parse_args()

    params = KdBuildParams()
    t0 = time.perf_counter()
    warm = trimesh.creation.icosphere(subdivisions=3)
    build_kdtree(np.asarray(warm.vertices, np.float32), np.asarray(warm.faces, np.int32), params)
    warmup_s = time.perf_counter() - t0

    rows = []
    for name in args.scenes.split(","):
        path = find_scene_file(SCENES[name][0])
        if path is None:
            print(f"{name}: {SCENES[name][0]} not found, skipped")
            continue
        repeat = args.dragon_repeat if name == "dragon" else args.repeat
        rows += bench_scene(name, path, repeat, params)
    print_table(rows, f"SAH kd-tree build ({params.key()}; {os.cpu_count()} CPUs, "
                      f"{numba.get_num_threads()} numba threads, {numba.threading_layer()}; "
                      f"JIT warm-up {warmup_s:.1f} s)")


if __name__ == "__main__":
    main()
