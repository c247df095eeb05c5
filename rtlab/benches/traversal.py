"""The paper's Table 4: kd-tree traversal variants (and the BVH of its future work) on the current
device. Primary rays with simple shading at 1024² (the paper's setting), one renderer launch per
variant through rtlab.benches.primary.bench_render: median device time, fps, Mrays/s, the error against the
float64 reference beside each time, and the resources the compiler gave the kernel - on the device
(Program.resources: CUDA registers and occupancy; NVIDIA OpenCL registers) and offline from nvcc
(registers, stack, shared memory, occupancy at the launch's block size) - beside the paper's
figures (GeForce 8800 GTS) and the speed-up over them.
"""
from __future__ import annotations

import datetime
import platform
from dataclasses import dataclass

from .primary import BenchRow, bench_render
from ..device.kernels import Variant, build_defines, kernel_source, primary_step
from ..scene.model import Scene

TABLE4_VARIANTS = ("stack", "packet", "restart", "shortstack", "ropes", "bvh")
# The paper's Table 4: fps at 1024x1024, primary rays, simple shading; "-" where it gave none
PAPER_TABLE4_FPS = {
    "stack": {"bunny": 43.2, "sponza": 40.5, "kitchen": 39.6, "dragon": 30.4},
    "packet": {"bunny": 15.8, "sponza": 16.5},
    "restart": {"bunny": 30.9, "sponza": 28.6, "kitchen": 28.9, "dragon": 21.4},
    "shortstack": {"bunny": 31.7, "sponza": 29.5, "kitchen": 28.2, "dragon": 21.8},
    "ropes": {"bunny": 38.4, "sponza": 34.4, "kitchen": 33.4, "dragon": 26.4},
}
PAPER_TABLE4_REGISTERS = {"stack": 18, "packet": 20, "restart": 17, "shortstack": 28, "ropes": 24}
PAPER_TABLE4_OCCUPANCY = {"stack": 0.50, "packet": 0.50, "restart": 0.50, "shortstack": 0.33, "ropes": 0.33}
PAPER_SIZE = 1024


@dataclass
class Table4Row:
    traversal: str
    bench: BenchRow             # time, Mrays/s, device resources, error against the reference
    nvcc: dict | None           # offline CUDA report of the render kernel (None without nvcc)

    @property
    def paper_fps(self) -> float | None:
        return PAPER_TABLE4_FPS.get(self.traversal, {}).get(self.bench.scene)

    def speedup(self) -> float | None:
        """fps over the paper's, at the paper's image size only."""
        paper = self.paper_fps
        return self.bench.fps / paper if paper and self.bench.size == PAPER_SIZE else None


def nvcc_report(variant: Variant, features) -> dict | None:
    """Offline CUDA resources of the render kernel for this variant and scene, or None without nvcc."""
    from ..backends.nvcc import nvcc_available, nvcc_resources
    if not nvcc_available():
        return None
    threads = variant.block[0] * variant.block[1]
    report = nvcc_resources(kernel_source(primary_step(variant), "cuda"), build_defines(variant, features),
                            block_threads=threads)
    r = report.get("render_primary")
    return None if r is None else {"registers": r.registers, "local_bytes": r.local_bytes,
                                   "shared_bytes": r.shared_bytes, "spill_bytes": r.spill_bytes,
                                   "occupancy": r.occupancy}


def bench_table4(scene: Scene, backend, traversals=TABLE4_VARIANTS, repeats: int = 25, check: bool = True,
                 view: str = "preset", base: Variant | None = None, progress=None) -> list[Table4Row]:
    """One Table 4 row group: every traversal on ``scene``'s camera on ``backend``."""
    from ..device.scene import device_scene
    base = base or Variant()
    rows = []
    for name in traversals:
        variant = base.with_(traversal=name)
        if progress is not None:
            progress(f"{scene.name}/{view} {name} on {backend.name}")
        row = bench_render(scene, backend, variant, repeats=repeats, check=check, view=view)
        features = device_scene(scene, backend).features(variant)
        rows.append(Table4Row(name, row, nvcc_report(variant, features)))
    return rows


def _fmt(value, spec: str, missing: str = "-") -> str:
    return missing if value is None else format(value, spec)


def resources_text(r: Table4Row) -> str:
    """Registers and occupancy: the device's where it reports them, else nvcc's offline figures."""
    b, n = r.bench, r.nvcc or {}
    regs = b.registers if b.registers else n.get("registers")
    occ = b.occupancy if b.occupancy is not None else n.get("occupancy")
    return f"{_fmt(regs, 'd')} regs, {_fmt(occ, '.0%')}"


def speedup_text(r: Table4Row) -> str:
    s = r.speedup()
    return "-" if s is None else f"{s:,.1f}×"


def table4_rows_markdown(rows: list[Table4Row]) -> list[str]:
    out = ["| scene | view | backend | traversal | median ms | fps | Mrays/s | regs | occupancy | private B | "
           "nvcc regs / stack B / shared B / occ. | error vs float64 reference | paper fps | speed-up | paper regs / occ. |",
           "|---|---|---|---|---:|---:|---:|---:|---:|---:|---|---|---:|---:|---|"]
    for r in rows:
        b, n = r.bench, r.nvcc
        nv = (f"{n['registers']} / {n['local_bytes']} / {n['shared_bytes']} / {n['occupancy']:.0%}" if n else "-")
        paper_res = (f"{PAPER_TABLE4_REGISTERS[r.traversal]} / {PAPER_TABLE4_OCCUPANCY[r.traversal]:.0%}"
                     if r.traversal in PAPER_TABLE4_REGISTERS else "-")
        out.append(f"| {b.scene} | {b.view} | {b.backend} | {b.variant} | {b.median_ms:.3f} | {b.fps:,.1f} | "
                   f"{b.mrays:,.1f} | {_fmt(b.registers or None, 'd')} | {_fmt(b.occupancy, '.0%')} | {_fmt(b.local_bytes, 'd')} | {nv} | "
                   f"{b.error_text()} | {_fmt(r.paper_fps, '.1f')} | {speedup_text(r)} | {paper_res} |")
    return out


def table4_pivot_markdown(rows: list[Table4Row]) -> list[str]:
    """The paper's layout: one row per scene (and view, backend), one column per traversal,
    'fps (paper fps)'."""
    traversals = list(dict.fromkeys(r.traversal for r in rows))
    groups: dict = {}
    for r in rows:
        groups.setdefault((r.bench.scene, r.bench.view, r.bench.backend), {})[r.traversal] = r
    out = ["| scene | view | backend | " + " | ".join(traversals) + " |",
           "|---|---|---|" + "---:|" * len(traversals)]
    for (scene, view, backend), by in groups.items():
        cells = []
        for t in traversals:
            r = by.get(t)
            if r is None:
                cells.append("-")
                continue
            paper = r.paper_fps
            cells.append(f"{r.bench.fps:,.1f}" + (f" ({paper})" if paper and r.bench.size == PAPER_SIZE else ""))
        out.append(f"| {scene} | {view} | {backend} | " + " | ".join(cells) + " |")
    regs = []
    for t in traversals:
        r = next(x for x in rows if x.traversal == t)
        paper = PAPER_TABLE4_REGISTERS.get(t)
        regs.append(resources_text(r) + (f" ({paper}, {PAPER_TABLE4_OCCUPANCY[t]:.0%})" if paper else ""))
    out.append("| registers, occupancy | | | " + " | ".join(regs) + " |")
    return out


def table4_markdown(rows: list[Table4Row], command: str) -> str:
    """Markdown for docs/benchmarks.md: command, devices, the pivot (paper's layout), then details."""
    size = rows[0].bench.size if rows else PAPER_SIZE
    devices = sorted({f"{r.bench.backend}: {r.bench.device}" for r in rows})
    out = [f"### Table 4: traversal variants, primary rays, {size}x{size}", "",
           f"Command: `{command}`  ", f"Date: {datetime.date.today().isoformat()}; host: {platform.node()}; "
           f"devices: {'; '.join(devices)}", "",
           "fps per traversal, the paper's (GeForce 8800 GTS, 1024²) in parentheses; last row: registers and "
           "occupancy as the device reports them, else nvcc's offline figures for sm_90 (the paper's in "
           "parentheses).", ""]
    out += table4_pivot_markdown(rows)
    out += ["", "Details: device time (median), the compiler's resources, the error against the float64 reference.", ""]
    out += table4_rows_markdown(rows)
    return "\n".join(out) + "\n"
