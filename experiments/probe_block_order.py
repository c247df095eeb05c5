"""Render-kernel throughput (primary rays, the benchmark views) for launch shapes and ray orders:
which threads share a warp. Prints one JSON line per (view, backend, traversal, block, order).
    python experiments/probe_block_order.py --views sponza/inside,conference/inside --backends cuda
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rtlab.backends import get_backend  # noqa: E402
from rtlab.benches.rays import view_scene  # noqa: E402
from rtlab.device.kernels import Variant  # noqa: E402
from rtlab.device.rendering import render  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--views", default="bunny/far,bunny/fill,sponza/inside,conference/inside")
ap.add_argument("--backends", default="cuda,opencl:NVIDIA")
ap.add_argument("--traversals", default="bvh,stack")
ap.add_argument("--shapes", default="32x4,8x4,8x8,16x8,8x16,8x32,32x4:morton,16x8:morton,8x8:morton")
ap.add_argument("--size", type=int, default=1024)
ap.add_argument("--repeats", type=int, default=22)
a = ap.parse_args()
backends = [get_backend(s.split(":")[0], (s.split(":") + [None])[1]) for s in a.backends.split(",")]
for view in a.views.split(","):
    scene = view_scene(view, a.size)
    for be in backends:
        for trav in a.traversals.split(","):
            for shape in a.shapes.split(","):
                dims, _, order = shape.partition(":")
                bx, by = (int(v) for v in dims.split("x"))
                v = Variant.paper(traversal=trav, block=(bx, by), ray_order=order or "rows")
                r = render(scene, be, v, repeats=a.repeats, warmup=3)
                print(json.dumps({"view": view, "backend": be.name, "traversal": trav, "shape": shape,
                                  "mrays": round(r.mrays_per_s)}), flush=True)
