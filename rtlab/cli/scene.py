"""Commands about the machine, the variants and the scenes: rtlab info, variants, scenes, build, inspect."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Optional, Tuple

import typer
from rich.markup import escape
from rich.table import Table

from .common import block_shape, console, kd_tree, load_scene


def info():
    """Backends, platforms and devices; why a backend is unavailable."""
    from ..backends import backend_status
    from ..device.kernels import lab_steps
    table = Table(title="rtlab backends")
    for col in ("backend", "id", "platform", "device", "status"):
        table.add_column(col)
    for row in backend_status():
        table.add_row(row["backend"], row["id"], escape(row["platform"]), escape(row["device"]),
                      "[green]ok[/]" if row["ok"] else f"[yellow]{escape(row['why'])}[/]")
    console.print(table)
    console.print(f"lab steps with kernels: {', '.join(lab_steps())}")
    from ..course import sandbox
    why = sandbox.seccomp_available()
    console.print("grader sandbox: " + escape(sandbox.describe(None if why else sandbox.sandbox_user())
                                               if not why else f"unavailable: {why}"))


def variants():
    """The variant registry: each traversal's code, source, function and what it reads; the programs;
    the defaults (the library's on a GPU, for frames and for trace()'s rays, and on a CPU; the paper's)."""
    from ..device.variants import (CPU_DEFAULT_VARIANT, GPU_DEFAULT_VARIANT, GPU_RAYS_VARIANT, INTERSECTIONS,
                                   ISECT_FUNCTIONS, LAB_PROGRAMS, LIBRARY_PROGRAMS, PAPER_VARIANT, registry_rows)
    rows = registry_rows()
    table = Table(title="traversals (--traversal; rtlab/device/variants.py)")
    for col in rows[0]:
        table.add_column(col)
    for r in rows:
        table.add_row(*(escape(str(v)) for v in r.values()))
    console.print(table)
    console.print("triangle tests (--isect; kernels/shared/rt_intersect.h): " + ", ".join(
        f"{name} (RT_ISECT {code}, {ISECT_FUNCTIONS[name]})" for name, code in INTERSECTIONS.items()))
    console.print("programs (kernels/cuda/NAME.cu, kernels/opencl/NAME.cl): " + ", ".join(
        f"{purpose}: library {LIBRARY_PROGRAMS.get(purpose, '-')}, lab {LAB_PROGRAMS[purpose]}"
        for purpose in LAB_PROGRAMS))
    for what, v in (("GPU default", GPU_DEFAULT_VARIANT), ("GPU default for trace()'s rays", GPU_RAYS_VARIANT),
                    ("CPU default", CPU_DEFAULT_VARIANT),
                    ("the paper's (labs, paper benches)", PAPER_VARIANT)):
        console.print(f"{what}: {v.label()}")


def scenes():
    """Scene presets: where each file was found and whether its sha256 matches."""
    from ..scene import list_scenes
    table = Table(title="rtlab scenes")
    for col in ("scene", "triangles (paper)", "file", "found at", "sha256"):
        table.add_column(col)
    rows = list_scenes()
    for r in rows:
        table.add_row(r["name"], f"{r.get('paper_triangles') or '-'}", r.get("file") or "procedural",
                      str(r.get("path") or "[red]missing[/]"), str(r.get("sha256", "-")))
    console.print(table)
    searched = rows[0].get("searched") if rows else None
    if searched:
        console.print("searched: " + ", ".join(str(s) for s in searched))


def build(scene: str = typer.Argument("default", help="preset name, 'default' or a mesh file")):
    """Build (or load from the cache) the SAH kd-tree and print the paper's Table 2 row."""
    from ..benches.build import table2_cells
    sc = load_scene(scene)
    t0 = time.perf_counter()
    tree, cached = kd_tree(sc)
    seconds = time.perf_counter() - t0
    table = Table(title=f"kd-tree for {sc.name} (the paper's Table 2 columns)")
    table.add_column("column")
    table.add_column("rtlab", justify="right")
    table.add_column("paper", justify="right")
    for column, ours, theirs in table2_cells(sc.name, tree, sc.n_triangles):
        table.add_row(column, ours, theirs)
    table.add_row("this load", f"from cache, {seconds:.2f} s" if cached else f"built, {seconds:.2f} s", "-")
    console.print(table)


def inspect(scene: str = typer.Argument("default", help="preset name, 'default' or a mesh file"),
            depth: int = typer.Option(6, min=0, help="kd-tree cells down to this depth"),
            pixel: Optional[Tuple[int, int]] = typer.Option(None, help="X Y: show this pixel's ray tree"),
            size: int = typer.Option(128, min=1, help="image size the pixel refers to (width = height)"),
            screenshot: Optional[Path] = typer.Option(None, help="write a PNG instead of opening a window"),
            backend: Optional[str] = typer.Option(None, help="backend that traces the pixel's rays"),
            window: str = typer.Option("1024x768", help="window / screenshot size WxH")):
    """Show the scene in pyvista: mesh, kd-tree cells, camera frustum, a pixel's rays and visited leaves."""
    from ..viz import inspect_scene
    view = inspect_scene(scene, depth=depth, pixel=pixel, size=size, screenshot=screenshot, backend=backend,
                         window_size=block_shape(window, "--window", "1024x768"))
    for line in view.summary():
        console.print(escape(line))
    if screenshot:
        console.print(f"wrote {screenshot}")


def register(app: typer.Typer) -> None:
    app.command()(info)
    app.command()(variants)
    app.command()(scenes)
    app.command()(build)
    app.command("inspect")(inspect)
