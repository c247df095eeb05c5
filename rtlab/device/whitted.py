"""Whitted ray tracing on any backend: shadows one-pass or two-pass (§3.2.1, lab step 04) and
reflection/refraction as a kernel tree (§3.2.2, lab step 05), with kernels specialised to the scene.

    result = render_whitted(scene, "opencl", shadows="two-pass", bounces=3)
    result.image, result.frame_ms, result.launches, result.resources

Bounces 0 runs the shadow kernels (the library's library_shadows; lab step 04's with ``lab=True``): ``one-pass`` is one kernel (primary ray, shadow rays, shading);
``two-pass`` is a primary kernel writing hit records to a global buffer and a shading kernel that
traces the shadow rays; ``none`` is the one-pass kernel compiled without shadow rays.

Bounces >= 1 runs the paper's kernel tree (library_bounces; lab step 05's with ``lab=True``): the primary kernel is the root; every node
below is one launch of the reflection or the refraction kernel over the rays of the level above,
visited depth-first, so one set of ray buffers per level -- max bounces + 1 -- is alive at once
(rtlab.device.whitted_frames). Each ray carries a weight; each node adds weight x colour to a float4
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
from ..scene.model import Scene
from .kernels import SceneFeatures, load_program
from .device_scene import device_scene
from .light_buffers import light_buffer_args, light_buffer_defines
from .tracing import TraceResult, check_count, require_scene
from .variants import LAB_PROGRAMS, Variant, program_for, resolve_variant
from .whitted_frames import FRAME_RUNNERS, NO_RAY, PACK_KERNELS, Launch  # noqa: F401  (NO_RAY: in a result's tree)

SHADOWS_STEP = LAB_PROGRAMS["shadows"]       # the lab steps of the shadow kernels and the kernel tree
TREE_STEP = LAB_PROGRAMS["bounces"]
SHADOW_MODES = ("one-pass", "two-pass", "none")
SCHEDULES = ("tree", "wavefront")             # the paper's depth-first kernel tree; level by level
FRESNEL_MODES = {"schlick": 1, "fixed": 0}   # RT_FRESNEL
MAX_LIGHTS = 32                              # lights_reaching() keeps one bit a light


@dataclass
class WhittedResult:
    image: np.ndarray                    # (H, W, 3) uint8
    frame_ms: list[float]                # device time of each timed frame (sum of its launches)
    host_ms: float                       # wall time of one frame (median), host work included
    launches: list[Launch]               # the last frame's launches, in order
    resources: dict                      # kernel -> KernelResources.as_dict()
    defines: dict
    step: str                            # the program that ran (library_shadows, 05_kernel_tree...)
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
    light_buffer: dict | None = None     # the shadow rays' light buffers, where the frame took them

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
        return sum(launch.rays for launch in self.launches if launch.kernel not in PACK_KERNELS + ("shade_records",))


def check_bounces(bounces) -> None:
    if isinstance(bounces, bool) or not isinstance(bounces, (int, np.integer)) \
            or not 0 <= bounces <= SceneFeatures.max_bounces:
        raise RtlabError(f"bounces must be a whole number from 0 to {SceneFeatures.max_bounces}, not {bounces!r}")


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
    check_bounces(bounces)
    defines = {"RT_SHADOWS": int(features.has_lights and shadows != "none"),
               "RT_MAX_DEPTH": min(int(bounces), int(features.max_bounces)),
               "RT_FRESNEL": FRESNEL_MODES[fresnel],
               "RT_WRITE_HITS": int(write_hits)}
    if tree:
        defines["RT_COMPACT"] = int(compact and schedule == "tree")
        defines["RT_TWO_PASS"] = int(shadows == "two-pass")
        defines["RT_WAVEFRONT"] = int(schedule == "wavefront")
    return defines


# Why many parameters: the public call's keyword options, each with a default; a call names one or two.
def render_whitted(scene: Scene, backend=None, variant: Variant | None = None, size: int | None = None,
                   shadows: str = "one-pass", bounces: int = 0, compact: bool = False, repeats: int = 1,
                   warmup: int = 0, write_hits: bool = False, fresnel: str = "schlick",
                   specialise: bool = True, device: str | None = None, schedule: str = "tree",
                   defines: dict | None = None, lab: bool = False) -> WhittedResult:
    """Render the scene's camera view with shadows and ``bounces`` levels of reflection/refraction
    (see the module docstring). Times ``repeats`` frames after ``warmup`` untimed ones. ``defines``
    adds or overrides -D switches (e.g. RT_CONSERVATIVE). ``variant`` None:
    rtlab.device.variants.default_variant(backend); parts a Variant leaves out (None) come from it.
    ``lab``: lab step 04's or 05's kernels instead of the library's."""
    if not hasattr(backend, "compile"):
        backend = get_backend(backend, device)
    scene = require_scene(scene)
    repeats = check_count(repeats, "repeats")
    check_bounces(bounces)
    scene.check_materials()
    scene.check_lights()
    variant = resolve_variant(variant, backend)
    tree = bounces > 0 or schedule == "wavefront"
    step = program_for("bounces" if tree else "shadows", variant, lab)
    camera = scene.camera if size is None else scene.camera.with_size(size)
    if len(scene.lights) > MAX_LIGHTS:
        raise RtlabError(f"scene {scene.name!r} has {len(scene.lights)} lights; the shading kernels take at most {MAX_LIGHTS}")
    ds = device_scene(scene, backend)
    features = ds.features(variant)
    if not specialise:
        features = features.general()
    wavefront = schedule == "wavefront"
    extra = shading_defines(features, shadows, bounces, fresnel, compact, write_hits, tree, schedule)
    extra.update(light_buffer_defines(variant, extra["RT_SHADOWS"], lab))
    extra.update(defines or {})
    program = load_program(backend, step, variant, features, **extra)
    ds.set_constants(program, camera, variant)
    args, light_buffer = ds.scene_args(variant), None
    if extra.get("RT_LIGHT_BUFFER"):
        args, lights, light_buffer = light_buffer_args(ds, variant, lab)
        program.set_constant("lights", lights)
    runner = FRAME_RUNNERS["wavefront" if wavefront else "tree" if tree else "shadows"](backend, program, args, camera, variant, shadows, extra, write_hits)
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
                           bool(extra.get("RT_COMPACT", 0)), schedule, backend.name, backend.device_name, variant,
                           light_buffer=light_buffer)
    if write_hits:
        t, tri, u, v = runner.primary_hits()
        result.hits = TraceResult(t, tri, u, v, result.median_ms, backend.name, backend.device_name)
        result.tree = runner.tree
    return result
