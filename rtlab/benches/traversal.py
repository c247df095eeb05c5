"""The paper's Table 4: kd-tree traversal variants (and the BVH of its future work) on the current
device. Primary rays with simple shading at 1024² (the paper's setting), one renderer launch per
variant through rtlab.benches.primary.bench_render: median device time, fps, Mrays/s, the error
against the float64 reference beside each time, and the resources the compiler gave the kernel - on the device
(Program.resources: CUDA registers and occupancy; NVIDIA OpenCL registers) and offline from nvcc
(registers, stack, shared memory, occupancy at the launch's block size) - beside the paper's
figures (GeForce 8800 GTS) and the speed-up over them.
"""
from __future__ import annotations

from dataclasses import dataclass

from ..device.kernels import Variant
from ..scene.model import Scene
from .paper_figures import PAPER_SIZE, PAPER_TABLE4_FPS, PAPER_TABLE4_OCCUPANCY, PAPER_TABLE4_REGISTERS
from .primary import BenchRow, bench_render, nvcc_render_report
from .tables import Table, fmt, report_markdown

TABLE4_VARIANTS = ("stack", "packet", "restart", "shortstack", "ropes", "bvh")


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


def bench_table4(scene: Scene, backend, traversals=TABLE4_VARIANTS, repeats: int = 25, check: bool = True,
                 view: str = "preset", base: Variant | None = None, progress=None) -> list[Table4Row]:
    """One Table 4 row group: every traversal on ``scene``'s camera on ``backend``."""
    from ..device.device_scene import device_scene
    base = base or Variant.paper()
    rows = []
    for name in traversals:
        variant = base.with_(traversal=name)
        if progress is not None:
            progress(f"{scene.name}/{view} {name} on {backend.name}")
        row = bench_render(scene, backend, variant, repeats=repeats, check=check, view=view)
        features = device_scene(scene, backend).features(variant)
        rows.append(Table4Row(name, row, nvcc_render_report(variant, features)))
    return rows


def resources_text(r: Table4Row) -> str:
    """Registers and occupancy: the device's where it reports them, else nvcc's offline figures."""
    b, n = r.bench, r.nvcc or {}
    regs = b.registers if b.registers else n.get("registers")
    occ = b.occupancy if b.occupancy is not None else n.get("occupancy")
    return f"{fmt(regs, 'd')} regs, {fmt(occ, '.0%')}"


def speedup_text(r: Table4Row) -> str:
    s = r.speedup()
    return "-" if s is None else f"{s:,.1f}×"


DETAIL_COLUMNS = ("scene", "view", "backend", "traversal", "median ms", "fps", "Mrays/s", "regs", "occupancy",
                  "private B", "nvcc regs / stack B / shared B / occ.", "error vs float64 reference", "paper fps",
                  "speed-up", "paper regs / occ.")


def detail_rows(rows: list[Table4Row]) -> list[tuple[str, ...]]:
    """Cells under DETAIL_COLUMNS: time, the compiler's resources, the error, the paper's figures."""
    out = []
    for r in rows:
        b, n = r.bench, r.nvcc
        nv = f"{n['registers']} / {n['local_bytes']} / {n['shared_bytes']} / {n['occupancy']:.0%}" if n else "-"
        paper_res = (f"{PAPER_TABLE4_REGISTERS[r.traversal]} / {PAPER_TABLE4_OCCUPANCY[r.traversal]:.0%}"
                     if r.traversal in PAPER_TABLE4_REGISTERS else "-")
        paper_fps = r.paper_fps if b.size == PAPER_SIZE else None
        out.append((b.scene, b.view, b.backend, r.traversal, f"{b.median_ms:.3f}", f"{b.fps:,.1f}", f"{b.mrays:,.1f}",
                    fmt(b.registers or None, "d"), fmt(b.occupancy, ".0%"), fmt(b.local_bytes, "d"), nv,
                    b.error_text(), fmt(paper_fps, ".1f"), speedup_text(r), paper_res))
    return out


def pivot_table(rows: list[Table4Row]) -> Table:
    """The paper's layout: one row per scene (and view, backend), one column per traversal,
    'fps (paper fps)'; last row registers and occupancy (the paper's in parentheses)."""
    traversals = list(dict.fromkeys(r.traversal for r in rows))
    groups: dict = {}
    for r in rows:
        groups.setdefault((r.bench.scene, r.bench.view, r.bench.backend), {})[r.traversal] = r
    cells = []
    for (scene, view, backend), by in groups.items():
        line = [scene, view, backend]
        for t in traversals:
            r = by.get(t)
            paper = r.paper_fps if r is not None and r.bench.size == PAPER_SIZE else None
            line.append("-" if r is None else f"{r.bench.fps:,.1f}" + (f" ({paper})" if paper else ""))
        cells.append(tuple(line))
    regs = []
    for t in traversals:
        r = next(x for x in rows if x.traversal == t)
        paper = PAPER_TABLE4_REGISTERS.get(t)
        regs.append(resources_text(r) + (f" ({paper}, {PAPER_TABLE4_OCCUPANCY[t]:.0%})" if paper else ""))
    if rows:
        cells.append(("registers, occupancy", "", "", *regs))
    return Table(("scene", "view", "backend", *traversals), cells,
                 note="fps per traversal, the paper's (GeForce 8800 GTS, 1024²) in parentheses; last row: registers "
                      "and occupancy as the device reports them, else nvcc's offline figures for sm_90 (the paper's "
                      "in parentheses).")


def table4_tables(rows: list[Table4Row]) -> list[Table]:
    """The pivot (the paper's layout), then the details of every row."""
    return [pivot_table(rows),
            Table(DETAIL_COLUMNS, detail_rows(rows),
                  note="Details: device time (median), the compiler's resources, the error against the float64 "
                       "reference.")]


def table4_markdown(rows: list[Table4Row], command: str) -> str:
    """Markdown for a fragment of docs/results/: command, devices, the pivot (paper's layout), then
    details."""
    size = rows[0].bench.size if rows else PAPER_SIZE
    return report_markdown(f"Table 4: traversal variants, primary rays, {size}x{size}", command,
                           [f"{r.bench.backend}: {r.bench.device}" for r in rows], table4_tables(rows))
