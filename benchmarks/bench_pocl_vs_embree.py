"""PoCL on this machine's CPU cores against Embree's single-thread figure (issue 7).

Embree (embreex 4.4, one thread) measured 16.4 Mrays/s on BUNNY at 1024² with the camera at 2.5× the
bounding-box diagonal on the 2-core development machine (../shared/bench/README.md). This prints
rtlab's PoCL throughput for the same view: the render kernel (camera rays in the kernel, shading) and
the trace API's kernel (rays from the host), device-event time, median of several launches, with the
error against the float64 reference beside it.

    python benchmarks/bench_pocl_vs_embree.py [--size 1024] [--repeats 5]
"""
from __future__ import annotations

import argparse
import os

import numpy as np

import rtlab
from rtlab.backends import get_backend
from rtlab.check import check_render
from rtlab.rendering import render
from rtlab.scene.model import Camera
from rtlab.tracing import camera_rays, trace

EMBREE_MRAYS = 16.4


def embree_view(scene, size: int) -> Camera:
    lo, hi = scene.bounds().astype(np.float64)
    centre, diag = (lo + hi) / 2, np.linalg.norm(hi - lo)
    eye = centre + np.array([0.0, 0.0, 2.5 * diag])
    return Camera(tuple(eye), tuple(centre), fov_deg=40.0, width=size, height=size)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    backend = get_backend("opencl", os.environ.get("RTLAB_DEVICE"))
    scene = rtlab.load_scene("bunny")
    scene.camera = embree_view(scene, args.size)
    r = render(scene, backend, repeats=args.repeats, warmup=1, write_hits=False)
    checked = render(scene, backend, repeats=1, write_hits=True)
    err = check_render(scene, checked, scene.camera).summary()
    o, d = camera_rays(scene.camera)
    times = [trace(scene, o, d, backend=backend).kernel_ms for _ in range(args.repeats + 1)][1:]
    trace_mrays = o.shape[0] / (np.median(times) * 1e-3) / 1e6
    print(f"device: {backend.describe()}; cores: {os.cpu_count()}; load: {os.getloadavg()[0]:.2f}")
    print(f"BUNNY {args.size}² at 2.5x the diagonal: render {r.mrays_per_s:.1f} Mrays/s "
          f"({r.mrays_per_s / EMBREE_MRAYS:.2f}x Embree 1 thread), trace {trace_mrays:.1f} Mrays/s "
          f"({trace_mrays / EMBREE_MRAYS:.2f}x); median of {args.repeats}")
    print(f"error vs float64 reference (render): {err}")


if __name__ == "__main__":
    main()
