"""The paper's whole evaluation on the current device: Tables 2-5, Figs. 4-5 and the memory placement
study of §3.1.1, in one call (`rtlab bench paper`).

Each section calls its own bench module (imported when it runs; a module that is not there yet is
named in the output and the run goes on) and leaves in ``DIR/<backend>-<device>/``:
``<section>.json`` (its rows and markdown, so a second run skips finished sections: resumable),
then, for the whole run, ``paper.md`` (every section's table: the paper's figure, ours, the
speed-up, registers/occupancy and the error against the float64 reference beside each time),
``paper.csv`` (one line per timed variant), and PNG plots: fig4.png, fig5.png and
error_vs_time.png (each variant a point).
"""
from __future__ import annotations

import csv
import datetime
import json
import math
import platform
import re
import time
import traceback
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from .paper_figures import PAPER_SIZE
from .tables import Table, fmt

SECTIONS = ("table2", "table3", "table4", "table5", "memory", "fig4", "fig5")
PAPER_SCENES = ("bunny", "sponza", "kitchen", "dragon")
SECTION_TITLES = {"table2": "Table 2: kd-tree statistics", "table3": "Table 3: triangle tests",
                  "table4": "Table 4: traversal variants", "table5": "Table 5: shadows and secondary rays",
                  "memory": "§3.1.1: memory placement", "fig4": "Fig. 4: block size and ray order",
                  "fig5": "Fig. 5: registers and occupancy"}


@dataclass
class PaperRow:
    """One timed variant: what paper.csv holds and error_vs_time.png plots."""
    section: str
    scene: str
    variant: str
    backend: str
    device: str
    size: int
    median_ms: float
    mrays: float
    fps: float
    paper: float | None = None       # the paper's figure for this cell
    paper_unit: str = ""             # "fps" or "ms"
    speedup: float | None = None     # ours over the paper's (same unit, higher is better)
    registers: int | None = None
    occupancy: float | None = None
    mismatches: int | None = None    # against the float64 reference (triangle ids, ties apart)
    ties: int | None = None
    t_rel_err_max: float | None = None
    psnr: float | None = None
    differs: int | None = None       # hits/pixels differing from the section's base variant
    note: str = ""


@dataclass
class SectionResult:
    section: str
    rows: list = field(default_factory=list)       # PaperRow dicts
    markdown: str = ""
    status: str = "done"                           # done, skipped: ..., failed: ..., missing: ...
    seconds: float = 0.0
    extra: dict = field(default_factory=dict)      # raw rows for plots (launch rows)


def _err(e: dict | None) -> dict:
    """Reference error fields of any bench module's error dict."""
    e = e or {}
    return {"mismatches": e.get("mismatches"), "ties": e.get("ties"), "t_rel_err_max": e.get("t_rel_err_max"),
            "psnr": e.get("psnr")}


# Why many parameters: the table's knobs, passed through from its `rtlab bench` command.
def _bench_row(section, b, paper=None, unit="fps", speedup=None, registers=None, occupancy=None, note="",
               differs=None) -> PaperRow:
    return PaperRow(section, b.scene + ("" if b.view == "preset" else f"/{b.view}"), b.variant, b.backend, b.device,
                    b.size, b.median_ms, b.mrays, b.fps, paper, unit if paper else "", speedup,
                    registers if registers is not None else (b.registers or None),
                    occupancy if occupancy is not None else b.occupancy, differs=differs, note=note, **_err(b.error))


# ---- sections --------------------------------------------------------------------------------

def section_table2(ctx) -> SectionResult:
    from ..device.device_scene import scene_kdtree
    from .build import table2
    entries = [(name, scene_kdtree(ctx.scene(name)), ctx.scene(name).n_triangles) for name in ctx.scenes]
    return SectionResult("table2", [], table2(entries).markdown())


def section_table3(ctx) -> SectionResult:
    from .intersect import bench_table3, table3_markdown
    from .paper_figures import PAPER_TABLE3_MS, PAPER_TABLE3_REGISTERS
    rows, paper_rows = [], []
    for name in [s for s in ctx.scenes if s in ("bunny", "sponza")] or ctx.scenes[:1]:
        ctx.progress(f"Table 3: {name}")
        rows += bench_table3(ctx.scene(name), ctx.backend, ["moller", "wald", "plucker", "watertight"], ctx.size,
                             repeats=ctx.repeats, render_size=ctx.size, render_repeats=ctx.repeats, check=ctx.check)
    for r in rows:
        paper = PAPER_TABLE3_MS.get(r.scene, {}).get(r.isect) if r.size == PAPER_SIZE else None
        paper_rows.append(PaperRow("table3-loop", r.scene, f"{r.isect} (1000-triangle loop)", r.backend, r.device,
                                   r.size, r.median_ms, r.mtests, 1e3 / r.median_ms, paper, "ms" if paper else "",
                                   paper / r.median_ms if paper else None,
                                   r.nvcc["registers"] if r.nvcc else None, r.nvcc["occupancy"] if r.nvcc else None,
                                   note=f"Mtests/s in the Mrays/s column; paper regs {PAPER_TABLE3_REGISTERS.get(r.isect, '-')}",
                                   **_err(r.error)))
        if r.render is not None:
            paper_rows.append(_bench_row("table3-render", r.render))
    return SectionResult("table3", [asdict(p) for p in paper_rows], table3_markdown(rows, ctx.command))


def section_table4(ctx) -> SectionResult:
    from .traversal import TABLE4_VARIANTS, bench_table4, table4_markdown
    rows = []
    for name in ctx.scenes:
        rows += bench_table4(ctx.scene(name), ctx.backend, TABLE4_VARIANTS, repeats=ctx.repeats, check=ctx.check,
                             progress=ctx.progress)
    paper_rows = []
    for r in rows:
        n = r.nvcc or {}
        regs = r.bench.registers or n.get("registers")
        occ = r.bench.occupancy if r.bench.occupancy is not None else n.get("occupancy")
        paper_rows.append(_bench_row("table4", r.bench, r.paper_fps if r.bench.size == PAPER_SIZE else None, "fps",
                                     r.speedup(), regs, occ))
    return SectionResult("table4", [asdict(p) for p in paper_rows], table4_markdown(rows, ctx.command))


def section_table5(ctx) -> SectionResult:
    from .shadows_bounces import PACK_KERNELS, bench_bounces, bench_shadows, table5_markdown
    rows = []
    for name in [s for s in ctx.scenes if s in ("bunny", "sponza", "kitchen")]:
        for mode in ("one-pass", "two-pass"):
            ctx.progress(f"Table 5: {name} shadows {mode}")
            rows.append(bench_shadows(ctx.scene(name), ctx.backend, mode, ctx.size, ctx.repeats,
                                      check_size=128 if ctx.check else 0))
    for name in [s for s in ctx.scenes if s in ("sponza", "kitchen")]:
        for depth in (1, 2, 3):
            ctx.progress(f"Table 5: {name} {depth} bounces")
            rows.append(bench_bounces(ctx.scene(name), ctx.backend, depth, ctx.size, ctx.repeats,
                                      check_size=128 if ctx.check else 0))
    paper_rows = []
    for r in rows:
        regs = [k.get("registers") for n, k in r.kernels.items() if n not in PACK_KERNELS and k.get("registers")]
        occs = [k.get("occupancy") for n, k in r.kernels.items() if n not in PACK_KERNELS and k.get("occupancy") is not None]
        paper = r.paper_fps if r.size == PAPER_SIZE else None
        mrays = r.rays / (r.median_ms * 1e-3) / 1e6 if r.median_ms else math.nan
        paper_rows.append(PaperRow(f"table5-{r.table}", r.scene, r.mode, r.backend, r.device, r.size, r.median_ms,
                                   mrays, r.fps, paper, "fps" if paper else "", r.fps / paper if paper else None,
                                   max(regs) if regs else None, min(occs) if occs else None,
                                   psnr=r.error.get("psnr") if r.error else None,
                                   note=(f"error at {r.error.get('size')}²: ray tree differs in "
                                         f"{r.error.get('tree_pixels')} px" if r.error else "")))
    return SectionResult("table5", [asdict(p) for p in paper_rows], table5_markdown(rows, ctx.command))


def section_memory(ctx) -> SectionResult:
    from .memory import bench_memory, compiler_report, memory_markdown
    rows = []
    for name in [s for s in ctx.scenes if s in ("bunny", "dragon")] or ctx.scenes[:1]:
        rows += bench_memory(ctx.scene(name), ctx.backend, repeats=ctx.repeats, check=ctx.check, progress=ctx.progress)
    paper_rows = []
    for r in rows:
        n = r.nvcc or {}
        d = r.diff
        paper_rows.append(_bench_row("memory", r.bench, registers=r.bench.registers or n.get("registers"),
                                     occupancy=r.bench.occupancy if r.bench.occupancy is not None else n.get("occupancy"),
                                     differs=(d["tri"] + d["t_bits"] + d["pixels"]) if d else None,
                                     note=r.placement))
    return SectionResult("memory", [asdict(p) for p in paper_rows], memory_markdown(rows, ctx.command, compiler_report()))


def _launch_paper_rows(section, rows) -> list[dict]:
    out = []
    for r in rows:
        if math.isnan(r.median_ms):
            continue
        d = r.diff
        out.append(asdict(PaperRow(section, r.scene, r.variant + (f"/pad{r.shared_pad}" if r.shared_pad else ""),
                                   r.backend, r.device, r.size, r.median_ms, r.mrays, r.fps, None, "", None,
                                   r.registers, r.occupancy, differs=sum(d.values()) if d else None, note=r.note,
                                   **_err(r.error))))
    return out


def section_fig4(ctx) -> SectionResult:
    from .launch import block_sweep, launch_markdown, plot_fig4
    scene = ctx.scene(ctx.scenes[0])
    rows = block_sweep(scene, ctx.backend, repeats=ctx.repeats, check=ctx.check, progress=ctx.progress)
    plot_fig4(rows, ctx.dir / "fig4.png")
    return SectionResult("fig4", _launch_paper_rows("fig4", rows), launch_markdown(rows, ctx.command) +
                         "\n![Fig. 4](fig4.png)\n", extra={"launch": [r.as_dict() for r in rows]})


def section_fig5(ctx) -> SectionResult:
    from .launch import launch_markdown, occupancy_sweep, plot_fig5, register_sweep
    scene = ctx.scene(ctx.scenes[0])
    rows = register_sweep(scene, ctx.backend, repeats=ctx.repeats, check=ctx.check, progress=ctx.progress)
    rows += occupancy_sweep(scene, ctx.backend, repeats=ctx.repeats, progress=ctx.progress)
    plot_fig5(rows, ctx.dir / "fig5.png")
    return SectionResult("fig5", _launch_paper_rows("fig5", rows), launch_markdown(rows, ctx.command) +
                         "\n![Fig. 5](fig5.png)\n", extra={"launch": [r.as_dict() for r in rows]})


SECTION_FUNCS = {"table2": section_table2, "table3": section_table3, "table4": section_table4,
                 "table5": section_table5, "memory": section_memory, "fig4": section_fig4, "fig5": section_fig5}


# ---- the run ---------------------------------------------------------------------------------

class PaperContext:
    def __init__(self, backend, out_dir: Path, scenes, size, repeats, check, command, progress):
        self.backend = backend
        self.dir = out_dir
        self.scenes = list(scenes)
        self.size = size
        self.repeats = repeats
        self.check = check
        self.command = command
        self.progress = progress
        self._scenes: dict = {}

    def scene(self, name: str):
        if name not in self._scenes:
            from ..scene import load_scene
            self._scenes[name] = load_scene(name, size=self.size)
        return self._scenes[name]


def device_dir(root: Path, backend) -> Path:
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", f"{backend.name}-{backend.device_name}").strip("_")
    return Path(root) / slug


# Why many parameters: the table's knobs, passed through from its `rtlab bench` command.
def run_paper(backend, out: Path, scenes=PAPER_SCENES, size: int = 1024, repeats: int = 10,
              sections=SECTIONS, check: bool = True, budget_s: float | None = None, force: bool = False,
              command: str = "rtlab bench paper", console=None) -> Path:
    """Run the sections on ``backend``; returns the device directory holding paper.md/.csv/.png."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
    d = device_dir(out, backend)
    d.mkdir(parents=True, exist_ok=True)
    results: dict[str, SectionResult] = {}
    t0 = time.perf_counter()
    with Progress(TextColumn("[bold]{task.fields[section]}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TimeElapsedColumn(), TextColumn("{task.description}"), console=console, transient=False) as bar:
        task = bar.add_task("", total=len(sections), section="paper")
        ctx = PaperContext(backend, d, scenes, size, repeats, check, command,
                           lambda msg: bar.update(task, description=msg))
        for name in sections:
            bar.update(task, section=name, description=SECTION_TITLES.get(name, name))
            saved = d / f"{name}.json"
            if saved.is_file() and not force:
                results[name] = SectionResult(**json.loads(saved.read_text()))
                results[name].status = results[name].status.split(" (from")[0] + " (from an earlier run)"
                bar.advance(task)
                continue
            if budget_s is not None and time.perf_counter() - t0 > budget_s:
                results[name] = SectionResult(name, status=f"skipped: time budget of {budget_s:.0f} s spent")
                bar.advance(task)
                continue
            s0 = time.perf_counter()
            try:
                result = SECTION_FUNCS[name](ctx)
            except ImportError as e:
                result = SectionResult(name, status=f"missing: its bench module is not there yet ({e})")
            except Exception as e:  # one section's failure must not lose the others
                tb = traceback.format_exc(limit=6)
                result = SectionResult(name, status=f"failed: {type(e).__name__}: {e}", markdown=f"```\n{tb}\n```\n")
            result.seconds = time.perf_counter() - s0
            results[name] = result
            if result.status == "done":
                saved.write_text(json.dumps(asdict(result), default=_json_default))
            # after every section, so a run stopped from outside still leaves its finished tables
            write_outputs(d, backend, results, command, size)
            if console is not None:
                console.print(f"{name}: {result.status} ({result.seconds:.0f} s)")
            bar.advance(task)
    write_outputs(d, backend, results, command, size)
    return d


def _json_default(o):
    if hasattr(o, "tolist"):
        return o.tolist()
    if isinstance(o, float) and not math.isfinite(o):
        return str(o)
    return str(o)


def all_rows(results: dict) -> list[PaperRow]:
    names = {f.name for f in fields(PaperRow)}
    return [PaperRow(**{k: v for k, v in r.items() if k in names}) for res in results.values() for r in res.rows]


SUMMARY_COLUMNS = ("section", "scene", "variant", "ms", "Mrays/s", "fps", "paper", "speed-up", "regs", "occ.",
                   "mism.", "ties", "max rel dt", "PSNR", "differs from base")


def summary_table(rows: list[PaperRow]) -> Table:
    """Every timed variant of the run, one row each."""
    return Table(SUMMARY_COLUMNS, [
        (r.section, r.scene, r.variant, fmt(r.median_ms, ".3f"), fmt(r.mrays, ",.1f"), fmt(r.fps, ",.1f"),
         f"{r.paper} {r.paper_unit}" if r.paper else "-", fmt(r.speedup, ",.1f") + ("×" if r.speedup else ""),
         fmt(r.registers, "d"), fmt(r.occupancy, ".0%"), fmt(r.mismatches, "d"), fmt(r.ties, "d"),
         fmt(r.t_rel_err_max, ".1e"), fmt(r.psnr, ".1f"), fmt(r.differs, "d")) for r in rows])


def _with_saved(d: Path, results: dict) -> dict:
    """``results`` plus every section an earlier run left in ``d``, in the paper's order."""
    out = {}
    for name in SECTIONS:
        if name in results:
            out[name] = results[name]
        elif (d / f"{name}.json").is_file():
            saved = SectionResult(**json.loads((d / f"{name}.json").read_text()))
            saved.status = saved.status.split(" (from")[0] + " (from an earlier run)"
            out[name] = saved
    return out


def write_outputs(d: Path, backend, results: dict, command: str, size: int) -> None:
    results = _with_saved(d, results)
    rows = all_rows(results)
    with open(d / "paper.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=[fl.name for fl in fields(PaperRow)])
        w.writeheader()
        for r in rows:
            w.writerow(asdict(r))
    plot_error_vs_time(rows, d / "error_vs_time.png")
    md = [f"# The paper's evaluation on {backend.device_name} ({backend.name})", "",
          f"Command: `{command}`  ", f"Date: {datetime.date.today().isoformat()}; host: {platform.node()}; "
          f"backend: {backend.describe()}; image {size}x{size}", "",
          "The paper's figures are a GeForce 8800 GTS (CUDA 1.1) at 1024²; the speed-up is ours over theirs in the "
          "same unit. Errors are against the float64 reference (rtlab.reference): triangle-id mismatches, ties "
          "(rays float32 cannot decide), largest relative |Δt|, PSNR of the image; 'differs from base' counts "
          "hits/pixels that changed against the section's base variant (0 for placements and launch shapes).", "",
          Table(("section", "status", "seconds"), [(SECTION_TITLES.get(name, name), res.status, f"{res.seconds:.0f}")
                                                   for name, res in results.items()]).markdown(),
          "## Every timed variant", "", summary_table(rows).markdown(), "![error against run time](error_vs_time.png)", ""]
    for name, res in results.items():
        md += [f"## {SECTION_TITLES.get(name, name)}", "", f"Status: {res.status}", ""]
        if res.markdown:
            md += [res.markdown, ""]
    (d / "paper.md").write_text("\n".join(md) + "\n")


def plot_error_vs_time(rows: list[PaperRow], path: Path) -> None:
    """Each variant a point: run time against its error (mismatch rate; largest relative |Δt|)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    pts = [r for r in rows if r.median_ms and math.isfinite(r.median_ms)
           and (r.mismatches is not None or isinstance(r.t_rel_err_max, float))]
    if not pts:
        return
    fig, (a, b) = plt.subplots(1, 2, figsize=(13, 5))
    sections = sorted({r.section for r in pts})
    cmap = plt.get_cmap("tab10")
    for i, s in enumerate(sections):
        mine = [r for r in pts if r.section == s]
        hits = [(r.median_ms, r.mismatches) for r in mine if r.mismatches is not None]
        if hits:
            a.scatter(*zip(*hits), color=cmap(i % 10), label=s, s=18)
        dt = [(r.median_ms, r.t_rel_err_max) for r in mine if isinstance(r.t_rel_err_max, float)
              and math.isfinite(r.t_rel_err_max) and r.t_rel_err_max > 0]
        if dt:
            b.scatter(*zip(*dt), color=cmap(i % 10), label=s, s=18)
    for ax in (a, b):
        ax.set_xscale("log")
        ax.set_xlabel("median device time per frame (ms)")
        ax.grid(alpha=0.3, which="both")
    a.set_yscale("symlog", linthresh=1)
    b.set_yscale("log")
    a.set_ylabel("triangle-id mismatches vs float64 (ties apart)")
    b.set_ylabel("largest relative |Δt| vs float64")
    a.set_title("error against run time: hits")
    b.set_title("error against run time: distance")
    a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
