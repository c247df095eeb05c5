"""The `rtlab` command line: info, scenes, build, render (bench, grade, inspect join as labs land).

Errors the user can act on (RtlabError) print one line and exit with status 2, never a traceback.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from .errors import RtlabError

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="rtlab: GPU ray tracing lab (Shih et al. 2009) on CUDA and OpenCL.")
console = Console()
err_console = Console(stderr=True)


def _load_scene(name: str, size: Optional[int] = None):
    from .scene import load_scene
    with console.status(f"loading scene {name}..."):
        return load_scene(name, size=size)


def _tree(scene):
    from .accel.cache import load_or_build_kdtree
    from .accel.kdtree import KdBuildParams
    with console.status(f"kd-tree for {scene.name} ({scene.n_triangles:,} triangles)..."):
        return load_or_build_kdtree(scene.vertices, scene.faces, KdBuildParams())


@app.command()
def info():
    """Backends, platforms and devices; why a backend is unavailable."""
    from .backends import backend_status
    table = Table(title="rtlab backends")
    for col in ("backend", "id", "platform", "device", "status"):
        table.add_column(col)
    for row in backend_status():
        table.add_row(row["backend"], row["id"], escape(row["platform"]), escape(row["device"]),
                      "[green]ok[/]" if row["ok"] else f"[yellow]{escape(row['why'])}[/]")
    console.print(table)
    from .kernels import lab_steps
    console.print(f"lab steps with kernels: {', '.join(lab_steps())}")


@app.command()
def scenes():
    """Scene presets: where each file was found and whether its sha256 matches."""
    from .scene import list_scenes
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


@app.command()
def build(scene: str = typer.Argument("default", help="preset name, 'default' or a mesh file")):
    """Build (or load from the cache) the SAH kd-tree and print the paper's Table 2 row."""
    from .accel.kdtree import kd_stats
    sc = _load_scene(scene)
    t0 = time.perf_counter()
    tree, cached = _tree(sc)
    seconds = time.perf_counter() - t0
    s = kd_stats(tree, sc.n_triangles)
    table = Table(title=f"kd-tree (Table 2) for {sc.name}")
    for col in ("#triangles", "#nodes", "#neleaves", "#links", "size", "depth", "SAH cost", "build s", "source"):
        table.add_column(col, justify="right")
    table.add_row(f"{s['triangles']:,}", f"{s['nodes']:,}", f"{s['nonempty_leaves']:,}",
                  f"{s['refs_per_nonempty_leaf']:.2f}", f"{s['size_bytes'] / 2**20:.1f} MB", str(s["depth"]),
                  f"{s['sah_cost']:.2f}", f"{tree.build_seconds:.2f}",
                  f"cache ({seconds:.2f} s)" if cached else "built")
    console.print(table)


@app.command()
def render(scene: str = typer.Argument("default", help="preset name, 'default' or a mesh file"),
           backend: Optional[str] = typer.Option(None, help="opencl, cuda or auto ($RTLAB_BACKEND)"),
           device: Optional[str] = typer.Option(None, help="device name substring or index ($RTLAB_DEVICE)"),
           size: Optional[int] = typer.Option(None, help="image width = height (default: the preset's, 1024)"),
           out: Path = typer.Option(Path("render.png"), help="PNG to write"),
           check: bool = typer.Option(False, help="compare with the float64 reference and print the error"),
           repeats: int = typer.Option(5, help="timed launches (median reported)"),
           traversal: str = typer.Option("stack", help="kd-tree traversal variant"),
           isect: str = typer.Option("moller", help="triangle intersection test"),
           block: str = typer.Option("32x4", help="block / work-group shape WxH")):
    """Render a scene (primary rays, simple shading), print time and Mrays/s, write a PNG."""
    from .kernels import Variant
    from .rendering import render as do_render, save_png
    try:
        bx, by = (int(v) for v in block.lower().split("x"))
    except ValueError:
        raise RtlabError(f"--block must look like 32x4, got '{block}'") from None
    variant = Variant(traversal=traversal, intersection=isect, block=(bx, by))
    from .backends import get_backend
    be = get_backend(backend, device)
    sc = _load_scene(scene, size)
    _tree(sc)
    with console.status(f"rendering {sc.name} {sc.camera.width}x{sc.camera.height}..."):
        result = do_render(sc, be, variant, repeats=repeats, warmup=1, write_hits=check)
    save_png(result.image, out)
    res = result.resources
    regs = f", {res['registers']} registers" if res.get("registers") else ""
    occ = f", occupancy {res['occupancy']:.0%}" if res.get("occupancy") else ""
    console.print(f"{sc.name} {sc.camera.width}x{sc.camera.height} on {result.backend} ({result.device}), "
                  f"{variant.label()}: {result.median_ms:.2f} ms (median of {len(result.kernel_ms)}), "
                  f"{result.mrays_per_s:.1f} Mrays/s{regs}{occ}; host {result.host_ms:.2f} ms per launch")
    if check:
        from .check import check_render
        with console.status("float64 reference..."):
            report = check_render(sc, result, sc.camera)
        console.print(f"error vs float64 reference: {report.summary()}")
    console.print(f"wrote {out}")


bench_app = typer.Typer(no_args_is_help=True, help="Benchmarks: the paper's tables on the current device.")
app.add_typer(bench_app, name="bench")


def _bench_scenes(scenes: str, views: str, size: int):
    """(scene, view label) pairs: preset cameras, or the benchmark views of ../shared/bench."""
    from .scene import bench_camera, load_scene
    out = []
    for name in [s for s in scenes.split(",") if s]:
        scene = _load_scene(name, size)
        if views == "preset":
            out.append((scene, "preset"))
            continue
        for view in views.split(","):
            vs = load_scene(name, size=size)
            vs.camera = bench_camera(f"{name}/{view}", size)
            out.append((vs, view))
    return out


@bench_app.command("primary")
def bench_primary(scenes: str = typer.Option("bunny,sponza,kitchen,dragon", help="comma-separated presets"),
                  backends: str = typer.Option("auto", help="comma-separated: opencl, cuda, auto"),
                  device: Optional[str] = typer.Option(None, help="device name substring (OpenCL)"),
                  size: int = typer.Option(1024, help="image width = height"),
                  views: str = typer.Option("preset", help="'preset' or bench views, e.g. far,fill,inside"),
                  repeats: int = typer.Option(25, help="timed launches; the median is reported"),
                  check: bool = typer.Option(True, help="error against the float64 reference"),
                  traversal: str = typer.Option("stack"), isect: str = typer.Option("moller"),
                  block: str = typer.Option("32x4"),
                  md: Optional[Path] = typer.Option(None, help="append the table as markdown to this file")):
    """Primary rays with simple shading (the paper's Table 4 setting): time, Mrays/s, error."""
    from .backends import get_backend
    from .bench import PAPER_STACK_FPS, bench_render, rows_markdown
    from .kernels import Variant
    bx, by = (int(v) for v in block.lower().split("x"))
    variant = Variant(traversal=traversal, intersection=isect, block=(bx, by))
    bes = [get_backend(b, device if b == "opencl" else None) for b in backends.split(",")]
    rows = []
    for scene, view in _bench_scenes(scenes, views, size):
        _tree(scene)
        for be in bes:
            with console.status(f"{scene.name}/{view} on {be.name}..."):
                rows.append(bench_render(scene, be, variant, repeats=repeats, check=check, view=view))
            r = rows[-1]
            console.print(f"{r.scene}/{r.view} {r.backend}: {r.median_ms:.3f} ms, {r.mrays:,.0f} Mrays/s; {r.error_text()}")
    table = Table(title=f"primary rays, {size}x{size}, {variant.label()}")
    for col in ("scene", "view", "backend", "device", "median ms", "Mrays/s", "fps", "paper fps", "regs", "occ.", "error"):
        table.add_column(col, justify="right")
    for r in rows:
        paper = PAPER_STACK_FPS.get(r.scene)
        table.add_row(r.scene, r.view, r.backend, r.device, f"{r.median_ms:.3f}", f"{r.mrays:,.0f}", f"{r.fps:,.0f}",
                      f"{paper}" if paper and size == 1024 else "-", str(r.registers or "-"),
                      f"{r.occupancy:.0%}" if r.occupancy is not None else "-", r.error_text())
    console.print(table)
    if md:
        cmd = "rtlab bench primary " + " ".join(sys.argv[3:]) if len(sys.argv) > 3 else "rtlab bench primary"
        with open(md, "a") as f:
            f.write(rows_markdown(rows, f"Primary rays, {size}x{size}", cmd) + "\n")


def main(argv: Optional[list[str]] = None) -> int:
    try:
        app(args=argv, standalone_mode=False)
    except RtlabError as e:
        err_console.print(f"[bold red]rtlab:[/] {escape(str(e))}", highlight=False)
        return 2
    except (typer.Abort, KeyboardInterrupt):
        err_console.print("rtlab: interrupted")
        return 130
    except Exception as e:  # click usage errors
        import click
        if isinstance(e, click.ClickException):
            e.show()
            return e.exit_code
        raise
    return 0


if __name__ == "__main__":
    sys.exit(main())
