"""BVH quality of several builds on the benchmark rays: the binned-SAH builder as it is against
spatial splits (SBVH) and other build parameters, measured on the host with the counting
traversal of rtlab.accel.bvh_stats (it walks the tree as kernels/shared/rt_bvh.h does).

    python experiments/bench_bvh_quality.py [--size 512] [--views bunny/far,sponza/inside]
        [--kinds primary,diffuse] [--builders current a=1e-5 a=1e-5,b=32 ...] [--no-check]

A builder is ``current`` (BvhBuildParams()) or comma-separated overrides of it: a = spatial_alpha,
g = spatial_growth, b = bins, ml = max_leaf_size, ct = cost_traversal, ci = cost_intersect. The
first builder is the baseline of the "vs" column. Columns: build seconds, references per usable
triangle, SAH cost (C_trav = C_isect = 1 for every build), mean inner-node visits and triangle
tests per ray, and the GPU cost proxy 65 nodes + 45 triangles per ray (instructions the CUDA kernel
spends on each), relative to the baseline's.

Check (unless --no-check): each build is uploaded in place of the "bvh" traversal's own and the
rays traced with rtlab.trace on OpenCL (PoCL on a CPU); "ids != base" counts rays whose triangle id
differs from the baseline build's (or t by more than 1e-6 relative), with the float64 reference's
verdict on those rays (rtlab.reference.compare_hits: a tie is a difference the ray cannot decide,
e.g. two coplanar triangles at the same t); "mism. vs ref" are mismatches against the reference
on the batch's checked subsample.
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from rtlab.accel.bvh import Bvh, BvhBuildParams, _usable_boxes, build_bvh
from rtlab.accel.bvh_stats import NODE_COST, TRI_COST, sah_cost, traversal_counts
from rtlab.benches.rays import make_rays

VIEWS = ("bunny/far", "bunny/fill", "dragon/fill", "sponza/inside", "kitchen/inside", "conference/inside")
KEYS = {"a": "spatial_alpha", "g": "spatial_growth", "b": "bins", "ml": "max_leaf_size", "ct": "cost_traversal",
        "ci": "cost_intersect"}
BUILDERS = ("current", "a=1e-5", "a=1e-4", "a=1e-3", "a=1e-5,b=32")
STACK = 64                       # one compiled program for every build's depth


def parse_builder(spec: str) -> BvhBuildParams:
    params = BvhBuildParams()
    if spec == "current":
        return params
    changes = {}
    for item in spec.split(","):
        key, value = item.split("=")
        field = KEYS[key.strip()]
        changes[field] = int(value) if field in ("bins", "max_leaf_size") else float(value)
    return replace(params, **changes)


def use_bvh(ds, bvh: Bvh) -> None:
    """Make the uploaded scene ``ds`` trace the "bvh" traversal on ``bvh``."""
    import rtlab.device.device_scene as device_scene_module
    arrays = device_scene_module.AccelArrays(device_scene_module.NO_NODES, bvh.node_data(), bvh.objects,
                                             bvh.bounds, bvh.depth + 1)
    device_scene_module.ACCEL_BUILDERS["bvh"] = lambda scene, tree: arrays
    ds.accel.pop("bvh", None)


def trace_with(batch, bvh: Bvh, backend):
    from rtlab.device.kernels import Variant
    from rtlab.device.device_scene import device_scene
    from rtlab.device.tracing import trace
    ds = device_scene(batch.scene, backend)
    use_bvh(ds, bvh)
    return trace(batch.scene, batch.origins, batch.directions, backend, Variant.paper(traversal="bvh"), min_stack_size=STACK)


def differ_vs_reference(batch, got, rays) -> str:
    """The float64 reference's verdict on ``rays`` of a trace: mismatches and ties."""
    from rtlab.reference import compare_hits, reference_trace
    o, d = batch.origins[rays], batch.directions[rays]
    ref = reference_trace(batch.scene.vertices, batch.scene.faces, o, d)
    c = compare_hits(ref, got.tri[rays], got.t[rays], batch.scene.vertices, batch.scene.faces, o, d)
    return f"{c.n_mismatch} mism., {c.n_ties} ties"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--views", default=",".join(VIEWS))
    ap.add_argument("--kinds", default="primary,diffuse")
    ap.add_argument("--builders", nargs="+", default=list(BUILDERS))
    ap.add_argument("--no-check", action="store_true", help="skip the trace() check on OpenCL")
    ap.add_argument("--backend", default="opencl")
    args = ap.parse_args()
    builders = [(spec, parse_builder(spec)) for spec in args.builders]
    backend = None
    if not args.no_check:
        from rtlab.backends import get_backend
        backend = get_backend(args.backend)
    builds: dict[tuple[str, str], Bvh] = {}
    header = ("view", "kind", "builder", "build s", "refs/tris", "SAH", "nodes/ray", "tris/ray", "proxy", "vs base",
              "ids != base", "mism. vs ref")
    rows = []
    print(" | ".join(header), flush=True)
    for view in args.views.split(","):
        for kind in args.kinds.split(","):
            batch = make_rays(view, kind, args.size)
            scene = batch.scene
            n_usable = int(_usable_boxes(scene.vertices.astype(np.float32), scene.faces.astype(np.int64))[2].sum())
            base_proxy, base_hits = None, None
            for spec, params in builders:
                key = (view.split("/")[0], spec)
                if key not in builds:
                    builds[key] = build_bvh(scene.vertices, scene.faces, params)
                bvh = builds[key]
                nodes, tris, _, _ = traversal_counts(bvh, scene.vertices, scene.faces, batch.origins,
                                                     batch.directions)
                proxy = NODE_COST * nodes.mean() + TRI_COST * tris.mean()
                base_proxy = base_proxy or proxy
                check, mism = "-", "-"
                if backend is not None:
                    got = trace_with(batch, bvh, backend)
                    if base_hits is None:
                        base_hits = got
                    same_t = np.isclose(got.t, base_hits.t, rtol=1e-6, atol=0) | (got.t == base_hits.t)
                    differ = np.flatnonzero((got.tri != base_hits.tri) | ~same_t)
                    check = str(len(differ))
                    if len(differ):
                        check += f" ({differ_vs_reference(batch, got, differ)})"
                    mism = str(batch.error(got.tri, got.t)["mismatches"])
                row = (view, kind, spec, f"{bvh.build_seconds:.2f}", f"{len(bvh.objects) / max(1, n_usable):.3f}",
                       f"{sah_cost(bvh):.1f}", f"{nodes.mean():.2f}", f"{tris.mean():.2f}", f"{proxy:.0f}",
                       f"{proxy / base_proxy:.3f}", check, mism)
                rows.append(row)
                print(" | ".join(row), flush=True)
    print()
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for row in rows:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"\n{time.perf_counter() - t0:.0f} s")
