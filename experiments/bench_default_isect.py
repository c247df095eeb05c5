"""The library's default triangle test: Möller-Trumbore (the paper's) against the watertight
test (Woop, Benthin & Wald 2013) on the benchmark views, by edge/vertex leaks and by speed.

    python experiments/bench_default_isect.py [--views bunny/far,sponza/inside] [--size 256]
        [--leak-rays 20000] [--repeat 5] [--backend opencl] [--traversals stack,bvh] [--md out.md]

Per view (rtlab.scene.bench_camera, the rays the peers' figures use) and traversal, for each test:
  trace ms     trace() of the view's primary rays, kernel time, best of --repeat (tests alternating)
  render ms    render() (primary rays, simple shading), kernel time, best of --repeat
  mism.        primary-ray mismatches against the float64 reference (ties apart)
  through      of --leak-rays rays from the eye aimed at vertices and at points k/8 along edges of
               the triangles the view sees (d = p - eye rounded to float32, as a renderer aims), the
               rays that miss or hit beyond the reference's hit (by > 1e-4 relative): they went
               through the surface at an edge or vertex. Silhouette edges let a few through either
               test (float32 rounding of an aimed ray): the watertight column is that floor.
A closed, rotated unit cube with rays from inside aimed at its edges and vertices is the first row:
there every ray must hit.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from rtlab.backends import get_backend
from rtlab.device.kernels import Variant
from rtlab.device.rendering import render
from rtlab.device.tracing import trace
from rtlab.reference import compare_hits, reference_trace
from rtlab.scene import load_scene
from rtlab.scene.model import camera_rays
from rtlab.scene.presets import bench_camera, bench_view_names

TESTS = ("moller", "watertight")


def aimed_rays(scene, eye, n, seed=13):
    """Rays from eye to vertices (a third) and to points k/8 along edges of the triangles the eye
    sees; float32 d = p - eye."""
    rng = np.random.default_rng(seed)
    o, d = camera_rays(scene.camera)
    seen = np.unique(reference_trace(scene.vertices, scene.faces, o, d).tri)
    seen = seen[seen >= 0]
    tris = scene.faces[rng.choice(seen, n)].astype(np.int64)
    v = scene.vertices.astype(np.float64)
    corner = rng.integers(0, 3, n)
    a, b = tris[np.arange(n), corner], tris[np.arange(n), (corner + 1) % 3]
    k = np.where(np.arange(n) < n // 3, 0, rng.integers(1, 8, n)) / 8.0
    target = v[a] * (1 - k[:, None]) + v[b] * k[:, None]
    origins = np.broadcast_to(np.asarray(eye, np.float32), (n, 3)).copy()
    return origins, (target.astype(np.float32) - origins).astype(np.float32)


def cube_rays(n, seed=14):
    """A closed unit cube, rotated (corners rounded to float32), and rays from random points inside
    it aimed at its vertices (a third) and at points k/8 along its edges, d = p - o in float32:
    every ray must hit: a miss is a crack in the test (docs/results.md has the counts)."""
    from rtlab.robustness import box_mesh, case_scene
    rng = np.random.default_rng(seed)
    v, f = box_mesh((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
    rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    scene = case_scene("cube", v @ rotation.T + (0.3, 0.2, 0.1), f)
    corners = scene.vertices.astype(np.float64)[scene.faces]
    pick = rng.integers(0, len(corners), n)
    e = rng.integers(0, 3, n)
    k = np.where(np.arange(n) < n // 3, 0, rng.integers(1, 8, n)) / 8.0
    p = corners[pick, e] * (1 - k[:, None]) + corners[pick, (e + 1) % 3] * k[:, None]
    centre = corners.reshape(-1, 3).mean(0)
    o = (centre + rng.uniform(-0.3, 0.3, (n, 3))).astype(np.float32)
    return scene, o, (p.astype(np.float32) - o).astype(np.float32)


def through(ref, got) -> int:
    r_hit, k_hit = ref.tri >= 0, got.tri >= 0
    with np.errstate(invalid="ignore"):
        farther = k_hit & r_hit & (got.t > ref.t * (1 + 1e-4))
    return int(np.sum(r_hit & ~k_hit) + np.sum(farther))


def best_ms(fn, repeat):
    return min(fn() for _ in range(repeat))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--views", default=",".join(bench_view_names()))
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--leak-rays", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--backend", default="opencl")
    ap.add_argument("--device", default=None)
    ap.add_argument("--traversals", default="stack,bvh")
    ap.add_argument("--md", default=None)
    args = ap.parse_args()
    backend = get_backend(args.backend, args.device)
    traversals = args.traversals.split(",")
    head = ("| view | traversal | test | trace ms | Mrays/s | render ms | mism. | through / aimed |\n"
            "|---|---|---|---|---|---|---|---|")
    lines = [f"backend {backend.name}, device {backend.device_name}, {args.size}², best of {args.repeat}, "
             f"{time.strftime('%Y-%m-%d')}", "", head]
    scene, o, d = cube_rays(args.leak_rays)
    ref = reference_trace(scene.vertices, scene.faces, o, d)
    assert np.all(ref.tri >= 0)
    for traversal in traversals:
        for isect in TESTS:
            got = trace(scene, o, d, backend=backend, variant=Variant(traversal, isect))
            lines.append(f"| cube edges/vertices | {traversal} | {isect} | - | - | - | - | "
                         f"{through(ref, got):,} / {len(o):,} |")
            print(lines[-1], flush=True)
    for view in args.views.split(","):
        name = view.split("/")[0]
        scene = load_scene(name, size=args.size)
        scene.camera = bench_camera(view, args.size)
        o, d = camera_rays(scene.camera)
        ref = reference_trace(scene.vertices, scene.faces, o, d)
        ao, ad = aimed_rays(scene, scene.camera.eye, args.leak_rays)
        aref = reference_trace(scene.vertices, scene.faces, ao, ad)
        for traversal in traversals:
            variants = {isect: Variant(traversal, isect) for isect in TESTS}
            for v in variants.values():                  # compile and warm up
                trace(scene, o[:64], d[:64], backend=backend, variant=v)
                render(scene, backend, v)
            trace_ms = {k: [] for k in TESTS}
            render_ms = {k: [] for k in TESTS}
            for _ in range(args.repeat):                 # alternate, so load on the machine hits both
                for isect, v in variants.items():
                    trace_ms[isect].append(trace(scene, o, d, backend=backend, variant=v).kernel_ms)
                    render_ms[isect].append(render(scene, backend, v).median_ms)
            for isect, v in variants.items():
                got = trace(scene, o, d, backend=backend, variant=v)
                c = compare_hits(ref, got.tri, got.t, scene.vertices, scene.faces, o, d)
                aimed = trace(scene, ao, ad, backend=backend, variant=v)
                ms = min(trace_ms[isect])
                lines.append(f"| {view} | {traversal} | {isect} | {ms:.1f} | {len(o) / ms / 1e3:.2f} | "
                             f"{min(render_ms[isect]):.1f} | {c.n_mismatch} | {through(aref, aimed):,} / {len(ao):,} |")
                print(lines[-1], flush=True)
    text = "\n".join(lines) + "\n"
    if args.md:
        with open(args.md, "a") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()
