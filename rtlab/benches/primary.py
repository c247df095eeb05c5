"""Benchmarks that print figures: device time (median of many launches after warm-up), Mrays/s, the
compiler's resources, and the error against the float64 reference beside every time."""
from __future__ import annotations

import datetime
import platform
from dataclasses import dataclass, field

import numpy as np

from ..device.kernels import Variant
from ..scene.model import Scene

# The paper's Table 4, stack single-ray column (fps at 1024x1024 on a GeForce 8800 GTS)
PAPER_STACK_FPS = {"bunny": 43.2, "sponza": 40.5, "kitchen": 39.6, "dragon": 30.4}


@dataclass
class BenchRow:
    scene: str
    view: str
    backend: str
    device: str
    variant: str
    size: int
    median_ms: float
    mrays: float
    fps: float
    registers: int | None
    occupancy: float | None
    local_bytes: int | None
    error: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)

    def error_text(self) -> str:
        e = self.error
        if not e:
            return "-"
        return (f"{e['mismatches']} mism. ({e['mismatch_rate']:.1e}), {e['ties']} ties, "
                f"max rel dt {e['t_rel_err_max']:.1e}, PSNR {e['psnr']:.1f}")


def bench_render(scene: Scene, backend, variant: Variant, repeats: int = 25, warmup: int = 3,
                 check: bool = True, view: str = "preset") -> BenchRow:
    """Time the render kernel on the scene's camera; check its hits against the float64 reference."""
    from ..device.rendering import render
    timed = render(scene, backend, variant, repeats=repeats, warmup=warmup, write_hits=False)
    row = BenchRow(scene.name, view, backend.name, backend.device_name, variant.label(), scene.camera.width,
                   timed.median_ms, timed.mrays_per_s, 1e3 / timed.median_ms,
                   timed.resources.get("registers"), timed.resources.get("occupancy"),
                   timed.resources.get("local_bytes"))
    row.extra["host_ms"] = timed.host_ms
    row.extra["spread_ms"] = (float(np.min(timed.kernel_ms)), float(np.max(timed.kernel_ms)))
    if check:
        from ..reference.check import check_render
        checked = render(scene, backend, variant, repeats=1, write_hits=True)
        row.error = check_render(scene, checked, scene.camera).as_dict()
    return row


def rows_markdown(rows: list[BenchRow], title: str, command: str) -> str:
    """A markdown block for docs/benchmarks.md: command, device, date, then the table."""
    date = datetime.date.today().isoformat()
    devices = sorted({f"{r.backend}: {r.device}" for r in rows})
    out = [f"### {title}", "", f"Command: `{command}`  ", f"Date: {date}; host: {platform.node()}; "
           f"devices: {'; '.join(devices)}", "",
           "| scene | view | backend | variant | size | median ms | Mrays/s | fps | regs | occupancy | error vs float64 reference |",
           "|---|---|---|---|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        occ = f"{r.occupancy:.0%}" if r.occupancy is not None else "-"
        out.append(f"| {r.scene} | {r.view} | {r.backend} | {r.variant} | {r.size}² | {r.median_ms:.3f} | "
                   f"{r.mrays:,.0f} | {r.fps:,.0f} | {r.registers or '-'} | {occ} | {r.error_text()} |")
    return "\n".join(out) + "\n"
