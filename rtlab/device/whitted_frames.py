"""The frame runners of rtlab.device.whitted.render_whitted: the launches of one frame, host side.

One class a schedule: lab step 04's shadow kernels (:class:`ShadowFrame`), lab step 05's kernel tree
walked depth-first (:class:`TreeFrame`, the paper's §3.2.2) and the tree's rays level by level
(:class:`WavefrontFrame`, kernels/shared/rt_wavefront.h). Each runs a frame, says which kernels it
launches and with what block, and reads back the image, the primary hits and (with write_hits) the
ray tree: node -> triangle id per pixel, NO_RAY where the node spawned no ray.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kernel_constants import kernel_constant
from .layout import HIT_DTYPE
from .tracing import unpack_hits

NO_RAY = int(kernel_constant("RT_NO_RAY"))      # tri of a tree node whose ray was not spawned
KINDS = (("R", "trace_reflection", "RT_REFLECTION"), ("T", "trace_refraction", "RT_REFRACTION"))
CONSTANTS = ("frame", "lights", "materials")
PACK_KERNELS = ("pack_frame", "pack_pending")     # the float4 frame to RGBA8: no rays
PACK_BLOCK = (256,)     # a packing launch reads a float4 and writes a word a pixel: larger blocks stream it faster


@dataclass
class Launch:
    """One kernel launch of a frame: its tree node ("P" primary, "PR" its reflection, "PRT" the
    refraction of that, ...), level, the rays it was launched over and its device time."""
    kernel: str
    node: str
    level: int
    rays: int
    ms: float


class Frame:
    """What every frame runner shares: the program and its scene arguments, the launch shapes (the
    variant's 2D block for pixel kernels, as many threads in 1D for ray kernels) and the packed
    RGBA8 pixels of the last frame."""
    PIXEL_KERNELS = ()

    def __init__(self, backend, program, scene_args, camera, variant, write_hits):
        self.backend, self.program, self.args, self.camera = backend, program, scene_args, camera
        self.block2d = variant.block
        self.block1d = (variant.block[0] * variant.block[1],)
        self.n = camera.width * camera.height
        self.write_hits = write_hits
        self.pixels = backend.empty(4 * self.n)
        self.tree: dict | None = None

    def block(self, kernel):
        return self.block2d if kernel in self.PIXEL_KERNELS else self.block1d

    def image(self) -> np.ndarray:
        rgba = self.backend.to_host(self.pixels, np.uint32, self.n)
        return rgba.view(np.uint8).reshape(self.camera.height, self.camera.width, 4)[:, :, :3].copy()


class ShadowFrame(Frame):
    """Lab step 04: one frame of one-pass (or no) shadows, or two-pass shadows."""

    PIXEL_KERNELS = ("render_shadows", "trace_primary_hits", "shade_hits")

    def __init__(self, backend, program, scene_args, camera, variant, shadows, defines, write_hits):
        super().__init__(backend, program, scene_args, camera, variant, write_hits)
        self.two_pass = shadows == "two-pass"
        self.hits = backend.empty(HIT_DTYPE.itemsize * self.n if (self.two_pass or write_hits) else 4)

    def kernels(self) -> list[str]:
        return ["trace_primary_hits", "shade_hits"] if self.two_pass else ["render_shadows"]

    def frame(self) -> list[Launch]:
        size = (self.camera.width, self.camera.height)
        if not self.two_pass:
            ms = self.program.launch("render_shadows", size, self.block2d, self.args + [self.pixels, self.hits],
                                     constants=CONSTANTS)
            return [Launch("render_shadows", "P", 0, self.n, ms)]
        # Pass 1 writes each pixel's hit record to the global buffer; pass 2 reads it back
        ms1 = self.program.launch("trace_primary_hits", size, self.block2d, self.args + [self.hits],
                                  constants=("frame",))
        ms2 = self.program.launch("shade_hits", size, self.block2d, self.args + [self.hits, self.pixels],
                                  constants=CONSTANTS)
        return [Launch("trace_primary_hits", "P", 0, self.n, ms1), Launch("shade_hits", "P", 0, self.n, ms2)]

    def primary_hits(self):
        return unpack_hits(self.backend.to_host(self.hits, np.float32, 4 * self.n))


@dataclass
class _Level:
    """The ray buffers of one tree level: records (direction, weight), (t, u, v, tri), pixel."""
    dirs: object
    hits: object
    pixels: object
    count: object


class TreeFrame(Frame):
    """Lab step 05: one frame of the kernel tree, walked depth-first from the host."""

    PIXEL_KERNELS = ("trace_primary_tree",)

    def __init__(self, backend, program, scene_args, camera, variant, shadows, defines, write_hits):
        super().__init__(backend, program, scene_args, camera, variant, write_hits)
        self.depth = defines["RT_MAX_DEPTH"]
        self.compact = bool(defines["RT_COMPACT"])
        self.two_pass = bool(defines["RT_TWO_PASS"])
        self.kinds = [(letter, kernel) for letter, kernel, define in KINDS if program.defines.get(define, 1)]
        self.frame_rgb = backend.empty(16 * self.n)
        self.levels = self._tree_buffers()
        self.zero = np.zeros(1, np.int32)
        self.primary = None

    def _tree_buffers(self) -> list[_Level]:
        """Depth-first, a node's records live only until its subtree is done: one set of buffers
        per level, max bounces + 1 in all (§3.2.2), however many nodes the tree has. The deepest
        level's records are written only for a two-pass shading kernel or when hits are asked for."""
        b, n = self.backend, self.n
        return [_Level(b.empty(16 * n), b.empty(16 * n), b.empty(4 * n if self.compact else 4), b.empty(4))
                for _ in range(self.depth + 1)]

    def kernels(self) -> list[str]:
        names = ["trace_primary_tree"] + ([k for _, k in self.kinds] if self.depth > 0 else [])
        return names + (["shade_records"] if self.two_pass else []) + ["pack_frame"]

    def _out(self, level: int) -> list:
        lv = self.levels[level]
        return [lv.dirs, lv.hits, lv.pixels, lv.count]

    def _live(self, level: int) -> int:
        """Rays the node just launched recorded at ``level``: the next launch's size."""
        if not self.compact:
            return self.n
        return int(self.backend.to_host(self.levels[level].count, np.int32, 1)[0])

    def _after_node(self, node: str, level: int, launches: list[Launch]) -> int:
        live = self._live(level)
        if self.two_pass and live:
            lv = self.levels[level]
            ms = self.program.launch("shade_records", (live,), self.block1d,
                                     self.args + [lv.dirs, lv.hits, lv.pixels, np.int32(live), self.frame_rgb,
                                                  np.int32(level)], constants=CONSTANTS)
            launches.append(Launch("shade_records", node, level, live, ms))
        if self.tree is not None:
            self._record_tree(node, level, live)
        return live

    def _descend(self, level: int, node: str, parents: int, launches: list[Launch]) -> None:
        """Children of the node whose records are at ``level - 1``: reflection subtree first, then
        refraction (depth-first, the paper's memory-saving order)."""
        if level > self.depth:
            return
        above = self.levels[level - 1]
        for letter, kernel in self.kinds:
            if parents == 0:
                return
            if self.compact:
                self.backend.fill(self.levels[level].count, self.zero)
            ms = self.program.launch(kernel, (parents,), self.block1d,
                                     self.args + [above.dirs, above.hits, above.pixels, np.int32(parents),
                                                  self.frame_rgb] + self._out(level) + [np.int32(level)],
                                     constants=CONSTANTS)
            launches.append(Launch(kernel, node + letter, level, parents, ms))
            self._descend(level + 1, node + letter, self._after_node(node + letter, level, launches), launches)

    def frame(self) -> list[Launch]:
        launches: list[Launch] = []
        self.tree = {} if self.write_hits else None
        if self.compact:
            self.backend.fill(self.levels[0].count, self.zero)
        ms = self.program.launch("trace_primary_tree", (self.camera.width, self.camera.height), self.block2d,
                                 self.args + [self.frame_rgb] + self._out(0), constants=CONSTANTS)
        launches.append(Launch("trace_primary_tree", "P", 0, self.n, ms))
        self._descend(1, "P", self._after_node("P", 0, launches), launches)
        ms = self.program.launch("pack_frame", (self.n,), PACK_BLOCK, [self.frame_rgb, self.pixels, np.int32(self.n)])
        launches.append(Launch("pack_frame", "", 0, self.n, ms))
        return launches

    def _record_tree(self, node: str, level: int, live: int) -> None:
        lv = self.levels[level]
        hits = self.backend.to_host(lv.hits, np.float32, 4 * live).reshape(-1, 4) if live else np.zeros((0, 4), np.float32)
        tri = np.full(self.n, NO_RAY, np.int32)
        if self.compact:
            pixels = self.backend.to_host(lv.pixels, np.int32, live)
            tri[pixels] = hits[:, 3].view(np.int32)
        else:
            tri[:] = hits[:, 3].view(np.int32)
        self.tree[node] = tri
        if level == 0:
            self.primary = (hits, pixels if self.compact else np.arange(self.n))

    def primary_hits(self):
        hits, pixels = self.primary
        out = np.zeros((self.n, 4), np.float32)
        out[pixels] = hits
        return unpack_hits(out)


@dataclass
class _Queue:
    """A ray queue of rt_wavefront.h: (origin, weight), (direction, pixel), path, counts (reflection,
    refraction, and in level 0's queue the pending pixels)."""
    ow: object
    dp: object
    path: object
    count: object
    cap: int


class WavefrontFrame(Frame):
    """The tree's rays level by level (kernels/shared/rt_wavefront.h): one launch per level over the
    queue the level above filled. Two queues, the one read and the one filled, alternate; each is
    grown to twice the rays of the level that fills it (a ray appends at most two children). Level 0
    packs the pixels that spawn no child; pack_pending packs the others after the last level."""

    PIXEL_KERNELS = ("trace_wavefront_primary",)

    def __init__(self, backend, program, scene_args, camera, variant, shadows, defines, write_hits):
        super().__init__(backend, program, scene_args, camera, variant, write_hits)
        self.depth = defines["RT_MAX_DEPTH"]
        self.frame_rgb = backend.empty(16 * self.n)
        self.hits_cap = self.n if write_hits else 1
        self.hits = backend.empty(16 * self.hits_cap)
        self.queues = [self._queue(2 * self.n if self.depth > 0 else 1) for _ in range(2)]
        self.pending = backend.empty(4 * self.n if self.depth > 0 else 4)
        self.zero = np.zeros(4, np.int32)
        self.primary_records = None

    def _queue(self, cap: int) -> _Queue:
        b = self.backend
        return _Queue(b.empty(16 * cap), b.empty(16 * cap), b.empty(4 * cap), b.empty(16), cap)

    def _filled(self, index: int, need: int) -> _Queue:
        """Queue ``index``, emptied and grown to hold ``need`` rays, for the next launch to fill."""
        if self.queues[index].cap < need:
            self.queues[index] = self._queue(need)
        self.backend.fill(self.queues[index].count, self.zero)
        return self.queues[index]

    def _queue_args(self, q: _Queue) -> list:
        return [q.ow, q.dp, q.path, q.count, np.int32(q.cap)]

    def kernels(self) -> list[str]:
        return ["trace_wavefront_primary"] + (["trace_wavefront", "pack_pending"] if self.depth > 0 else [])

    def frame(self) -> list[Launch]:
        launches: list[Launch] = []
        self.tree = {} if self.write_hits else None
        out = self._filled(0, 2 * self.n if self.depth > 0 else 0)
        ms = self.program.launch("trace_wavefront_primary", (self.camera.width, self.camera.height), self.block2d,
                                 self.args + [self.frame_rgb, self.pixels, self.pending, self.hits]
                                 + self._queue_args(out), constants=CONSTANTS)
        launches.append(Launch("trace_wavefront_primary", "P", 0, self.n, ms))
        if self.tree is not None:
            self._record_level(0, None, 0, 0)
        pending = 0
        for level in range(1, self.depth + 1):
            src = self.queues[(level - 1) % 2]
            front, back, level0_pending = (int(c) for c in self.backend.to_host(src.count, np.int32, 3))
            pending = level0_pending if level == 1 else pending
            rays = front + back
            if rays == 0:
                break
            out = self._filled(level % 2, 2 * rays if level < self.depth else 0)
            if self.write_hits and rays > self.hits_cap:
                self.hits_cap, self.hits = rays, self.backend.empty(16 * rays)
            ms = self.program.launch("trace_wavefront", (rays,), self.block1d,
                                     self.args + [src.ow, src.dp, src.path, np.int32(front), np.int32(rays),
                                                  np.int32(src.cap), self.frame_rgb, self.hits]
                                     + self._queue_args(out) + [np.int32(level)], constants=CONSTANTS)
            launches.append(Launch("trace_wavefront", "P" + "*" * level, level, rays, ms))
            if self.tree is not None:
                self._record_level(level, src, front, back)
        if pending:
            ms = self.program.launch("pack_pending", (pending,), PACK_BLOCK,
                                     [self.frame_rgb, self.pending, self.pixels, np.int32(pending)])
            launches.append(Launch("pack_pending", "", 0, pending, ms))
        return launches

    def _record_level(self, level: int, src: _Queue | None, front: int, back: int) -> None:
        """The ray tree's nodes of one level, from the launch's hits and the queue it read."""
        rays = front + back if level else self.n
        hits = self.backend.to_host(self.hits, np.float32, 4 * rays).reshape(-1, 4)
        tri = hits[:, 3].view(np.int32)
        if level == 0:
            self.tree["P"] = tri.copy()
            self.primary_records = hits
            return
        slots = np.concatenate([np.arange(front), src.cap - 1 - np.arange(back)])
        pixel = self.backend.to_host(src.dp, np.float32, 4 * src.cap).reshape(-1, 4)[slots, 3].view(np.int32)
        path = self.backend.to_host(src.path, np.int32, src.cap)[slots]
        for code in np.unique(path):
            node = "P" + "".join("RT"[(int(code) >> b) & 1] for b in range(level))
            ids = np.full(self.n, NO_RAY, np.int32)
            mask = path == code
            ids[pixel[mask]] = tri[mask]
            self.tree[node] = ids

    def primary_hits(self):
        return unpack_hits(self.primary_records)


FRAME_RUNNERS = {"shadows": ShadowFrame, "tree": TreeFrame, "wavefront": WavefrontFrame}
