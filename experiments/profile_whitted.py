"""Where a Whitted frame's time goes: every launch of the kernel tree (node, rays, device ms) for a
list of render configurations, median of several frames.

    python experiments/profile_whitted.py --scene sponza --size 1024 --bounces 3 \
        --configs bvh:compact,bvh:compact:noshadows,bvh:compact:regs48

A configuration is ``traversal[:option...]`` with options ``compact``, ``noshadows``, ``twopass``,
``regsN`` (register cap), ``blockWxH``, ``isect=NAME``, ``wavefront`` (one launch per level),
``fmaN`` (RT_BVH_BOX_FMA=N: the BVH's fused box test on or off, whatever the scene's position),
``RT_NAME=V`` (any -D), ``packN`` (the packing launch's block, N threads),
``lbN`` (light buffers of at most N cells a face edge), ``lbmibN`` (of at most N MiB), ``lblistN`` (their lists
at most N triangles long); ``RT_LIGHT_BUFFER=0`` turns them off.
"""
from __future__ import annotations

import argparse
from collections import defaultdict


from rtlab.backends import get_backend
from rtlab.device.kernels import Variant
from rtlab.accel import light_buffer
from rtlab.accel.light_buffer import MAX_LIST, MAX_WORDS, RESOLUTIONS
from rtlab.device import whitted_frames
from rtlab.device.whitted import render_whitted
from rtlab.device.whitted_frames import PACK_BLOCK, PACK_KERNELS
from rtlab.scene import load_scene
from rtlab.scene.materials import apply_materials


def parse_config(text: str):
    parts = text.split(":")
    kw, opts = {"traversal": parts[0]}, {"compact": False, "shadows": "one-pass", "schedule": "tree", "defines": {}}
    for p in parts[1:]:
        if p == "wavefront":
            opts["schedule"] = "wavefront"
        elif p == "compact":
            opts["compact"] = True
        elif p == "noshadows":
            opts["shadows"] = "none"
        elif p == "twopass":
            opts["shadows"] = "two-pass"
        elif p.startswith("regs"):
            kw["max_registers"] = int(p[4:])
        elif p.startswith("block"):
            w, h = p[5:].split("x")
            kw["block"] = (int(w), int(h))
        elif p.startswith("isect="):
            kw["intersection"] = p[6:]
        elif p.startswith("fma"):
            opts["defines"]["RT_BVH_BOX_FMA"] = int(p[3:])
        elif p.startswith("pack"):
            opts["pack_block"] = int(p[4:])
        elif p.startswith("lbmib"):
            opts["light_buffer_mib"] = int(p[5:])
        elif p.startswith("lblist"):
            opts["light_buffer_list"] = int(p[6:])
        elif p.startswith("lb"):
            opts["light_buffer_res"] = int(p[2:])
        elif "=" in p and p.startswith("RT_"):
            name, value = p.split("=")
            opts["defines"][name] = int(value)
        else:
            raise SystemExit(f"unknown option {p!r} in {text!r}")
    return Variant.paper(**kw), opts


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="sponza")
    ap.add_argument("--materials", default="paper")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--bounces", type=int, default=3)
    ap.add_argument("--backend", default="cuda")
    ap.add_argument("--device", default=None)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--configs", default="bvh:compact")
    ap.add_argument("--bvh", default="", help="BVH build parameters, e.g. max_leaf_size=4,cost_traversal=1.5")
    ap.add_argument("--per-launch", action="store_true", help="print every launch of each configuration")
    args = ap.parse_args()

    if args.bvh:
        from rtlab.accel import bvh
        params = bvh.BvhBuildParams(**{k: type(getattr(bvh.BvhBuildParams, k))(v) for k, v in
                                       (kv.split("=") for kv in args.bvh.split(","))})
        bvh.load_or_build_bvh.__defaults__ = (params, None)
        print(f"BVH {params}")
    scene = apply_materials(load_scene(args.scene, size=args.size), args.materials)
    backend = get_backend(args.backend, args.device)
    print(f"{scene.name} {args.size}² {args.bounces} bounces, materials {args.materials}, {backend.name} "
          f"({backend.device_name}), median of {args.repeats} frames")
    for text in args.configs.split(","):
        variant, opts = parse_config(text)
        light_buffer.MAX_LIST = opts.get("light_buffer_list", MAX_LIST)
        finest = opts.get("light_buffer_res", RESOLUTIONS[0])
        light_buffer.RESOLUTIONS = tuple(finest >> k for k in range(8) if finest >> k >= RESOLUTIONS[-1])
        light_buffer.MAX_WORDS = MAX_WORDS if finest <= RESOLUTIONS[0] else 1 << 30   # finer than the library's: room for it
        if "light_buffer_mib" in opts:
            light_buffer.MAX_WORDS = opts["light_buffer_mib"] << 18
        whitted_frames.PACK_BLOCK = (opts.get("pack_block", PACK_BLOCK[0]),)
        r = render_whitted(scene, backend, variant, shadows=opts["shadows"], bounces=args.bounces,
                           compact=opts["compact"], schedule=opts["schedule"], repeats=args.repeats, warmup=2,
                           defines=opts["defines"])
        regs = "/".join(str(v.get("registers")) for v in r.resources.values())
        print(f"{text:40s} {r.median_ms:7.3f} ms {r.fps:8.1f} fps  rays {r.rays_launched():>10,}  "
              f"launches {len(r.launches):2d}  regs {regs}  host {r.host_ms:.2f} ms")
        if r.light_buffer:
            blocks = "; ".join(f"{b['resolution']}² a face, {b['mib']:.1f} MiB, {b['mean_list']:.1f} a list, "
                               f"{b['cells_to_traversal']:,} cells to the traversal" for b in r.light_buffer["lights"])
            print(f"    light buffers: {blocks} (built in {r.light_buffer['build_s']:.1f} s)")
        by_level = defaultdict(lambda: [0, 0.0])
        for launch in r.launches:
            by_level[launch.level if launch.kernel not in PACK_KERNELS else "pack"][0] += launch.rays
            by_level[launch.level if launch.kernel not in PACK_KERNELS else "pack"][1] += launch.ms
        print("    by level: " + "  ".join(f"L{k}: {v[0]:,} rays {v[1]:.3f} ms" for k, v in by_level.items()))
        if args.per_launch:
            for launch in r.launches:
                rate = launch.rays / launch.ms / 1e3 if launch.ms > 0 else float("nan")
                print(f"    {launch.kernel:20s} {launch.node:6s} L{launch.level} {launch.rays:>9,} rays "
                      f"{launch.ms:7.3f} ms  {rate:8.1f} Mrays/s")


if __name__ == "__main__":
    main()
