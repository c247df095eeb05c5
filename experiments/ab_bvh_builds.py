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
cost_prim, ``lmN`` leaf_max, ``plain`` / ``split`` the binary tree it collapses (default: the cheaper),
``strideN`` each node padded to N float4 rows (the layout, not the tree). ``--defines NAME=V,...``
compiles the same -D into every configuration's kernels.
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
from rtlab.device.device_scene import DeviceScene
from rtlab.device.tracing import trace


# Configuration parts: prefix -> (field, type), and whole words -> (field, value)
BVH_PREFIXES = {"ml": ("max_leaf_size", int), "ct": ("cost_traversal", float), "ci": ("cost_intersect", float),
                "bins": ("bins", int), "gain": ("gain", float)}       # gain: the SAH gain that keeps the split tree
BVH4_PREFIXES = {"cn": ("cost_node", float), "cp": ("cost_prim", float), "lm": ("leaf_max", int),
                 "stride": ("stride", int)}
BVH4_WORDS = {"plain": ("binary", "plain"), "split": ("binary", "split")}


def parse_params(text: str, prefixes: dict = BVH_PREFIXES, words: dict | None = None) -> dict:
    """A configuration's parts joined by "+" ("base": none) -> the build parameters they change."""
    out = {}
    for part in text.split("+"):
        if part == "base":
            continue
        if words and part in words:
            field, value = words[part]
            out[field] = value
            continue
        prefix = next((p for p in prefixes if part.startswith(p)), None)
        if prefix is None:
            raise SystemExit(f"unknown configuration part {part!r}")
        field, kind = prefixes[prefix]
        out[field] = kind(part[len(prefix):])
    return out


def tree_for(scene, changes: dict):
    changes = dict(changes)
    gain = changes.pop("gain", bvh_stats.SPLIT_MIN_GAIN)
    plain = dataclasses.replace(BvhBuildParams(), **changes)
    split = dataclasses.replace(bvh_stats.SPLIT_BUILD, **changes)
    a, _ = load_or_build_bvh(scene.vertices, scene.faces, plain)
    b, _ = load_or_build_bvh(scene.vertices, scene.faces, split)
    pick = b if bvh_stats.sah_cost(b) <= (1.0 - gain) * bvh_stats.sah_cost(a) else a
    return pick, f"plain SAH {bvh_stats.sah_cost(a):.2f}, split SAH {bvh_stats.sah_cost(b):.2f}"


def bvh_build(scene, changes: dict):
    """(upload arrays, description) of the binary tree under ``changes``."""
    bvh, both = tree_for(scene, changes)
    info = (f"{'split' if bvh.params.spatial else 'plain'}, SAH {bvh_stats.sah_cost(bvh):.1f}, "
            f"{bvh.n_nodes:,} nodes, {len(bvh.objects):,} refs ({both})")
    return device_scene_module.bvh_accel(scene, None, bvh), info


def padded_rows(b, stride: int):
    """The 4-wide tree's rows with each node padded to ``stride`` rows (8: one 128-B line, node starts
    aligned), the refs rewritten to the new rows; the kernels read any stride, as their refs say."""
    from rtlab.accel.bvh4 import LEAF_BITS, NODE_ROWS
    m, tri0 = b.n_nodes, b.tri_row0
    rows = np.zeros((stride * m + len(b.rows) - tri0, 4), np.float32)
    nodes = rows[:stride * m].reshape(m, stride, 4)
    nodes[:, :NODE_ROWS] = b.rows[:tri0].reshape(m, NODE_ROWS, 4)
    rows[stride * m:] = b.rows[tri0:]
    refs = nodes.view(np.int32)[:, 6, :].astype(np.int64)
    # a leaf ref is ~(first row << LEAF_BITS | count): its triangles moving down by `shift` rows lowers it
    shift = (stride - NODE_ROWS) * m
    out = np.where(refs >= 0, refs // NODE_ROWS * stride, np.where(refs == ~0, ~0, refs - (shift << LEAF_BITS)))
    nodes.view(np.int32)[:, 6, :] = out.astype(np.int32)
    return rows


def bvh4_build(scene, changes: dict):
    """(upload arrays, description) of the 4-wide tree collapsed under ``changes``."""
    changes = dict(changes)
    stride = changes.pop("stride", None)
    b, _ = load_or_build_bvh4(scene.vertices, scene.faces, dataclasses.replace(Bvh4BuildParams(), **changes))
    arrays = device_scene_module.bvh4_accel(scene, None, b)
    if stride:
        arrays = dataclasses.replace(arrays, node_data=padded_rows(b, stride))
    return arrays, f"{b.binary} tree collapsed, cost {b.cost:.2f}, {b.n_nodes:,} nodes, depth {b.depth}"


FAMILIES = {"bvh": (BVH_PREFIXES, None, bvh_build), "bvh4": (BVH4_PREFIXES, BVH4_WORDS, bvh4_build)}


def upload(backend, scene, family: str, changes: dict):
    """A DeviceScene of its own holding ``family``'s tree built under ``changes``; (scene, builder, info)."""
    arrays, info = FAMILIES[family][2](scene, changes)

    def builder(scene_, tree_):
        return arrays

    ds = DeviceScene.upload(backend, scene, None)
    with mock.patch.dict(device_scene_module.ACCEL_BUILDERS, {family: builder}):
        ds._accel(family)                # the tree uploaded now, under this configuration's builder
    return ds, builder, info


def main(argv=None) -> None:
    ap = ab_arguments(__doc__.split("\n")[0], "base;ml4", 4)
    ap.add_argument("--variant", default=None, help="a variant reading the family's tree (default: the backend's "
                                                     "default with the family's traversal)")
    ap.add_argument("--family", default="bvh", choices=("bvh", "bvh4"), help="the tree the configurations change")
    ap.add_argument("--defines", default="", help="NAME=V,... compiled into every configuration's kernels")
    a = ap.parse_args(argv)
    defines = {k: int(v) for k, v in (d.split("=") for d in a.defines.split(",") if d)}
    backend = get_backend(a.backend, a.device)
    variant = tracing.resolve_variant(a.variant or a.family, backend, rays=True)
    prefixes, words, _ = FAMILIES[a.family]
    configs = [(c, parse_params(c, prefixes, words)) for c in a.configs.split(";")]
    peers = peer_figures()
    scenes = {}
    for batch in ab_batches(a, backend, f"variant {variant.label()}", [c for c, _ in configs]):
        key = batch.view.split("/")[0]
        if key not in scenes:
            scenes[key] = {c: upload(backend, batch.scene, a.family, ch) for c, ch in configs}
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
                              repeats=a.repeats, warmup=1, width=width, defines=defines)
                best[c].append(min(r.launches_ms))
                last[c] = r
        print_row(batch, best, last, peers.get((batch.view, batch.kind, a.size), {}).get("best"))


if __name__ == "__main__":
    main()
