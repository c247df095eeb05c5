"""Can one probe ray a tile tell which camera-ray tiles are costly, and what does tracing the probes cost?

    python experiments/probe_tile_costs.py overlap [--size 1024]            # host only, no GPU
    python experiments/probe_tile_costs.py time --backend cuda [--device NVIDIA] [--size 1024]

``overlap``: for each benchmark view, each 8x16 tile's cost (its costliest ray: node visits x 121 +
triangle tests x 75, the 4-wide walk mirrored on the host) against a probe's estimate (the ray at row
2, column 4 of each of the tile's four 8x4 warp parts, the largest of the four): how many of the
costliest 1 % and 3 % of the tiles the probe's own costliest 1 % and 3 % find; and the same for the
estimate trace() orders camera rays by (rtlab.accel.tile_costs, no ray traced), with its Spearman rank
correlation against the tiles' costs. ``time``: the kernel
time of trace() over the probe rays alone (one an 8x4 tile, 1/32 of the rays, or one in four 8x4 tiles),
through trace_rays and trace_rays_fetch: what a probe launch would cost before the ordered launch. The
order the probe gives is timed by ab_trace_configs.py's ``sortprobeP``.
"""
from __future__ import annotations

import argparse
from unittest import mock

import numpy as np

from ab_trace_configs import tile_order
from rtlab.benches.rays import make_rays

VIEWS = "bunny/far,bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside"


def overlap(views: list[str], size: int) -> None:
    from rtlab.accel.bvh4 import load_or_build_bvh4
    from rtlab.accel.bvh_wide_stats import traversal_counts_bvh4
    from rtlab.accel.tile_costs import tile_boxes, tile_costs
    print("| view | tile cost: mean / p99 / max | probe finds of the costliest 1 % | of the costliest 3 % "
          "| estimate finds of the costliest 1 % | of the costliest 3 % | estimate's Spearman |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for view in views:
        batch = make_rays(view, "primary", size)
        b, _ = load_or_build_bvh4(batch.scene.vertices, batch.scene.faces)
        nodes, _, tris = traversal_counts_bvh4(b, batch.scene.vertices, batch.scene.faces, batch.origins,
                                               batch.directions)[:3]
        cost = (np.asarray(nodes) * 121 + np.asarray(tris) * 75).reshape(size // 16, 4, 4, size // 8, 8)
        tile = cost.max(axis=(1, 2, 4)).ravel()                 # (tile row, warp part, row, tile column, column)
        probe = cost[:, :, 2, :, 4].max(axis=1).ravel()
        estimate = tile_costs(tile_boxes(b), batch.scene.camera.basis(), size, size, (8, 16)).ravel()
        cells = []
        for guess in (probe, estimate):
            for percent in (1, 3):
                k = len(tile) * percent // 100
                found = np.intersect1d(np.argsort(-tile, kind="stable")[:k], np.argsort(-guess, kind="stable")[:k])
                cells.append(f"{len(found)} of {k}")
        rank = lambda a: np.argsort(np.argsort(a, kind="stable"), kind="stable")   # noqa: E731
        cells.append(f"{np.corrcoef(rank(tile), rank(estimate))[0, 1]:.2f}")
        print(f"| {view} | {tile.mean():,.0f} / {np.percentile(tile, 99):,.0f} / {tile.max():,.0f} | "
              + " | ".join(cells) + " |", flush=True)


def probe_times(views: list[str], size: int, backend_name: str, device: str | None, repeats: int) -> None:
    from rtlab.backends import get_backend
    from rtlab.device import tracing
    from rtlab.device.tracing import default_variant, trace
    backend = get_backend(backend_name, device)
    variant = default_variant(backend, rays=True)
    print(f"device: {backend.name}: {backend.device_name}; {variant.label()}; median of {repeats} launches, µs")
    print("| view | probes | rays | trace_rays | trace_rays_fetch |")
    print("|---|---|---:|---:|---:|")
    for view in views:
        batch = make_rays(view, "primary", size)
        warps = tile_order(size, size, 8, 4).reshape(-1, 32)
        for label, idx in (("one an 8x4 tile", warps[:, 20]), ("one in four 8x4 tiles", warps[::4, 20])):
            o, d = np.ascontiguousarray(batch.origins[idx]), np.ascontiguousarray(batch.directions[idx])
            cells = []
            for fetch in (False, True):
                with mock.patch.object(tracing, "fetches_rays", tracing.fetches_rays if fetch else (lambda *_: False)):
                    r = trace(batch.scene, o, d, backend, variant, repeats=repeats, warmup=2)
                cells.append(f"{np.median(r.launches_ms) * 1e3:.1f}")
            print(f"| {view} | {label} | {len(idx):,} | " + " | ".join(cells) + " |", flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mode", choices=("overlap", "time"))
    ap.add_argument("--views", default=VIEWS)
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--backend", default="cuda")
    ap.add_argument("--device", default=None)
    ap.add_argument("--repeats", type=int, default=10)
    a = ap.parse_args(argv)
    views = a.views.split(",")
    if a.mode == "overlap":
        overlap(views, a.size)
    else:
        probe_times(views, a.size, a.backend, a.device, a.repeats)


if __name__ == "__main__":
    main()
