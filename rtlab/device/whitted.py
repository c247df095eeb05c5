"""Whitted ray tracing on any backend: shadows one-pass or two-pass (§3.2.1, lab step 04) and
reflection/refraction as a kernel tree (§3.2.2, lab step 05), with kernels specialised to the scene.

    result = render_whitted(scene, "opencl", shadows="two-pass", bounces=3)
    result.image, result.frame_ms, result.launches, result.resources

Bounces 0 runs lab step 04: ``one-pass`` is one kernel (primary ray, shadow rays, shading);
``two-pass`` is a primary kernel writing hit records to a global buffer and a shading kernel that
traces the shadow rays; ``none`` is the one-pass kernel compiled without shadow rays.

Bounces >= 1 runs lab step 05, the paper's kernel tree: the primary kernel is the root; every node
below is one launch of the reflection or the refraction kernel over the rays of the level above,
visited depth-first, so one set of ray buffers per level -- max bounces + 1 -- is alive at once
(:func:`_tree_buffers`). Each ray carries a weight; each node adds weight x colour to a float4
frame, packed to RGBA8 at the end. With ``compact=True`` every node appends only the rays that can
have children to the next level and the host launches the children over that count alone (a
wavefront step, beyond the paper), skipping empty subtrees; with two-pass shadows a shading kernel
follows every node.

``schedule="wavefront"`` (beyond the paper) traces the same rays level by level instead: one launch
per level over a queue of all that level's rays, reflection and refraction together, children
spawned where their parent is shaded (kernels/shared/rt_wavefront.h says why: the tree's deep nodes
are launches too small to fill a GPU). Two queues are alive at once; the image equals the tree's up
to the order of float additions into a pixel (at most one 8-bit step).

Kernels leave out what the scene does not use (``specialise=True``): no lights, no lighting loop
and no shadow rays; no transparent material, no refraction kernel and no Fresnel; the bounce depth
is cut to the deepest level that can still hold a ray. The general kernel (``specialise=False``)
compiles everything in and gives the same image.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..backends import get_backend
from ..errors import RtlabError
from .kernels import SceneFeatures, Variant, load_program
from .layout import HIT_DTYPE
from ..scene.model import Scene
from .tracing import TraceResult, default_variant, unpack_hits
from .scene import device_scene

SHADOWS_STEP = "04_shadows"
TREE_STEP = "05_kernel_tree"
SHADOW_MODES = ("one-pass", "two-pass", "none")
SCHEDULES = ("tree", "wavefront")             # the paper's depth-first kernel tree; level by level
FRESNEL_MODES = {"schlick": 1, "fixed": 0}   # RT_FRESNEL
MAX_LIGHTS = 32                              # lights_reaching() keeps one bit a light
NO_RAY = -2                                  # RT_NO_RAY: tri of a tree node whose ray was not spawned
KINDS = (("R", "trace_reflection", "RT_REFLECTION"), ("T", "trace_refraction", "RT_REFRACTION"))
CONSTANTS = ("frame", "lights", "materials")


@dataclass
class Launch:
    """One kernel launch of a frame: its tree node ("P" primary, "PR" its reflection, "PRT" the
    refraction of that, ...), level, the rays it was launched over and its device time."""
    kernel: str
    node: str
    level: int
    rays: int
    ms: float


@dataclass
class WhittedResult:
    image: np.ndarray                    # (H, W, 3) uint8
    frame_ms: list[float]                # device time of each timed frame (sum of its launches)
    host_ms: float                       # wall time of one frame (median), host work included
    launches: list[Launch]               # the last frame's launches, in order
    resources: dict                      # kernel -> KernelResources.as_dict()
    defines: dict
    step: str
    shadows: str
    bounces: int                         # asked for
    depth: int                           # compiled RT_MAX_DEPTH (kernel-tree levels below the root)
    compact: bool
    schedule: str = "tree"
    backend: str = ""
    device: str = ""
    variant: Variant = field(default_factory=Variant)
    hits: TraceResult | None = None      # primary hits, with write_hits
    tree: dict | None = None             # node -> (H*W,) int32 triangle ids, with write_hits (bounces >= 1)

    @property
    def median_ms(self) -> float:
        return float(np.median(self.frame_ms))

    @property
    def fps(self) -> float:
        return 1e3 / self.median_ms if self.median_ms > 0 else float("inf")

    def kernel_ms(self) -> dict[str, float]:
        """Device time of the last frame by kernel name."""
        out: dict[str, float] = {}
        for launch in self.launches:
            out[launch.kernel] = out.get(launch.kernel, 0.0) + launch.ms
        return out

    def rays_launched(self) -> int:
        """Threads of the tracing kernels (shading-only and packing launches left out)."""
        return sum(launch.rays for launch in self.launches if launch.kernel not in ("pack_frame", "shade_records"))


def shading_defines(features, shadows: str, bounces: int, fresnel: str, compact: bool = False,
                    write_hits: bool = False, tree: bool = False, schedule: str = "tree") -> dict:
    """Defines beyond the scene's own (rtlab.device.kernels.build_defines) for one render mode."""
    if shadows not in SHADOW_MODES:
        raise RtlabError(f"shadows must be one of {', '.join(SHADOW_MODES)}, not {shadows!r}")
    if schedule not in SCHEDULES:
        raise RtlabError(f"schedule must be one of {', '.join(SCHEDULES)}, not {schedule!r}")
    if schedule == "wavefront" and shadows == "two-pass":
        raise RtlabError("the wavefront schedule shades where it traces: shadows one-pass or none, not two-pass")
    if fresnel not in FRESNEL_MODES:
        raise RtlabError(f"fresnel must be one of {', '.join(FRESNEL_MODES)}, not {fresnel!r}")
    if not isinstance(bounces, (int, np.integer)) or not 0 <= bounces <= SceneFeatures.max_bounces:
        raise RtlabError(f"bounces must be a whole number from 0 to {SceneFeatures.max_bounces}, not {bounces!r}")
    defines = {"RT_SHADOWS": int(features.has_lights and shadows != "none"),
               "RT_MAX_DEPTH": min(int(bounces), int(features.max_bounces)),
               "RT_FRESNEL": FRESNEL_MODES[fresnel],
               "RT_WRITE_HITS": int(write_hits)}
    if tree:
        defines["RT_COMPACT"] = int(compact and schedule == "tree")
        defines["RT_TWO_PASS"] = int(shadows == "two-pass")
        defines["RT_WAVEFRONT"] = int(schedule == "wavefront")
    return defines


def render_whitted(scene: Scene, backend=None, variant: Variant | None = None, size: int | None = None,
                   shadows: str = "one-pass", bounces: int = 0, compact: bool = False, repeats: int = 1,
                   warmup: int = 0, write_hits: bool = False, fresnel: str = "schlick",
                   specialise: bool = True, device: str | None = None, schedule: str = "tree",
                   defines: dict | None = None) -> WhittedResult:
    """Render the scene's camera view with shadows and ``bounces`` levels of reflection/refraction
    (see the module docstring). Times ``repeats`` frames after ``warmup`` untimed ones. ``defines``
    adds or overrides -D switches (e.g. RT_CONSERVATIVE). ``variant`` None: rtlab.device.tracing.default_variant(backend)."""
    if not hasattr(backend, "compile"):
        backend = get_backend(backend, device)
    variant = variant or default_variant(backend)
    if variant.traversal == "packet":
        raise RtlabError("the packet traversal has no shadow or secondary-ray kernels (its shared stack lives in "
                         "lab step 03's entry kernels); choose a single-ray traversal")
    camera = scene.camera if size is None else scene.camera.with_size(size)
    if len(scene.lights) > MAX_LIGHTS:
        raise RtlabError(f"scene {scene.name!r} has {len(scene.lights)} lights; the shading kernels take at most {MAX_LIGHTS}")
    ds = device_scene(scene, backend)
    features = ds.features(variant)
    if not specialise:
        features = features.general()
    wavefront = schedule == "wavefront"
    tree = bounces > 0 or wavefront
    step = TREE_STEP if tree else SHADOWS_STEP
    extra = shading_defines(features, shadows, bounces, fresnel, compact, write_hits, tree, schedule)
    extra.update(defines or {})
    program = load_program(backend, step, variant, features, **extra)
    ds.set_constants(program, camera, variant)
    frame_class = _WavefrontFrame if wavefront else _TreeFrame if tree else _ShadowFrame
    runner = frame_class(backend, program, ds.scene_args(variant), camera, variant, shadows, extra, write_hits)
    for _ in range(warmup):
        runner.frame()
    frames, walls = [], []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        launches = runner.frame()
        walls.append((time.perf_counter() - t0) * 1e3)
        frames.append(sum(launch.ms for launch in launches))
    result = WhittedResult(runner.image(), frames, float(np.median(walls)), launches,
                           {k: program.resources(k, runner.block(k)).as_dict() for k in runner.kernels()},
                           program.defines, step, shadows, int(bounces), extra["RT_MAX_DEPTH"],
                           bool(extra.get("RT_COMPACT", 0)), schedule, backend.name, backend.device_name, variant)
    if write_hits:
        t, tri, u, v = runner.primary_hits()
        result.hits = TraceResult(t, tri, u, v, result.median_ms, backend.name, backend.device_name)
        result.tree = runner.tree
    return result


class _Frame:
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


class _ShadowFrame(_Frame):
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


class _TreeFrame(_Frame):
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
        ms = self.program.launch("pack_frame", (self.n,), self.block1d, [self.frame_rgb, self.pixels, np.int32(self.n)])
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
    """A ray queue of rt_wavefront.h: (origin, weight), (direction, pixel), path, two counts."""
    ow: object
    dp: object
    path: object
    count: object
    cap: int


class _WavefrontFrame(_Frame):
    """The tree's rays level by level (kernels/shared/rt_wavefront.h): one launch per level over the
    queue the level above filled. Two queues, the one read and the one filled, alternate; each is
    grown to twice the rays of the level that fills it (a ray appends at most two children)."""

    PIXEL_KERNELS = ("trace_wavefront_primary",)

    def __init__(self, backend, program, scene_args, camera, variant, shadows, defines, write_hits):
        super().__init__(backend, program, scene_args, camera, variant, write_hits)
        self.depth = defines["RT_MAX_DEPTH"]
        self.frame_rgb = backend.empty(16 * self.n)
        self.hits_cap = self.n if write_hits else 1
        self.hits = backend.empty(16 * self.hits_cap)
        self.queues = [self._queue(2 * self.n if self.depth > 0 else 1) for _ in range(2)]
        self.zero = np.zeros(2, np.int32)
        self.primary_records = None

    def _queue(self, cap: int) -> _Queue:
        b = self.backend
        return _Queue(b.empty(16 * cap), b.empty(16 * cap), b.empty(4 * cap), b.empty(8), cap)

    def _filled(self, index: int, need: int) -> _Queue:
        """Queue ``index``, emptied and grown to hold ``need`` rays, for the next launch to fill."""
        if self.queues[index].cap < need:
            self.queues[index] = self._queue(need)
        self.backend.fill(self.queues[index].count, self.zero)
        return self.queues[index]

    def _queue_args(self, q: _Queue) -> list:
        return [q.ow, q.dp, q.path, q.count, np.int32(q.cap)]

    def kernels(self) -> list[str]:
        return ["trace_wavefront_primary"] + (["trace_wavefront"] if self.depth > 0 else []) + ["pack_frame"]

    def frame(self) -> list[Launch]:
        launches: list[Launch] = []
        self.tree = {} if self.write_hits else None
        out = self._filled(0, 2 * self.n if self.depth > 0 else 0)
        ms = self.program.launch("trace_wavefront_primary", (self.camera.width, self.camera.height), self.block2d,
                                 self.args + [self.frame_rgb, self.hits] + self._queue_args(out), constants=CONSTANTS)
        launches.append(Launch("trace_wavefront_primary", "P", 0, self.n, ms))
        if self.tree is not None:
            self._record_level(0, None, 0, 0)
        for level in range(1, self.depth + 1):
            src = self.queues[(level - 1) % 2]
            front, back = (int(c) for c in self.backend.to_host(src.count, np.int32, 2))
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
        ms = self.program.launch("pack_frame", (self.n,), self.block1d, [self.frame_rgb, self.pixels, np.int32(self.n)])
        launches.append(Launch("pack_frame", "", 0, self.n, ms))
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


def render_whitted_command(console, scene: Scene, backend, variant: Variant, shadows: str, bounces: int,
                           materials: str, fresnel: str, compact: bool, repeats: int, check: bool, out,
                           schedule: str = "tree") -> WhittedResult:
    """`rtlab render --shadows/--bounces`: render with a material preset, print the figures, write the PNG."""
    from .rendering import save_png
    from ..scene.materials import apply_materials
    scene = apply_materials(scene, materials)
    cam = scene.camera
    with console.status(f"rendering {scene.name} {cam.width}x{cam.height}, shadows {shadows}, {bounces} bounces..."):
        result = render_whitted(scene, backend, variant, shadows=shadows, bounces=bounces, compact=compact,
                                repeats=repeats, warmup=1, write_hits=check, fresnel=fresnel, schedule=schedule)
    save_png(result.image, out)
    kernels = ", ".join(f"{k} {ms:.2f} ms" + (f" ({result.resources[k]['registers']} regs)"
                                              if result.resources.get(k, {}).get("registers") else "")
                        for k, ms in result.kernel_ms().items())
    console.print(f"{scene.name} {cam.width}x{cam.height} on {result.backend} ({result.device}), materials "
                  f"{materials}, shadows {shadows}, {bounces} bounces (depth {result.depth}, {schedule}"
                  f"{', compacted' if result.compact else ''}): "
                  f"{result.median_ms:.2f} ms a frame ({result.fps:,.1f} fps), {len(result.launches)} launches, "
                  f"{result.rays_launched():,} rays; {kernels}")
    if bounces > 0 and result.depth == 0:
        console.print(f"no material of {scene.name} reflects or transmits with materials {materials!r}, so no "
                      "secondary rays were traced; the paper's Fig. 6 materials: --materials paper")
    if check:
        from ..reference.whitted import reference_whitted, whitted_error
        with console.status("float64 Whitted reference..."):
            ref = reference_whitted(scene, cam, bounces=result.depth, shadows=shadows != "none", fresnel=fresnel)
        tree = result.tree if result.tree is not None else {"P": result.hits.tri}
        console.print(f"error vs float64 reference: {whitted_error(result.image, tree, ref).summary()}")
    console.print(f"wrote {out}")
    return result


# ---- probes: the kernels' own spawn and shadow-ray functions on arbitrary hits (for tests) -------

def hit_records(t, tri, u, v) -> np.ndarray:
    """(N, 4) float32 hit records as the kernels store them: t, u, v, triangle id bits."""
    rec = np.zeros((len(tri), 4), np.float32)
    rec[:, 0], rec[:, 1], rec[:, 2] = t, u, v
    rec[:, 3] = np.asarray(tri, np.int32).view(np.float32)
    return rec


def _probe_program(scene: Scene, backend, step: str, variant: Variant | None):
    if not hasattr(backend, "compile"):
        backend = get_backend(backend)
    variant = variant or default_variant(backend)
    ds = device_scene(scene, backend)
    program = load_program(backend, step, variant, ds.features(variant))
    ds.set_constants(program, None, variant)
    return backend, program, ds.scene_args(variant)


def _rows(a, w=0.0) -> np.ndarray:
    out = np.zeros((len(a), 4), np.float32)
    out[:, :3] = np.asarray(a, np.float32)
    out[:, 3] = w
    return out


def probe_shadow_rays(scene: Scene, backend, directions, hits: TraceResult, targets,
                      variant: Variant | None = None) -> np.ndarray:
    """(N,) bool: whether the shadow ray of rtlab's shading (light_visible) from each hit of rays
    with the given directions reaches the target point. Misses count as visible."""
    backend, program, args = _probe_program(scene, backend, SHADOWS_STEP, variant)
    n = len(hits.tri)
    if n == 0:
        return np.zeros(0, bool)
    bufs = [backend.to_device(_rows(directions)), backend.to_device(hit_records(hits.t, hits.tri, hits.u, hits.v)),
            backend.to_device(_rows(targets))]
    out = backend.empty(4 * n)
    program.launch("probe_shadow", (n,), (128,), args + bufs + [out, np.int32(n)], constants=("frame",))
    return backend.to_host(out, np.int32, n) != 0


def probe_secondary_rays(scene: Scene, backend, directions, hits: TraceResult, kind: str,
                         variant: Variant | None = None):
    """The reflection ("reflection") or refraction ("refraction") child the kernels spawn from each
    hit (parent weight 1): (origins (N, 3), weights (N,), directions (N, 3), TraceResult of the
    child's closest hit). Weight 0 and tri NO_RAY where none is spawned."""
    kinds = {"reflection": 0, "refraction": 1}
    if kind not in kinds:
        raise RtlabError(f"kind must be 'reflection' or 'refraction', not {kind!r}")
    backend, program, args = _probe_program(scene, backend, TREE_STEP, variant)
    n = len(hits.tri)
    bufs = [backend.to_device(_rows(directions)), backend.to_device(hit_records(hits.t, hits.tri, hits.u, hits.v))]
    outs = [backend.empty(16 * n) for _ in range(3)]
    program.launch("probe_secondary", (n,), (128,), args + bufs + [np.int32(kinds[kind]), np.int32(n)] + outs,
                   constants=("frame", "materials"))
    o, d, h = (backend.to_host(b, np.float32, 4 * n).reshape(n, 4) for b in outs)
    t, tri, u, v = unpack_hits(h)
    return o[:, :3], o[:, 3], d[:, :3], TraceResult(t, tri, u, v, 0.0, backend.name, backend.device_name)


def probe_refraction(backend, directions, normals, ior, front) -> tuple[np.ndarray, np.ndarray]:
    """The kernels' refract_dir and fresnel_schlick on unit directions and normals (facing the
    directions' origin side): (refracted directions (N, 3), Schlick reflectance (N,)); zero
    directions and reflectance 1 under total internal reflection."""
    if not hasattr(backend, "compile"):
        backend = get_backend(backend)
    from .kernels import build_defines, kernel_source
    program = backend.compile(kernel_source(TREE_STEP, backend.language), build_defines(Variant(), SceneFeatures()))
    n = len(directions)
    d = _rows(directions, np.broadcast_to(np.asarray(front, np.float32), (n,)))
    nrm = _rows(normals, np.broadcast_to(np.asarray(ior, np.float32), (n,)))
    out = backend.empty(16 * n)
    program.launch("probe_refract", (n,), (128,), [backend.to_device(d), backend.to_device(nrm), out, np.int32(n)])
    res = backend.to_host(out, np.float32, 4 * n).reshape(n, 4)
    return res[:, :3], res[:, 3]
