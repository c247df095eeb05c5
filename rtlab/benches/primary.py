"""Primary rays with simple shading (the paper's Table 4 setting, ``rtlab bench primary``): device time
(median of many launches after warm-up), Mrays/s, the compiler's resources, and the error against
the float64 reference beside every time. :func:`bench_render` is the timed render every other bench
of the renderer builds on."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..device.kernels import Variant
from ..scene.model import Scene
from .paper_figures import PAPER_SIZE, PAPER_TABLE4_FPS
from .tables import Table, fmt, report_markdown



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
                 check: bool = True, view: str = "preset", lab: bool = True) -> BenchRow:
    """Time the render kernel on the scene's camera; check its hits against the float64 reference.
    ``lab``: the lab steps' kernels, where the paper's variants live (the paper's tables); False: the
    library's (the same entry kernels, its own program)."""
    from ..device.rendering import render
    from ..device.variants import resolve_variant
    variant = resolve_variant(variant, backend)
    timed = render(scene, backend, variant, repeats=repeats, warmup=warmup, write_hits=False, lab=lab)
    row = BenchRow(scene.name, view, backend.name, backend.device_name, variant.label(), scene.camera.width,
                   timed.median_ms, timed.mrays_per_s, 1e3 / timed.median_ms,
                   timed.resources.get("registers"), timed.resources.get("occupancy"),
                   timed.resources.get("local_bytes"))
    row.extra["host_ms"] = timed.host_ms
    row.extra["spread_ms"] = (float(np.min(timed.kernel_ms)), float(np.max(timed.kernel_ms)))
    if check:
        from ..reference.check import check_render
        checked = render(scene, backend, variant, repeats=1, write_hits=True, lab=lab)
        row.error = check_render(scene, checked, scene.camera).as_dict()
    return row


def nvcc_render_report(variant: Variant, features, shared_pad: int = 0) -> dict | None:
    """nvcc's offline sm_90 report of the render kernel this variant runs (its step, defines and
    register cap): registers, stack, spill and shared bytes, and the occupancy at the variant's block
    with ``shared_pad`` more bytes of shared memory a block; None without nvcc."""
    from ..backends.nvcc import nvcc_available, nvcc_resources
    from ..backends.occupancy import SM90, cuda_occupancy
    from ..device.kernels import build_defines, build_options, kernel_source, primary_step
    if not nvcc_available():
        return None
    threads = variant.block[0] * variant.block[1]
    r = nvcc_resources(kernel_source(primary_step(variant), "cuda"), build_defines(variant, features),
                       block_threads=threads, extra_options=build_options(variant, "cuda")).get("render_primary")
    if r is None:
        return None
    return {"registers": r.registers, "local_bytes": r.local_bytes, "spill_bytes": r.spill_bytes,
            "shared_bytes": r.shared_bytes,
            "occupancy": cuda_occupancy(r.registers, threads, r.shared_bytes + shared_pad, SM90)}


COLUMNS = ("scene", "view", "backend", "device", "variant", "size", "median ms", "Mrays/s", "fps", "paper fps",
           "regs", "occupancy", "error vs float64 reference")


def table_rows(rows: list[BenchRow]) -> list[tuple[str, ...]]:
    """Cells under COLUMNS; the paper's fps (Table 4, stack) at its size, 1024², only."""
    out = []
    for r in rows:
        paper = PAPER_TABLE4_FPS["stack"].get(r.scene) if r.size == PAPER_SIZE else None
        out.append((r.scene, r.view, r.backend, r.device, r.variant, f"{r.size}²", f"{r.median_ms:.3f}",
                    f"{r.mrays:,.0f}", f"{r.fps:,.0f}", fmt(paper, ""), str(r.registers or "-"),
                    fmt(r.occupancy, ".0%"), r.error_text()))
    return out


def primary_tables(rows: list[BenchRow], title: str) -> list[Table]:
    return [Table(COLUMNS, table_rows(rows), title)]


def primary_markdown(rows: list[BenchRow], title: str, command: str) -> str:
    """A markdown block for a fragment of docs/results/: command, device, date, then the table."""
    return report_markdown(title, command, [f"{r.backend}: {r.device}" for r in rows], primary_tables(rows, title))
