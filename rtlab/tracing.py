"""The trace API: closest hits of arbitrary rays on any backend. The renderer, the tests and the
benchmarks all go through here.

    hits = rtlab.trace(scene, origins, directions)            # t, tri, u, v per ray
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .backends import get_backend
from .device_scene import DeviceScene
from .errors import RtlabError
from .kernels import Variant, load_program, primary_step, rays_per_work_item
from .layout import HIT_DTYPE, float4_rows
from .scene.model import Camera, Scene

PRIMARY_STEP = "00_primary"
TRACE_BLOCK = 128

_device_scenes: dict = {}
DEVICE_SCENES_KEPT = 8   # uploads kept alive; the oldest goes (and frees its buffers) past that


def device_scene(scene: Scene, backend) -> DeviceScene:
    """The scene uploaded to ``backend``, once per (scene object, backend), for the most recently
    used few: benches that derive many scenes (material presets) do not hold every upload."""
    key = (id(scene), id(backend))
    entry = _device_scenes.pop(key, None)
    if entry is None or entry[0] is not scene:
        entry = (scene, DeviceScene.upload(backend, scene))
    _device_scenes[key] = entry            # most recent last
    while len(_device_scenes) > DEVICE_SCENES_KEPT:
        _device_scenes.pop(next(iter(_device_scenes)))
    return entry[1]


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


_ray_buffers: dict = {}


def ray_buffers(backend, n: int):
    """Device buffers for n rays and their hits (origins, directions, hits), kept per backend for the
    most recent ray count: a caller tracing batch after batch of one size allocates once."""
    key = id(backend)
    entry = _ray_buffers.get(key)
    if entry is None or entry[0] is not backend or entry[1] != n:
        entry = (backend, n, (backend.empty(n * 16), backend.empty(n * 16), backend.empty(n * HIT_DTYPE.itemsize)))
        _ray_buffers[key] = entry
    return entry[2]


def trace(scene: Scene, origins, directions, backend=None, variant: Variant | None = None,
          tmin: float = 0.0, tmax: float = np.inf, device: str | None = None,
          defines: dict | None = None, min_stack_size: int = 0, repeats: int = 1,
          warmup: int = 0) -> TraceResult:
    """Closest hit along each ray within (tmin, tmax). Rays with NaN/Inf components or a zero
    direction are reported as misses. ``backend`` is a Backend or a name ("opencl", "cuda").
    ``defines`` adds or overrides -D switches (e.g. RT_CONSERVATIVE); ``min_stack_size`` compiles a
    stack at least that deep, so one program serves scenes of different depths. ``repeats`` times that
    many launches on the same rays after ``warmup`` untimed ones (benchmarks); ``kernel_ms`` is their
    median device time."""
    origins, directions = _rays_f32(origins, "origins"), _rays_f32(directions, "directions")
    if origins.shape != directions.shape:
        raise RtlabError(f"origins {origins.shape} and directions {directions.shape} differ in shape")
    if not hasattr(backend, "compile"):
        backend = get_backend(backend, device)
    variant = variant or Variant()
    ds = device_scene(scene, backend)
    n = origins.shape[0]
    if n == 0:
        empty = np.zeros(0, np.float32)
        return TraceResult(empty, np.zeros(0, np.int32), empty, empty, 0.0, backend.name, backend.device_name)
    features = ds.features(variant)
    if features.stack_size < min_stack_size:
        features = replace(features, stack_size=int(min_stack_size))
    program = load_program(backend, primary_step(variant), variant, features, **(defines or {}))
    ds.set_constants(program, None, variant)
    o_buf, d_buf, h_buf = ray_buffers(backend, n)
    backend.fill(o_buf, float4_rows(origins, tmin))
    backend.fill(d_buf, float4_rows(directions, tmax))
    args = ds.scene_args(variant) + [o_buf, d_buf, h_buf, np.int32(n)]
    items = -(-n // rays_per_work_item(variant))
    times = [program.launch("trace_rays", (items,), (TRACE_BLOCK,), args, constants=("frame",))
             for _ in range(max(0, warmup) + max(1, repeats))][max(0, warmup):]
    t, tri, u, v = unpack_hits(backend.to_host(h_buf, np.float32, 4 * n))
    return TraceResult(t, tri, u, v, float(np.median(times)), backend.name, backend.device_name, tuple(times))


def camera_rays(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """The primary rays of every pixel in float32, row-major from the top-left pixel, built with the
    same operations as camera_ray() in kernels/shared/rt_types.h."""
    eye, u, v, w = camera.basis()
    x = np.arange(camera.width, dtype=np.float32)
    y = np.arange(camera.height, dtype=np.float32)
    one, two, half = np.float32(1), np.float32(2), np.float32(0.5)
    sx = two * (x + half) / np.float32(camera.width) - one
    sy = one - two * (y + half) / np.float32(camera.height)
    sx, sy = np.meshgrid(sx, sy)
    d = (w[None, None, :] + u[None, None, :] * sx[..., None]) + v[None, None, :] * sy[..., None]
    d = d * (one / np.sqrt((d * d).sum(axis=-1, dtype=np.float32)))[..., None]
    d = d.reshape(-1, 3).astype(np.float32)
    o = np.broadcast_to(eye, d.shape).astype(np.float32)
    return o, d
