"""What the 4-wide walk's per-octant copies (rt_bvh4.h, RT_BVH4_OCTANT_WALKS) rest on and cost, on the
host: the share of camera-ray warps whose rays all point into one octant (a warp: 8x4 pixels of an 8x16
block, as trace()'s grid launch lays them out), and how long nvcc takes to build the library's trace
program for trace()'s default with and without the copies.

    python experiments/octant_walks_host.py [--views bunny/far,conference/inside] [--sizes 1024,2048]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from rtlab.backends.nvcc import nvcc_available, nvcc_resources
from rtlab.benches.rays import view_scene
from rtlab.device.kernels import SceneFeatures, build_defines, build_options, kernel_source
from rtlab.device.variants import GPU_RAYS_VARIANT
from rtlab.scene.model import camera_rays

WARP_W, WARP_H = 8, 4          # a warp of an 8x16 block: 32 consecutive threads, x fastest


def octant_uniform_share(view: str, size: int) -> tuple[float, int]:
    """(share of warps whose 32 camera rays share one octant, octants in the image)"""
    _, d = camera_rays(view_scene(view, size).camera)
    d = np.asarray(d).reshape(size, size, 3)
    octant = (4 * (d[..., 0] < 0) + 2 * (d[..., 1] < 0) + (d[..., 2] < 0)).astype(np.int8)
    warps = octant.reshape(size // WARP_H, WARP_H, size // WARP_W, WARP_W).transpose(0, 2, 1, 3).reshape(-1, 32)
    return float(np.all(warps == warps[:, :1], axis=1).mean()), len(np.unique(octant))


def build_seconds(walks: int) -> float:
    features = SceneFeatures(stack_size=32, n_lights=0, n_materials=1)
    defines = {**build_defines(GPU_RAYS_VARIANT, features), "RT_BVH4_OCTANT_WALKS": walks}
    t = time.perf_counter()
    nvcc_resources(kernel_source("library_trace", "cuda"), defines,
                   extra_options=build_options(GPU_RAYS_VARIANT, "cuda", "library_trace"))
    return time.perf_counter() - t


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--views", default="bunny/far,bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside")
    ap.add_argument("--sizes", default="1024,2048")
    a = ap.parse_args(argv)
    print("| view | size | warps sharing one octant | octants in the image |\n|---|---:|---:|---:|")
    for view in a.views.split(","):
        for size in (int(s) for s in a.sizes.split(",")):
            share, octants = octant_uniform_share(view, size)
            print(f"| {view} | {size}² | {100 * share:.2f} % | {octants} |", flush=True)
    if nvcc_available():
        print(f"nvcc -cubin, library_trace.cu for trace()'s default: {build_seconds(0):.1f} s without the "
              f"per-octant walks, {build_seconds(1):.1f} s with them")


if __name__ == "__main__":
    main()
