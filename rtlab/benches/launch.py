"""Launch shape and occupancy (the paper's §4.1, Figs. 4 and 5) and ray order, on the current device.

- :func:`block_sweep` (Fig. 4): the render kernel at each block shape, x by y threads as the paper
  writes them (2x32 is 2 wide and 32 tall: a warp then covers 2x16 pixels), in pixel (row) order
  and, where both sides are powers of two, in Morton order within the block (each warp an 8x4 tile).
  The paper found 2x32 and 4x32 best and 14x32, 22x20 good (GeForce 8800 GTS).
- :func:`register_sweep` (Fig. 5, first axis): each traversal under register caps (``-maxrregcount``
  for CUDA, ``-cl-nv-maxrregcount`` for NVIDIA's OpenCL; PoCL has none). The paper added redundant
  variables to raise registers and lower occupancy; a cap lowers registers and raises occupancy,
  paying in spills - the same curve walked from the other side.
- :func:`occupancy_sweep` (Fig. 5, second axis; CUDA only): registers left alone, occupancy held
  down by dynamic shared memory a block doesn't use, so occupancy is the only thing that changes.

Every row carries the error column: hits and pixels that differ from the default launch (must be
0; the default launch's own error against the float64 reference is in the base row).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from ..backends.occupancy import cuda_occupancy
from ..device.kernels import Variant, build_options, load_program, primary_step
from ..device.layout import HIT_DTYPE
from ..scene.model import Scene
from .paper_figures import PAPER_FIG4_BEST, PAPER_FIG4_GOOD
from .primary import nvcc_render_report
from .tables import Table, fmt, report_markdown

FIG4_BLOCKS = ((1, 32), (2, 32), (4, 32), (8, 32), (16, 32), (32, 32), (8, 8), (16, 16), (14, 32), (22, 20),
               (32, 1), (32, 2), (32, 4), (32, 8), (64, 2), (128, 1))
FIG5_TRAVERSALS = ("stack", "restart", "shortstack", "ropes")
FIG5_CAPS = (0, 64, 48, 40, 32, 24)            # 0: no cap; ptxas goes no lower than 24 on sm_90
OCCUPANCY_BLOCKS = (16, 12, 8, 6, 4, 3, 2, 1)  # resident blocks a multiprocessor (128-thread blocks)


@dataclass
class LaunchRow:
    kind: str                  # "block", "regcap" or "occupancy"
    scene: str
    backend: str
    device: str
    size: int
    variant: str
    block: tuple
    ray_order: str
    traversal: str
    cap: int                   # register cap, 0 for none
    shared_pad: int            # dynamic shared bytes a block (occupancy sweep)
    median_ms: float
    mrays: float
    fps: float
    registers: int | None
    occupancy: float | None
    spill_bytes: int | None
    resources_from: str        # "device", "nvcc sm_90" or "-"
    diff: dict = field(default_factory=dict)     # vs the default launch of the same traversal
    error: dict = field(default_factory=dict)    # float64 reference (base rows)
    note: str = ""

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class _Timed:
    times: list
    pixels: np.ndarray
    hits: np.ndarray | None
    resources: dict


def time_render(scene: Scene, backend, variant: Variant, repeats: int = 10, warmup: int = 2,
                shared_bytes: int = 0, write_hits: bool = True) -> _Timed:
    """Device times of the render kernel (after ``warmup`` launches) and one launch's pixels and
    hit records; ``shared_bytes`` of dynamic shared memory a block (CUDA)."""
    from ..device.device_scene import device_scene
    ds = device_scene(scene, backend)
    program = load_program(backend, primary_step(variant), variant, ds.features(variant),
                           RT_WRITE_HITS=int(write_hits))
    ds.set_constants(program, scene.camera, variant)
    n = scene.camera.width * scene.camera.height
    pixels = backend.empty(4 * n)
    hits = backend.empty(n * HIT_DTYPE.itemsize if write_hits else 4)
    args = ds.scene_args(variant) + [pixels, hits]
    kw = {"shared_bytes": shared_bytes} if shared_bytes else {}
    launch = lambda: program.launch("render_primary", (scene.camera.width, scene.camera.height), variant.block,
                                    args, constants=("frame", "lights", "materials"), **kw)
    for _ in range(warmup):
        launch()
    times = [launch() for _ in range(max(1, repeats))]
    rgba = backend.to_host(pixels, np.uint32, n)
    h = backend.to_host(hits, np.float32, 4 * n).view(HIT_DTYPE).reshape(-1) if write_hits else None
    return _Timed(times, rgba, h, program.resources("render_primary", variant.block).as_dict())


def _diff(t: _Timed, base: _Timed) -> dict:
    return {"tri": int(np.count_nonzero(t.hits["tri"] != base.hits["tri"])),
            "t_bits": int(np.count_nonzero(t.hits["t"].view(np.int32) != base.hits["t"].view(np.int32))),
            "pixels": int(np.count_nonzero(t.pixels != base.pixels))}


# Why many parameters: the table's knobs, passed through from its `rtlab bench` command.
def _row(kind, scene, backend, variant, timed, base, features, shared_pad=0, note="", base_error=None) -> LaunchRow:
    """A row with the device's resources where it reports registers (CUDA, NVIDIA OpenCL), else
    nvcc's offline sm_90 figures for a GPU backend; none for a CPU device (no occupancy there)."""
    ms = float(np.median(timed.times))
    n = scene.camera.width * scene.camera.height
    res = timed.resources
    regs, occ, spills, source = res.get("registers"), res.get("occupancy"), res.get("spill_bytes"), "device"
    threads = variant.block[0] * variant.block[1]
    if regs and backend.name == "cuda" and shared_pad:
        occ = cuda_occupancy(regs, threads, (res.get("shared_bytes") or 0) + shared_pad, backend.limits)
    if not regs:
        nv = nvcc_render_report(variant, features, shared_pad) if backend.is_gpu() else None
        if nv:
            regs, occ, spills, source = nv["registers"], nv["occupancy"], nv["spill_bytes"], "nvcc sm_90"
        else:
            source = "-"
    diff = _diff(timed, base) if base is not None else {}
    row = LaunchRow(kind, scene.name, backend.name, backend.device_name, scene.camera.width, variant.label(),
                    tuple(variant.block), variant.ray_order, variant.traversal, variant.max_registers, shared_pad,
                    ms, n / (ms * 1e-3) / 1e6, 1e3 / ms, regs, occ, spills, source, diff, note=note)
    if base_error and diff and not diff["tri"] and not diff["t_bits"]:
        row.error = dict(base_error)   # the same hits as the base launch: its error against the reference
    return row


def _base(scene, backend, variant, repeats, check):
    """The default launch of ``variant``'s traversal: its timing, hits, and error vs the reference."""
    timed = time_render(scene, backend, variant, repeats)
    error = {}
    if check:
        from ..reference.check import check_render
        from ..device.rendering import render
        error = check_render(scene, render(scene, backend, variant, write_hits=True, lab=True), scene.camera).as_dict()
    return timed, error


def _fits(backend, variant) -> str:
    """Why the block cannot launch on this device, or ''."""
    threads = variant.block[0] * variant.block[1]
    limit = None
    if backend.name == "opencl":
        limit = backend.device.max_work_group_size
    elif backend.name == "cuda":
        limit = 1024
    return f"{threads} threads exceed the device's {limit}" if limit and threads > limit else ""


def block_sweep(scene: Scene, backend, blocks=FIG4_BLOCKS, orders=("rows", "morton"), repeats: int = 10,
                check: bool = True, base: Variant | None = None, progress=None) -> list[LaunchRow]:
    """Fig. 4 and ray order: every block shape (and order), the same rays, the same hits."""
    from ..device.device_scene import device_scene
    base = base or Variant.paper()
    features = device_scene(scene, backend).features(base)
    base_timed, error = _base(scene, backend, base, repeats, check)
    rows = []
    for block in blocks:
        for order in orders:
            if order == "morton" and any(b & (b - 1) for b in block):
                continue
            variant = base.with_(block=tuple(block), ray_order=order)
            if progress is not None:
                progress(f"Fig. 4: {scene.name} {block[0]}x{block[1]} {order} on {backend.name}")
            why = _fits(backend, variant)
            if why:
                continue
            try:
                timed = time_render(scene, backend, variant, repeats)
            except Exception as e:  # e.g. too many resources for this block on this device
                rows.append(LaunchRow("block", scene.name, backend.name, backend.device_name, scene.camera.width,
                                      variant.label(), tuple(block), order, variant.traversal, 0, 0, math.nan,
                                      math.nan, math.nan, None, None, None, "-", note=f"failed: {e}"))
                continue
            rows.append(_row("block", scene, backend, variant, timed, base_timed, features, base_error=error))
    return rows


def register_sweep(scene: Scene, backend, traversals=FIG5_TRAVERSALS, caps=FIG5_CAPS, repeats: int = 10,
                   check: bool = True, base: Variant | None = None, progress=None) -> list[LaunchRow]:
    """Fig. 5 by register caps: each traversal at each cap (one point a traversal on PoCL)."""
    from ..device.device_scene import device_scene
    base = base or Variant.paper()
    rows = []
    for name in traversals:
        uncapped = base.with_(traversal=name, max_registers=0)
        try:
            features = device_scene(scene, backend).features(uncapped)
            base_timed, error = _base(scene, backend, uncapped, repeats, check)
        except Exception as e:
            rows.append(LaunchRow("regcap", scene.name, backend.name, backend.device_name, scene.camera.width,
                                  uncapped.label(), tuple(base.block), base.ray_order, name, 0, 0, math.nan, math.nan,
                                  math.nan, None, None, None, "-", note=f"failed: {e}"))
            continue
        for cap in caps:
            variant = uncapped.with_(max_registers=cap)
            if cap and not build_options(variant, backend):
                continue  # no register file to cap (PoCL)
            if progress is not None:
                progress(f"Fig. 5: {scene.name} {name} cap {cap or 'none'} on {backend.name}")
            timed = base_timed if not cap else time_render(scene, backend, variant, repeats)
            rows.append(_row("regcap", scene, backend, variant, timed, base_timed, features, base_error=error))
    return rows


def occupancy_sweep(scene: Scene, backend, traversals=("stack",), blocks_per_sm=OCCUPANCY_BLOCKS,
                    repeats: int = 10, base: Variant | None = None, progress=None) -> list[LaunchRow]:
    """Fig. 5 by occupancy alone (CUDA): dynamic shared memory a block leaves fewer blocks resident;
    the kernel, its registers and its rays stay the same."""
    if backend.name != "cuda":
        return []
    from ..device.device_scene import device_scene
    base = base or Variant.paper()
    limits = backend.limits
    rows = []
    for name in traversals:
        variant = base.with_(traversal=name)
        features = device_scene(scene, backend).features(variant)
        base_timed = time_render(scene, backend, variant, repeats)
        static = base_timed.resources.get("shared_bytes") or 0
        regs = base_timed.resources.get("registers") or 0
        threads = variant.block[0] * variant.block[1]
        seen = {cuda_occupancy(regs, threads, static, limits)}
        for k in blocks_per_sm:
            # a block's share of the multiprocessor's shared memory when k blocks fit, in allocation
            # units, less the per-block reservation and what the kernel declares itself
            share = limits.shared_bytes // k // limits.shared_alloc_unit * limits.shared_alloc_unit
            pad = share - limits.shared_reserved_per_block - static
            occupancy = cuda_occupancy(regs, threads, static + pad, limits)
            if pad <= 0 or occupancy in seen:
                continue  # registers already hold occupancy at or below this
            seen.add(occupancy)
            if progress is not None:
                progress(f"Fig. 5: {scene.name} {name} {k} blocks/SM on {backend.name}")
            try:
                timed = time_render(scene, backend, variant, repeats, shared_bytes=pad)
            except Exception as e:
                rows.append(LaunchRow("occupancy", scene.name, backend.name, backend.device_name, scene.camera.width,
                                      variant.label(), tuple(variant.block), variant.ray_order, name, 0, pad, math.nan,
                                      math.nan, math.nan, None, None, None, "-", note=f"failed: {e}"))
                continue
            rows.append(_row("occupancy", scene, backend, variant, timed, base_timed, features, shared_pad=pad,
                             note=f"{k} blocks/SM requested"))
    return rows


def diff_text(r: LaunchRow) -> str:
    d = r.diff
    if not d:
        return "-"
    return "0" if not any(d.values()) else f"{d['tri']} ids, {d['t_bits']} t, {d['pixels']} px"


def _error_text(e: dict) -> str:
    if not e:
        return "-"
    return f"{e['mismatches']} mism., {e['ties']} ties, max rel dt {e['t_rel_err_max']:.1e}"


FIG4_COLUMNS = ("scene", "backend", "block", "threads", "order", "median ms", "Mrays/s", "vs 32x4 rows", "regs",
                "occupancy", "resources from", "differs", "error vs float64", "note")
FIG5_COLUMNS = ("scene", "backend", "traversal", "cap", "shared pad B", "median ms", "fps", "Mrays/s", "regs",
                "spills B", "occupancy", "resources from", "differs", "error vs float64", "note")


def fig4_rows(rows: list[LaunchRow]) -> list[tuple[str, ...]]:
    blocks = [r for r in rows if r.kind == "block"]
    ref = {(r.scene, r.backend): r.median_ms for r in blocks if r.block == (32, 4) and r.ray_order == "rows"}
    out = []
    for r in blocks:
        g = ref.get((r.scene, r.backend))
        mark = " (paper best)" if r.block in PAPER_FIG4_BEST else (" (paper good)" if r.block in PAPER_FIG4_GOOD else "")
        out.append((r.scene, r.backend, f"{r.block[0]}x{r.block[1]}{mark}", str(r.block[0] * r.block[1]), r.ray_order,
                    fmt(r.median_ms, ".3f"), fmt(r.mrays, ",.1f"), fmt(g / r.median_ms if g else None, ".2f"),
                    fmt(r.registers, "d"), fmt(r.occupancy, ".0%"), r.resources_from, diff_text(r),
                    _error_text(r.error), r.note))
    return out


def fig5_rows(rows: list[LaunchRow]) -> list[tuple[str, ...]]:
    return [(r.scene, r.backend, r.traversal, str(r.cap or "none"), str(r.shared_pad), fmt(r.median_ms, ".3f"),
             fmt(r.fps, ",.1f"), fmt(r.mrays, ",.1f"), fmt(r.registers, "d"), fmt(r.spill_bytes, "d"),
             fmt(r.occupancy, ".0%"), r.resources_from, diff_text(r), _error_text(r.error), r.note)
            for r in rows if r.kind in ("regcap", "occupancy")]


def launch_tables(rows: list[LaunchRow]) -> list[Table]:
    """Fig. 4 (block shapes and ray order) and Fig. 5 (register caps, occupancy), those with rows."""
    tables = [Table(FIG4_COLUMNS, fig4_rows(rows), note="Fig. 4: block shapes, x by y threads (the paper: 2x32 and "
                    "4x32 best, 14x32 and 22x20 good). Error column: hits/pixels differing from the default launch "
                    "(must be 0)."),
              Table(FIG5_COLUMNS, fig5_rows(rows), note="Fig. 5: each traversal under register caps, and (CUDA) with "
                    "occupancy held down by unused dynamic shared memory. Error column: hits/pixels differing from "
                    "the same traversal uncapped.")]
    return [t for t in tables if t.rows]


INTRO = ("Times are of render_primary with its hit records written (16 bytes a pixel more than Table 4's launches), "
         "so every row can be compared hit for hit with the default launch.")


def launch_markdown(rows: list[LaunchRow], command: str) -> str:
    return report_markdown("Launch shape and occupancy (§4.1, Figs. 4 and 5) and ray order", command,
                           [f"{r.backend}: {r.device}" for r in rows], launch_tables(rows), INTRO)


def plot_fig4(rows: list[LaunchRow], path) -> None:
    """Bars of Mrays/s per block shape (rows order; Morton beside it), occupancy above each bar."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    blocks = [r for r in rows if r.kind == "block" and not math.isnan(r.mrays)]
    groups = sorted({(r.scene, r.backend) for r in blocks})
    if not groups:
        return
    fig, axes = plt.subplots(len(groups), 1, figsize=(12, 3.6 * len(groups)), squeeze=False)
    for ax, (scene, be) in zip(axes[:, 0], groups):
        mine = [r for r in blocks if (r.scene, r.backend) == (scene, be)]
        shapes = list(dict.fromkeys(r.block for r in mine))
        x = np.arange(len(shapes))
        for k, (order, color) in enumerate((("rows", "tab:blue"), ("morton", "tab:orange"))):
            vals = [next((r.mrays for r in mine if r.block == s and r.ray_order == order), np.nan) for s in shapes]
            ax.bar(x + (k - 0.5) * 0.4, vals, 0.4, label=f"{order} order", color=color)
            for xi, s in zip(x, shapes):
                r = next((r for r in mine if r.block == s and r.ray_order == order), None)
                if r is not None and r.occupancy is not None and order == "rows":
                    ax.text(xi - 0.2, r.mrays, f"{r.occupancy:.0%}", ha="center", va="bottom", fontsize=7)
        labels = [f"{s[0]}x{s[1]}" + ("*" if s in PAPER_FIG4_BEST else ("+" if s in PAPER_FIG4_GOOD else ""))
                  for s in shapes]
        ax.set_xticks(x, labels, rotation=45)
        ax.set_ylabel("Mrays/s")
        ax.set_title(f"Fig. 4: block shape, {scene}, {be} (* paper's best, + paper's good; % = occupancy)")
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_fig5(rows: list[LaunchRow], path) -> None:
    """fps against registers (register caps) and against occupancy (caps and shared padding)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    pts = [r for r in rows if r.kind in ("regcap", "occupancy") and not math.isnan(r.fps)]
    if not pts:
        return
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.5))
    for (scene, be, trav) in sorted({(r.scene, r.backend, r.traversal) for r in pts}):
        caps = sorted([r for r in pts if r.kind == "regcap" and (r.scene, r.backend, r.traversal) == (scene, be, trav)
                       and r.registers], key=lambda r: r.registers)
        if caps:
            a.plot([r.registers for r in caps], [r.fps for r in caps], "o-", label=f"{trav} ({scene}, {be})")
        occ = sorted([r for r in pts if (r.scene, r.backend, r.traversal) == (scene, be, trav)
                      and r.occupancy is not None], key=lambda r: r.occupancy)
        if occ:
            b.plot([100 * r.occupancy for r in occ], [r.fps for r in occ], "o-", label=f"{trav} ({scene}, {be})")
    a.set_xlabel("registers per thread (after -maxrregcount)")
    a.set_ylabel("frames per second")
    a.set_title("Fig. 5: performance against register usage")
    b.set_xlabel("occupancy (%)")
    b.set_ylabel("frames per second")
    b.set_title("... against occupancy (caps and shared-memory padding)")
    for ax in (a, b):
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
