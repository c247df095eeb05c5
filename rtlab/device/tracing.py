"""The trace API: closest hits of arbitrary rays on any backend. The renderer, the tests and the
benchmarks all go through here.

    hits = rtlab.trace(scene, origins, directions)            # t, tri, u, v per ray
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..backends import get_backend
from ..errors import RtlabError
from ..scene.model import Scene
from .kernels import DEFAULT_PRIMARY_STEP, TRACE_THREADS, Variant, load_program, primary_step, rays_per_work_item
from .layout import HIT_DTYPE, float4_rows
from .scene import device_scene

TRACE_BLOCK = TRACE_THREADS    # threads a block of trace_rays (a profiler may sweep it)
# Directions whose largest component lies outside this range are scaled by a power of two into
# [1, 2) before tracing (_scaled_directions): below it their squares underflow (a length of 1e-19
# read as a zero direction), above it products with coordinates overflow.
DIRECTION_RANGE = (2.0 ** -16, 2.0 ** 16)
# What trace(), render() and render_whitted() run when no variant is named (default_variant): the
# watertight test (Woop et al. 2013) and its conservative traversal, which let no ray through shared
# edges and vertices. Moller-Trumbore, the paper's test and Variant()'s, let 13-24 % of the rays aimed
# at edges and vertices of the benchmark views through (docs/benchmarks.md, issue 13). On a GPU the
# BVH in 8x16 blocks: twice the kd stack's rays per second on most benchmark views, and tile-shaped
# warps trace indoor views 18-19 % faster than 32x4 rows (H100, docs/benchmarks.md, issue 12). On a
# CPU the kd stack traversal, which PoCL runs faster than the single-ray BVH. The lab steps and the
# paper's benches name their variants and keep the paper's.
DEFAULT_VARIANT = Variant(intersection="watertight")
GPU_DEFAULT_VARIANT = Variant(traversal="bvh", intersection="watertight", block=(8, 16))


def default_variant(backend) -> Variant:
    """The variant the library runs on ``backend`` when none is named (see DEFAULT_VARIANT)."""
    return GPU_DEFAULT_VARIANT if backend.is_gpu() else DEFAULT_VARIANT


@dataclass
class TraceResult:
    t: np.ndarray        # (N,) float32, inf where missed (tmax where tmax is finite)
    tri: np.ndarray      # (N,) int32, -1 where missed
    u: np.ndarray
    v: np.ndarray
    kernel_ms: float     # device time of the tracing kernel (median over the timed launches)
    backend: str = ""
    device: str = ""
    launches_ms: tuple = ()   # each timed launch's device time (``repeats`` of trace())

    @property
    def hit(self) -> np.ndarray:
        return self.tri >= 0


def unpack_hits(records: np.ndarray) -> tuple[np.ndarray, ...]:
    h = records.view(HIT_DTYPE).reshape(-1)
    return h["t"].copy(), h["tri"].copy(), h["u"].copy(), h["v"].copy()


def _rays_f32(a, name: str) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != 2 or a.shape[1] != 3:
        raise RtlabError(f"{name} must have shape (N, 3), got {a.shape}")
    return a.astype(np.float32, copy=False)


def _scaled_directions(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directions whose largest component is outside DIRECTION_RANGE, divided by a power of two s so
    that it lies in [1, 2): (directions, s per ray). A power of two changes no rounding, so the
    kernel traces the very same ray, o + t d = o + (t s) (d / s): its interval is (tmin s, tmax s)
    and t = t_kernel / s exactly. NaN, infinite and zero directions keep s = 1 (they miss)."""
    largest = np.abs(directions).max(axis=1, initial=0.0).astype(np.float64)
    low, high = DIRECTION_RANGE
    rescale = np.isfinite(largest) & (largest > 0.0) & ((largest < low) | (largest > high))
    scale = np.ones(len(directions))
    if rescale.any():
        exponent = np.frexp(largest[rescale])[1]           # largest = f 2^e, f in [0.5, 1)
        scale[rescale] = np.ldexp(1.0, exponent - 1)        # largest / scale in [1, 2)
        directions = directions.astype(np.float64)
        directions[rescale] /= scale[rescale, None]
        directions = directions.astype(np.float32)
    return directions, scale


def _ray_bounds(tmin, tmax, n: int) -> tuple[np.ndarray, np.ndarray]:
    """tmin and tmax as (n,) float64; a negative tmin is an error (an empty interval is not)."""
    try:
        lo = np.broadcast_to(np.asarray(tmin, np.float64), (n,))
        hi = np.broadcast_to(np.asarray(tmax, np.float64), (n,))
    except ValueError:
        raise RtlabError(f"tmin and tmax must be scalars or one value per ray ({n}), got shapes "
                         f"{np.shape(tmin)} and {np.shape(tmax)}") from None
    if np.any(lo < 0.0):
        first = int(np.flatnonzero(lo < 0.0)[0])
        raise RtlabError(f"tmin must be >= 0, got {lo[first]:g} (ray {first}): the traversals start at the ray's "
                         "origin; to trace from behind it, move the origin to o + tmin d and trace from 0")
    return lo, hi


_ray_buffers: dict = {}


def ray_buffers(backend, n: int):
    """Device buffers for n rays and their hits (origins, directions, hits), kept per backend (the
    object itself: backends live as long as the process) for the most recent ray count: a caller
    tracing batch after batch of one size allocates once."""
    entry = _ray_buffers.get(backend)
    if entry is None or entry[0] != n:
        entry = (n, (backend.empty(n * 16), backend.empty(n * 16), backend.empty(n * HIT_DTYPE.itemsize)))
        _ray_buffers[backend] = entry
    return entry[1]


def trace(scene: Scene, origins, directions, backend=None, variant: Variant | None = None,
          tmin: float = 0.0, tmax: float = np.inf, device: str | None = None,
          defines: dict | None = None, min_stack_size: int = 0, repeats: int = 1,
          warmup: int = 0, width: int | None = None) -> TraceResult:
    """Closest hit along each ray o + t d within (tmin, tmax), t in units of |d| (d need not be
    normalised: any finite, non-zero length works). At exactly equal t the lowest triangle id
    wins, in every traversal and triangle test (as in the float64 reference), so all variants
    report the same triangle at a tie: duplicated triangles, or two triangles of an edge whose
    float32 t come out equal. With the watertight test (the default) every traversal returns the
    very same ids; with the others, where the two t of an edge differ by rounding, the packet and
    the BVH may report the nearer one the kd-tree's cells hide (a tie by the reference's rule,
    rtlab.reference.compare_hits). Rays with NaN/Inf components or a zero
    direction are reported as misses. ``tmin``, ``tmax``: scalars or one per ray; tmin must be
    >= 0 (a RtlabError otherwise). ``variant`` None: default_variant(backend) (watertight;
    the BVH on a GPU; a Variant you name keeps its own test and traversal). ``backend`` is a Backend or a name ("opencl", "cuda").
    ``defines`` adds or overrides -D switches (e.g. RT_CONSERVATIVE); ``min_stack_size`` compiles a
    stack at least that deep, so one program serves scenes of different depths. ``repeats`` times that
    many launches on the same rays after ``warmup`` untimed ones (benchmarks); ``kernel_ms`` is their
    median device time. ``width``: the rays form an image of that many columns, row-major (as
    camera_rays gives them); the kernel then takes them in tiles of ``variant.block`` (and its ray
    order), so a warp traces neighbouring rays: up to 19 % faster on indoor views (docs/benchmarks.md).
    The hits are the same either way."""
    origins, directions = _rays_f32(origins, "origins"), _rays_f32(directions, "directions")
    if origins.shape != directions.shape:
        raise RtlabError(f"origins {origins.shape} and directions {directions.shape} differ in shape")
    n = origins.shape[0]
    lo, hi = _ray_bounds(tmin, tmax, n)
    if not hasattr(backend, "compile"):
        backend = get_backend(backend, device)
    variant = variant or default_variant(backend)
    ds = device_scene(scene, backend)
    if n == 0:
        empty = np.zeros(0, np.float32)
        return TraceResult(empty, np.zeros(0, np.int32), empty, empty, 0.0, backend.name, backend.device_name)
    directions, scale = _scaled_directions(directions)
    features = ds.features(variant)
    if features.stack_size < min_stack_size:
        features = replace(features, stack_size=int(min_stack_size))
    program = load_program(backend, primary_step(variant), variant, features, **(defines or {}))
    ds.set_constants(program, None, variant)
    o_buf, d_buf, h_buf = ray_buffers(backend, n)
    backend.fill(o_buf, float4_rows(origins, lo * scale))
    backend.fill(d_buf, float4_rows(directions, hi * scale))
    items = -(-n // rays_per_work_item(variant))        # a packet traversal takes several rays an item
    launch = _grid_launch(program, ds, variant, n, width, (o_buf, d_buf, h_buf)) if width else \
        (lambda: program.launch("trace_rays", (items,), (TRACE_BLOCK,),
                                ds.scene_args(variant) + [o_buf, d_buf, h_buf, np.int32(n)], constants=("frame",)))
    times = [launch() for _ in range(max(0, warmup) + max(1, repeats))][max(0, warmup):]
    t, tri, u, v = unpack_hits(backend.to_host(h_buf, np.float32, 4 * n))
    if np.any(scale != 1.0):
        t = (t / scale).astype(np.float32)
    return TraceResult(t, tri, u, v, float(np.median(times)), backend.name, backend.device_name, tuple(times))


def _grid_launch(program, ds, variant: Variant, n: int, width: int, buffers):
    """The launch of trace_ray_grid over rays laid out as rows of ``width`` (trace's ``width``)."""
    width = int(width)
    if width <= 0 or n % width:
        raise RtlabError(f"width={width}: {n} rays do not form rows of that many")
    if primary_step(variant) != DEFAULT_PRIMARY_STEP:
        raise RtlabError(f"width= needs lab step {DEFAULT_PRIMARY_STEP}'s kernels; {variant.label()} runs in "
                         f"{primary_step(variant)}'s, which trace a plain list of rays")
    height = n // width
    args = ds.scene_args(variant) + list(buffers) + [np.int32(width), np.int32(height)]
    return lambda: program.launch("trace_ray_grid", (width, height), variant.block, args, constants=("frame",))
