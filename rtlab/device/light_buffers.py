"""Shadow rays through light buffers (rtlab.accel.light_buffer, kernels/shared/rt_light_buffer.h) in the
library's frame kernels: which frames take them, and the buffers they read.

A frame takes them (RT_LIGHT_BUFFER) where it traces shadow rays with the library's programs on a BVH
in global memory, one ray a thread: the labs' programs and the paper's kd-tree variants keep the paper's
shadow rays through the traversal (Table 5), and a counting or texture build keeps the loaders it was
made for. The CPU's traversals in SIMD lanes (bvh-wide, bvh-packet: the CPU default) keep them too: on
PoCL their shadow rays walk the wide BVH faster than a list is walked a ref at a time
(docs/results.md, "Shadow rays through a light buffer").
Each light's block is appended to the traversal's node_data, built once per tree and light positions
and kept with the uploaded scene; the light's position.w carries the block's first word, its color.w the block's resolution and its refs' id bits.
"""
from __future__ import annotations

import time

import numpy as np

from ..accel import light_buffer
from ..accel.light_buffer import build_light_buffer, light_buffer_stats
from ..errors import RtlabError
from .device_scene import KD_FAMILIES, DeviceArray, accel_family, light_constants


def takes_light_buffer(variant, lab: bool) -> bool:
    """Whether shadow rays of ``variant``'s frames may go through light buffers (see the module docstring)."""
    return (not lab and variant.node_memory == "global" and not variant.count_work and not variant.spec.lanes
            and accel_family(variant.traversal) not in KD_FAMILIES)


def light_buffer_defines(variant, shadows: int, lab: bool) -> dict:
    """{"RT_LIGHT_BUFFER": 1} for a frame with shadow rays that takes light buffers, else {}."""
    return {"RT_LIGHT_BUFFER": 1} if shadows and takes_light_buffer(variant, lab) else {}


def light_buffer_args(ds, variant, lab: bool = False) -> tuple[list, np.ndarray, dict]:
    """``ds.scene_args(variant)`` with node_data followed by each light's block, the lights' constants
    with their blocks' first words and resolutions, and what the blocks are (resolution, MiB, build seconds)."""
    if not takes_light_buffer(variant, lab):
        raise RtlabError(f"light buffers need the library's programs on a BVH in global memory, not "
                         f"{variant.label()}{' (lab)' if lab else ''}")
    args = ds.scene_args(variant)
    family = accel_family(variant.traversal)
    key = (family, tuple(tuple(float(c) for c in light.position) for light in ds.scene.lights),
           light_buffer.RESOLUTIONS, light_buffer.MAX_WORDS, light_buffer.MAX_LIST)
    made = ds.light_buffers.get(key)
    if made is None or made[0] is not ds.accel[family][0]:
        made = _make(ds, ds.accel[family][0], key[1])
        ds.light_buffers[key] = made
    _, node_data, blocks, info = made
    args[1] = node_data.buffer
    lights = light_constants(ds.scene)
    lights["position"][:len(blocks), 3] = blocks[:, 0].astype(np.int32).view(np.float32)
    lights["color"][:len(blocks), 3] = blocks[:, 1].astype(np.int32).view(np.float32)    # resolution | id bits << 16
    return args, lights, info


def _make(ds, arrays, positions) -> tuple:
    t0 = time.perf_counter()
    words = [np.ascontiguousarray(arrays.node_data, np.float32).view(np.int32).ravel()]
    at = words[0].size
    bases, blocks = [], []          # per light: (the block's first word, its resolution), (-1, 0) for none
    for position in positions:
        block = build_light_buffer(ds.scene.vertices, ds.scene.faces, position, light_buffer.MAX_WORDS)
        bases.append((-1, 0) if block is None else (at, int(block[0]) | int(block[1]) << 16))
        if block is not None:
            words.append(block)
            at += block.size
            blocks.append(light_buffer_stats(block))
    words.append(np.zeros(-at % 4, np.int32))
    rows = np.concatenate(words).view(np.float32).reshape(-1, 4)
    info = {"lights": blocks, "build_s": time.perf_counter() - t0}
    return arrays, DeviceArray(ds.backend.to_device(rows), len(rows)), np.asarray(bases, np.int64).reshape(-1, 2), info
