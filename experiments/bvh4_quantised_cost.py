"""What 8-bit child boxes would cost the 4-wide BVH's walk, counted on the host (no GPU).

A quantised 4-wide node, as CWBVH quantises its 8 children (Ylitie, Karras & Laine 2017): each node
keeps its own box's low corner and a power-of-two step per axis (2^e, the smallest with 255 steps
covering the box), and each child's six planes as 8-bit counts of steps, rounded outward (low planes
down, high planes up), so a child's box only grows. 64 bytes a node (corner 12, exponents 3, planes 24,
refs 16, padding) against the float node's 112. Growing boxes costs visits: this script walks the
benchmark views' rays through the float64 mirror of rt_bvh4.h's order (rtlab.accel.bvh_wide_stats) with
the exact boxes and with the quantised ones, and prints node visits, boxes tested and triangle tests a
ray for both. The hits' t must be the same (the boxes are conservative); the script checks.

    python experiments/bvh4_quantised_cost.py --size 128 [--views dragon/fill,...] [--kinds diffuse,primary]

A count, not a time: the decode (a byte to float and an fma a plane) and a pad on the quantised
distances are the kernel's cost to weigh against 43 % fewer node bytes.
"""
from __future__ import annotations

import argparse

import numpy as np

from rtlab.accel.bvh4 import load_or_build_bvh4
from rtlab.accel.bvh_wide_stats import traversal_counts_bvh4
from rtlab.benches.rays import make_rays, view_scene


def _half_down(x: np.ndarray) -> np.ndarray:
    """x rounded down to a half (float16), as float64"""
    h = x.astype(np.float16)
    return np.where(h > x, np.nextafter(h, np.float16(-np.inf)), h).astype(np.float64)


def quantised_planes(planes: np.ndarray, form: str = "8bit") -> np.ndarray:
    """(M, 6, 4) planes (lo.x, hi.x, lo.y, hi.y, lo.z, hi.z of four slots; empty slots lo = +inf) with each
    valid child's planes rounded outward on its node's box, as float64: "8bit", counts of the smallest
    power-of-two step with 255 across the box; "half", fractions of the box in float16."""
    p = planes.astype(np.float64)
    out = p.copy()
    valid = p[:, 0, :] <= p[:, 1, :]
    for a in range(3):
        lo, hi = p[:, 2 * a, :], p[:, 2 * a + 1, :]
        node_lo = np.where(valid, lo, np.inf).min(axis=1)
        node_hi = np.where(valid, hi, -np.inf).max(axis=1)
        node_lo = np.where(np.isfinite(node_lo), node_lo, 0.0)
        low32 = node_lo.astype(np.float32)                  # the corner as the node would store it: rounded down
        low32 = np.where(low32 > node_lo, np.nextafter(low32, np.float32(-np.inf)), low32)
        node_lo = low32.astype(np.float64)
        extent = np.maximum(np.where(np.isfinite(node_hi), node_hi, 0.0) - node_lo, 0.0)
        if form == "half":
            span = np.maximum(extent, 1e-30)[:, None]
            q_lo = np.clip(_half_down((lo - node_lo[:, None]) / span), 0.0, 1.0)
            q_hi = np.clip(-_half_down(-(hi - node_lo[:, None]) / span), 0.0, 1.0)
            dec_lo, dec_hi = node_lo[:, None] + q_lo * span, node_lo[:, None] + q_hi * span
        else:
            # the smallest power of two with 255 steps covering the extent (a node of zero extent: any step)
            step = np.exp2(np.ceil(np.log2(np.maximum(extent, 1e-30) / 255.0)))[:, None]
            q_lo = np.clip(np.floor((lo - node_lo[:, None]) / step), 0, 255)
            q_hi = np.clip(np.ceil((hi - node_lo[:, None]) / step), 0, 255)
            dec_lo, dec_hi = node_lo[:, None] + q_lo * step, node_lo[:, None] + q_hi * step
        # the decode in float64 may round across the exact plane by an ulp: never inward
        out[:, 2 * a, :] = np.where(valid, np.minimum(dec_lo, lo), lo)
        out[:, 2 * a + 1, :] = np.where(valid, np.maximum(dec_hi, hi), hi)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", default="bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside")
    ap.add_argument("--kinds", default="diffuse,primary")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--form", choices=("8bit", "half"), default="8bit",
                    help="8-bit step counts (64-byte nodes) or float16 fractions of the node's box (80-byte nodes)")
    args = ap.parse_args()
    label = {"8bit": "8-bit", "half": "half"}[args.form]
    print(f"| view | rays | node visits a ray (float, {label}) | boxes tested | triangle tests | node bytes read a "
          f"ray (112 B, {64 if args.form == '8bit' else 80} B nodes) | same t on every ray |")
    print("|---|---|---|---|---|---|---|")
    for view in args.views.split(","):
        scene = view_scene(view, args.size)
        b4, _ = load_or_build_bvh4(scene.vertices, scene.faces)
        quant = quantised_planes(b4.planes(), args.form)
        node_bytes = 64 if args.form == "8bit" else 80
        for kind in args.kinds.split(","):
            rays = make_rays(view, kind, args.size, check_rays=1, scene=scene)
            a = traversal_counts_bvh4(b4, scene.vertices, scene.faces, rays.origins, rays.directions)
            q = traversal_counts_bvh4(b4, scene.vertices, scene.faces, rays.origins, rays.directions, planes=quant)
            same_t = np.array_equal(a[4], q[4])
            ties = int(np.sum(a[3] != q[3]))     # the same t on another triangle: coplanar overlaps
            nv, qv = a[0].mean(), q[0].mean()
            print(f"| {view} | {kind} | {nv:.1f} → {qv:.1f} ({(qv / nv - 1) * 100:+.1f} %) | "
                  f"{a[1].mean():.1f} → {q[1].mean():.1f} | {a[2].mean():.2f} → {q[2].mean():.2f} "
                  f"({(q[2].mean() / a[2].mean() - 1) * 100:+.1f} %) | {112 * nv:.0f} → {node_bytes * qv:.0f} "
                  f"({(node_bytes * qv / (112 * nv) - 1) * 100:+.0f} %) | {'yes' if same_t else 'NO'}"
                  f"{f' (another triangle at the same t on {ties} rays)' if ties else ''} |")


if __name__ == "__main__":
    main()
