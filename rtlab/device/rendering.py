"""The renderer: primary rays with simple shading (the paper's Table 4 setting) on any backend."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..backends import get_backend
from ..scene.model import Scene
from .kernels import load_program, rays_per_work_item
from .layout import HIT_DTYPE
from .device_scene import device_scene
from .tracing import TraceResult, check_count, require_scene, unpack_hits
from .variants import Variant, program_for, resolve_variant


@dataclass
class RenderResult:
    image: np.ndarray                 # (H, W, 3) uint8
    kernel_ms: list[float]            # device time of each timed launch
    host_ms: float                    # wall time of one launch including host overhead (median)
    hits: TraceResult | None = None   # per-pixel hit records when asked for
    backend: str = ""
    device: str = ""
    variant: Variant = field(default_factory=Variant)
    resources: dict = field(default_factory=dict)

    @property
    def median_ms(self) -> float:
        return float(np.median(self.kernel_ms))

    @property
    def mrays_per_s(self) -> float:
        h, w = self.image.shape[:2]
        return h * w / (self.median_ms * 1e-3) / 1e6


# Why many parameters: the public call's keyword options, each with a default; a call names one or two.
def render(scene: Scene, backend=None, variant: Variant | None = None, size: int | None = None,
           repeats: int = 1, warmup: int = 0, write_hits: bool = False, device: str | None = None,
           lab: bool = False) -> RenderResult:
    """Render the scene's camera view. Times ``repeats`` launches after ``warmup`` untimed ones.
    ``variant`` None: rtlab.device.variants.default_variant(backend); parts a Variant leaves out (None)
    come from it. ``lab``: the lab steps' kernels for the variant instead of the library's."""
    if not hasattr(backend, "compile"):
        backend = get_backend(backend, device)
    scene = require_scene(scene)
    scene.check_lights()
    repeats = check_count(repeats, "repeats")
    variant = resolve_variant(variant, backend)
    camera = scene.camera if size is None else scene.camera.with_size(size)
    ds = device_scene(scene, backend)
    program = load_program(backend, program_for("trace", variant, lab), variant, ds.features(variant),
                           RT_WRITE_HITS=int(write_hits))
    ds.set_constants(program, camera, variant)
    n = camera.width * camera.height
    pixels = backend.empty(n * 4)
    hits = backend.empty(n * HIT_DTYPE.itemsize if write_hits else 4)
    args = ds.scene_args(variant) + [pixels, hits]
    lanes = rays_per_work_item(variant)           # a work-item takes `lanes` pixels of a row
    block = (max(1, variant.block[0] // lanes), variant.block[1])
    launch = lambda: program.launch("render_primary", (-(-camera.width // lanes), camera.height), block, args,
                                    constants=("frame", "lights", "materials"))
    for _ in range(warmup):
        launch()
    times, walls = [], []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        times.append(launch())
        walls.append((time.perf_counter() - t0) * 1e3)
    rgba = backend.to_host(pixels, np.uint32, n)
    image = rgba.view(np.uint8).reshape(camera.height, camera.width, 4)[:, :, :3].copy()
    result = RenderResult(image, times, float(np.median(walls)), backend=backend.name,
                          device=backend.device_name, variant=variant,
                          resources=program.resources("render_primary", block).as_dict())
    if write_hits:
        t, tri, u, v = unpack_hits(backend.to_host(hits, np.float32, 4 * n))
        result.hits = TraceResult(t, tri, u, v, result.median_ms, backend.name, backend.device_name)
    return result


def save_png(image: np.ndarray, path) -> None:
    from PIL import Image
    Image.fromarray(image).save(path)
