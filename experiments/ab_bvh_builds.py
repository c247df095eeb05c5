"""A/B of BVH build parameters for the GPU default's "bvh" traversal, on the benchmark rays, the
configurations alternating round by round on the same rays (as ab_trace_configs.py does), with the
tree's SAH cost, node count and the error column.

    python experiments/ab_bvh_builds.py --backend cuda --kinds primary,diffuse --size 1024 \
        --configs "ml8;ml4;ct0.5;ct2" [--views ...] [--rounds 4] [--repeats 5]

A configuration changes rtlab.accel.bvh.BvhBuildParams for both builds that traversal_bvh chooses
between (plain and spatial splits, kept by the same SAH rule): ``mlN`` max_leaf_size N, ``ctX``
cost_traversal X, ``ciX`` cost_intersect X, ``binsN``; parts joined by ``+`` (``ml4+ct0.5``); ``base``
the builder's defaults. Each configuration gets its own DeviceScene, so the trees do not mix.

With ``--family bvh4`` the configurations change the 4-wide tree's collapse instead
(rtlab.accel.bvh4.Bvh4BuildParams, run with the "bvh4" traversal): ``cnX`` cost_node, ``cpX``
cost_prim, ``lmN`` leaf_max, ``plain`` / ``split`` the binary tree it collapses (default: the cheaper).
"""
from __future__ import annotations

import dataclasses
from unittest import mock

import numpy as np

from ab_trace_configs import ab_arguments, ab_batches, print_row   # experiments/ is on the path as a script
from rtlab.accel import bvh_stats
from rtlab.accel.bvh import BvhBuildParams, load_or_build_bvh
from rtlab.accel.bvh4 import Bvh4BuildParams, load_or_build_bvh4
from rtlab.backends import get_backend
from rtlab.benches.rays import peer_figures
from rtlab.device import device_scene as device_scene_module
from rtlab.device import tracing
from rtlab.device.device_scene import AccelArrays, DeviceScene, NO_NODES
from rtlab.device.tracing import trace


def parse_params(text: str) -> dict:
    out = {}
    for part in text.split("+"):
        if part == "base":
            continue
        if part.startswith("gain"):          # the SAH gain that keeps the spatial-split tree
            out["gain"] = float(part[4:])
            continue
        for prefix, field, kind in (("ml", "max_leaf_size", int), ("ct", "cost_traversal", float),
                                    ("ci", "cost_intersect", float), ("bins", "bins", int)):
            if part.startswith(prefix):
                out[field] = kind(part[len(prefix):])
                break
        else:
            raise SystemExit(f"unknown configuration part {part!r}")
    return out


def parse_bvh4_params(text: str) -> dict:
    out = {}
    for part in text.split("+"):
        if part == "base":
            continue
        if part in ("plain", "split"):
            out["binary"] = part
            continue
        for prefix, field, kind in (("cn", "cost_node", float), ("cp", "cost_prim", float), ("lm", "leaf_max", int)):
            if part.startswith(prefix):
                out[field] = kind(part[len(prefix):])
                break
        else:
            raise SystemExit(f"unknown configuration part {part!r}")
    return out


def upload_bvh4(backend, scene, changes: dict):
    params = dataclasses.replace(Bvh4BuildParams(), **changes)
    b, _ = load_or_build_bvh4(scene.vertices, scene.faces, params)

    def builder(scene_, tree_):
        return AccelArrays(NO_NODES, b.rows, np.zeros(1, np.int32), b.bounds, 3 * b.depth + 1)

    ds = DeviceScene.upload(backend, scene, None)
    with mock.patch.dict(device_scene_module.ACCEL_BUILDERS, {"bvh4": builder}):
        ds._accel("bvh4")
    return ds, builder, f"{b.binary} tree collapsed, cost {b.cost:.2f}, {b.n_nodes:,} nodes, depth {b.depth}"


def tree_for(scene, changes: dict):
    changes = dict(changes)
    gain = changes.pop("gain", bvh_stats.SPLIT_MIN_GAIN)
    plain = dataclasses.replace(BvhBuildParams(), **changes)
    split = dataclasses.replace(bvh_stats.SPLIT_BUILD, **changes)
    a, _ = load_or_build_bvh(scene.vertices, scene.faces, plain)
    b, _ = load_or_build_bvh(scene.vertices, scene.faces, split)
    pick = b if bvh_stats.sah_cost(b) <= (1.0 - gain) * bvh_stats.sah_cost(a) else a
    return pick, f"plain SAH {bvh_stats.sah_cost(a):.2f}, split SAH {bvh_stats.sah_cost(b):.2f}"


def upload(backend, scene, changes: dict):
    bvh, both = tree_for(scene, changes)

    def builder(scene_, tree_):
        return AccelArrays(NO_NODES, bvh.node_data(), bvh.objects, bvh.bounds, bvh.depth + 1)

    ds = DeviceScene.upload(backend, scene, None)
    with mock.patch.dict(device_scene_module.ACCEL_BUILDERS, {"bvh": builder}):
        ds._accel("bvh")                 # the tree uploaded now, under this configuration's builder
    info = (f"{'split' if bvh.params.spatial else 'plain'}, SAH {bvh_stats.sah_cost(bvh):.1f}, "
            f"{bvh.n_nodes:,} nodes, {len(bvh.objects):,} refs ({both})")
    return ds, builder, info


def main(argv=None) -> None:
    ap = ab_arguments(__doc__.split("\n")[0], "base;ml4", 4)
    ap.add_argument("--variant", default=None, help="a variant reading the family's tree (default: the backend's "
                                                     "default with the family's traversal)")
    ap.add_argument("--family", default="bvh", choices=("bvh", "bvh4"), help="the tree the configurations change")
    a = ap.parse_args(argv)
    backend = get_backend(a.backend, a.device)
    variant = tracing.resolve_variant(a.variant or a.family, backend, rays=True)
    parse, build = (parse_params, upload) if a.family == "bvh" else (parse_bvh4_params, upload_bvh4)
    configs = [(c, parse(c)) for c in a.configs.split(";")]
    peers = peer_figures()
    scenes = {}
    for batch in ab_batches(a, backend, f"variant {variant.label()}", [c for c, _ in configs]):
        key = batch.view.split("/")[0]
        if key not in scenes:
            scenes[key] = {c: build(backend, batch.scene, ch) for c, ch in configs}
            for c, (_, _, info) in scenes[key].items():
                print(f"<!-- {key} {c}: {info} -->", flush=True)
        width = batch.size if batch.kind == "primary" else None
        best = {c: [] for c, _ in configs}
        last = {}
        for _ in range(a.rounds):
            for c, _ in configs:
                ds, builder, _ = scenes[key][c]
                with mock.patch.object(tracing, "device_scene", lambda *_args, **_kw: ds), \
                        mock.patch.dict(device_scene_module.ACCEL_BUILDERS, {a.family: builder}):
                    r = trace(batch.scene, batch.origins, batch.directions, backend, variant,
                              repeats=a.repeats, warmup=1, width=width)
                best[c].append(min(r.launches_ms))
                last[c] = r
        print_row(batch, best, last, peers.get((batch.view, batch.kind, a.size), {}).get("best"))

if __name__ == "__main__":
    main()
