"""The `rtlab` command line: info, scenes, build, render (bench, grade, inspect join as labs land).

Errors the user can act on (RtlabError, and typer's usage errors: an unknown option, a value out
of range) print one line on stderr and exit with status 2, never a traceback (``main``).
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from ..errors import RtlabError

# The paper's Table 2: #triangles, #nodes, #neleaves, #links, size
PAPER_TABLE2 = {"bunny": (69451, 379713, 120511, 2.72, "11MB"), "sponza": (66454, 292195, 124059, 2.63, "10MB"),
                "kitchen": (103343, 362585, 146253, 2.63, "14MB"), "dragon": (871414, 1687237, 607852, 2.59, "103MB")}

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="rtlab: GPU ray tracing lab (Shih et al. 2009) on CUDA and OpenCL.")
console = Console()
err_console = Console(stderr=True, soft_wrap=True)   # an error stays one line


def _load_scene(name: str, size: Optional[int] = None):
    from ..scene import load_scene
    with console.status(f"loading scene {name}..."):
        return load_scene(name, size=size)


def _tree(scene):
    from ..accel.cache import load_or_build_kdtree
    from ..accel.kdtree import COMPILING_MESSAGE, KdBuildParams
    with console.status(f"kd-tree for {scene.name} ({scene.n_triangles:,} triangles)...") as status:
        def progress(message: str):
            if message == COMPILING_MESSAGE:
                console.print(f"{message}...")     # the one noticeable wait of a fresh install: keep it
            status.update(message)
        return load_or_build_kdtree(scene.vertices, scene.faces, KdBuildParams(), progress=progress)


def _block_shape(text: str, option: str = "--block") -> tuple[int, int]:
    """'32x4' -> (32, 4); anything else is a one-line error naming the option."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() and int(p) > 0 for p in parts):
        raise RtlabError(f"{option} must look like 32x4 (two positive whole numbers), got '{text}'")
    return int(parts[0]), int(parts[1])


def _int_list(text: str, option: str) -> list[int]:
    """'1,2,3' -> [1, 2, 3]; anything else is a one-line error naming the option."""
    items = [t.strip() for t in text.split(",") if t.strip()]
    try:
        return [int(t) for t in items]
    except ValueError:
        raise RtlabError(f"{option} must be whole numbers separated by commas, got '{text}'") from None


@app.command()
def info():
    """Backends, platforms and devices; why a backend is unavailable."""
    from ..backends import backend_status
    table = Table(title="rtlab backends")
    for col in ("backend", "id", "platform", "device", "status"):
        table.add_column(col)
    for row in backend_status():
        table.add_row(row["backend"], row["id"], escape(row["platform"]), escape(row["device"]),
                      "[green]ok[/]" if row["ok"] else f"[yellow]{escape(row['why'])}[/]")
    console.print(table)
    from ..device.kernels import lab_steps
    console.print(f"lab steps with kernels: {', '.join(lab_steps())}")


@app.command()
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


@app.command()
def build(scene: str = typer.Argument("default", help="preset name, 'default' or a mesh file")):
    """Build (or load from the cache) the SAH kd-tree and print the paper's Table 2 row."""
    from ..accel.kdtree import kd_stats
    sc = _load_scene(scene)
    t0 = time.perf_counter()
    tree, cached = _tree(sc)
    seconds = time.perf_counter() - t0
    s = kd_stats(tree, sc.n_triangles)
    paper = PAPER_TABLE2.get(sc.name.lower())
    table = Table(title=f"kd-tree for {sc.name} (the paper's Table 2 columns)")
    table.add_column("column")
    table.add_column("rtlab", justify="right")
    table.add_column("paper", justify="right")
    ours = [f"{s['triangles']:,}", f"{s['nodes']:,}", f"{s['nonempty_leaves']:,}",
            f"{s['refs_per_nonempty_leaf']:.2f}", f"{s['size_bytes'] / 2**20:.1f} MB"]
    for i, (col, value) in enumerate(zip(("#triangles", "#nodes", "#neleaves", "#links", "size"), ours)):
        table.add_row(col, value, f"{paper[i]:,}" if paper and i < 3 else (f"{paper[i]}" if paper else "-"))
    table.add_row("depth", str(s["depth"]), "-")
    table.add_row("SAH cost", f"{s['sah_cost']:.2f}", "-")
    table.add_row("build time", f"{tree.build_seconds:.2f} s", "-")
    table.add_row("this load", f"from cache, {seconds:.2f} s" if cached else f"built, {seconds:.2f} s", "-")
    console.print(table)


@app.command()
def render(scene: str = typer.Argument("default", help="preset name, 'default' or a mesh file"),
           backend: Optional[str] = typer.Option(None, help="opencl, cuda or auto ($RTLAB_BACKEND)"),
           device: Optional[str] = typer.Option(None, help="device name substring or index ($RTLAB_DEVICE)"),
           size: Optional[int] = typer.Option(None, min=1, help="image width = height (default: the preset's, 1024)"),
           out: Path = typer.Option(Path("render.png"), help="PNG to write"),
           check: bool = typer.Option(False, help="compare with the float64 reference and print the error"),
           repeats: int = typer.Option(5, min=1, help="timed launches (median reported)"),
           traversal: Optional[str] = typer.Option(None, help="traversal (default: bvh on a GPU, stack on a CPU)"),
           isect: Optional[str] = typer.Option(None, help="triangle intersection test (default: watertight; the "
                                               "paper's: moller)"),
           block: Optional[str] = typer.Option(None, help="block / work-group shape WxH (default: 8x16 on a GPU, "
                                               "32x4 on a CPU)"),
           shadows: Optional[str] = typer.Option(None, help="Whitted shading: one-pass, two-pass or none"),
           bounces: Optional[int] = typer.Option(None, min=0, help="reflection/refraction bounces (kernel tree)"),
           materials: str = typer.Option("auto", help="with --shadows/--bounces: file, mtl, bart, paper, "
                                         "paper-refraction, auto (rtlab.scene.materials)"),
           fresnel: str = typer.Option("schlick", help="with --bounces: schlick or fixed"),
           compact: bool = typer.Option(False, help="with --bounces: compact live rays between levels"),
           schedule: str = typer.Option("tree", help="with --bounces: tree (the paper's depth-first kernel "
                                        "tree) or wavefront (one launch per level)"),
           kernels: Optional[Path] = typer.Option(None, "--kernels", help="kernel tree to compile (a copy of "
                                                  "kernels/ with your work; default $RTLAB_KERNEL_DIR or the "
                                                  "installation's)")):
    """Render a scene (primary rays, simple shading; with --shadows or --bounces Whitted ray tracing:
    shadows, reflection, refraction), print time and Mrays/s, write a PNG."""
    from ..device.rendering import render as do_render, save_png
    from ..device.tracing import default_variant
    out.parent.mkdir(parents=True, exist_ok=True)     # before the work: a bad --out fails at once
    from ..backends import get_backend
    be = get_backend(backend, device)
    chosen = {"traversal": traversal, "intersection": isect, "block": _block_shape(block) if block else None}
    variant = default_variant(be).with_(**{k: v for k, v in chosen.items() if v is not None})
    _use_kernels(kernels, variant, whitted=shadows is not None or bounces is not None)
    sc = _load_scene(scene, size)
    _tree(sc)
    if shadows is not None or bounces is not None:
        from ..device.whitted import render_whitted_command
        render_whitted_command(console, sc, be, variant, shadows or "one-pass", bounces or 0, materials, fresnel,
                               compact, repeats, check, out, schedule)
        return
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
        from ..reference.check import check_render
        with console.status("float64 reference..."):
            report = check_render(sc, result, sc.camera)
        console.print(f"error vs float64 reference: {report.summary()}")
    console.print(f"wrote {out}")


bench_app = typer.Typer(no_args_is_help=True, help="Benchmarks: the paper's tables on the current device.")
app.add_typer(bench_app, name="bench")


def _use_kernels(kernels: Optional[Path], variant=None, whitted: bool = False) -> None:
    """Switch to the kernel tree of --kernels (if given) and say which tree runs and what in it is
    still a template stub (rtlab render --traversal ropes --check must not pass off the reference)."""
    from ..device.kernels import use_kernel_dir
    from ..labs.trees import kernel_tree_summary
    if kernels is not None:
        use_kernel_dir(kernels)
    console.print(escape(kernel_tree_summary(None if whitted else variant)), highlight=False)


@bench_app.callback()
def bench_options(kernels: Optional[Path] = typer.Option(None, "--kernels", help="kernel tree to compile (default "
                                                         "$RTLAB_KERNEL_DIR or the installation's)")):
    """Benchmarks: the paper's tables on the current device (rtlab bench --kernels DIR SECTION ...)."""
    _use_kernels(kernels)


def _bench_scenes(scenes: str, views: str, size: int):
    """(scene, view label) pairs: preset cameras, or the benchmark views of ../shared/bench."""
    from ..scene import bench_camera, load_scene
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
                  size: int = typer.Option(1024, min=1, help="image width = height"),
                  views: str = typer.Option("preset", help="'preset' or bench views, e.g. far,fill,inside"),
                  repeats: int = typer.Option(25, min=1, help="timed launches; the median is reported"),
                  check: bool = typer.Option(True, help="error against the float64 reference"),
                  traversal: str = typer.Option("stack"), isect: str = typer.Option("moller"),
                  block: str = typer.Option("32x4"),
                  md: Optional[Path] = typer.Option(None, help="append the table as markdown to this file")):
    """Primary rays with simple shading (the paper's Table 4 setting): time, Mrays/s, error."""
    from ..backends import get_backend
    from ..benches.primary import PAPER_STACK_FPS, bench_render, rows_markdown
    from ..device.kernels import Variant
    variant = Variant(traversal=traversal, intersection=isect, block=_block_shape(block))
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


@bench_app.command("rays")
def bench_rays_cmd(kind: str = typer.Option("primary", help="ray kinds, comma-separated: primary, diffuse"),
                   views: str = typer.Option("bunny/far,bunny/fill,dragon/fill,sponza/inside,kitchen/inside,"
                                             "conference/inside", help="benchmark views (scene/view), comma-separated"),
                   backends: str = typer.Option("auto", help="comma-separated: opencl, cuda, auto"),
                   device: Optional[str] = typer.Option(None, help="device name substring (OpenCL)"),
                   sizes: str = typer.Option("1024", help="image sides, comma-separated"),
                   traversals: str = typer.Option("bvh,stack", help="traversals to time, comma-separated"),
                   isect: str = typer.Option("moller"),
                   block: str = typer.Option("8x16", help="block of the image-shaped launches (primary rays)"),
                   repeats: int = typer.Option(22, help="timed launches; the median is reported"),
                   render: bool = typer.Option(True, help="also time the render kernel on primary views"),
                   md: Optional[Path] = typer.Option(None, help="append the table as markdown to this file")):
    """Rays through the trace API on the peers' benchmark views (../shared/bench): kernel time, Mrays/s,
    the error against the float64 reference, the render kernel on the same camera, the best peer."""
    from ..backends import get_backend
    from ..benches.rays import COLUMNS, bench_rays, make_rays, rays_markdown, table_rows
    from ..device.kernels import Variant
    bes = [get_backend(b, device if b == "opencl" else None) for b in backends.split(",")]
    variants = [Variant(traversal=t, intersection=isect, block=_block_shape(block)) for t in traversals.split(",") if t]
    rows = []
    for size in (int(s) for s in sizes.split(",") if s):
        for view in (v for v in views.split(",") if v):
            for k in (k for k in kind.split(",") if k):
                with console.status(f"{view} {k} rays at {size}² and their float64 reference..."):
                    batch = make_rays(view, k, size)
                for be in bes:
                    for variant in variants:
                        with console.status(f"{view} {k} {size}² on {be.name} {variant.traversal}..."):
                            rows.append(bench_rays(batch, be, variant, repeats=repeats, render=render))
                        console.print("  ".join(table_rows(rows[-1:])[0]))
    table = Table(title="rays through rtlab.trace")
    for col in COLUMNS:
        table.add_column(col, justify="right")
    for cells in table_rows(rows):
        table.add_row(*cells)
    console.print(table)
    if md:
        with open(md, "a") as f:
            f.write(rays_markdown(rows, _command("rays")) + "\n")


@bench_app.command("cpu")
def bench_cpu_cmd(views: str = typer.Option("bunny/fill,sponza/inside,default",
                                            help="benchmark views (scene/view) or presets with their own camera"),
                  size: int = typer.Option(1024, help="image side: size² primary rays"),
                  traversal: str = typer.Option("bvh-packet", help="rtlab's traversals, comma-separated"),
                  isect: str = typer.Option("moller"),
                  device: Optional[str] = typer.Option(None, help="OpenCL device name substring (default: the CPU)"),
                  threads: Optional[int] = typer.Option(None, help="PoCL worker threads (POCL_MAX_PTHREAD_COUNT; "
                                                                   "default: one a core)"),
                  rounds: int = typer.Option(7, help="alternating timed rounds; medians are reported"),
                  md: Optional[Path] = typer.Option(None, help="append the table as markdown to this file")):
    """rtlab on PoCL against Embree (embreex, one thread), the same rays in the same run: Mrays/s of
    each, the ratio, and each one's error against the float64 reference."""
    import os
    if threads is not None:
        if threads < 1:
            raise RtlabError(f"--threads must be at least 1, got {threads}")
        os.environ["POCL_MAX_PTHREAD_COUNT"] = str(threads)    # read when PoCL starts, below
    from ..backends import get_backend
    from ..benches.cpu import COLUMNS, EmbreeTracer, bench_cpu, cpu_markdown, table_rows
    from ..benches.rays import make_rays
    from ..device.kernels import Variant
    variants = [Variant(traversal=t, intersection=isect) for t in traversal.split(",") if t]
    backend = get_backend("opencl", device if device is not None else os.environ.get("RTLAB_DEVICE", "cpu"))
    rows = []
    for view in (v for v in views.split(",") if v):
        with console.status(f"{view}: {size}² rays and their float64 reference..."):
            batch = make_rays(view, "primary", size)
        with console.status(f"{view}: Embree's BVH..."):
            embree = EmbreeTracer(batch.scene.vertices, batch.scene.faces)
        for variant in variants:
            with console.status(f"{view}: rtlab {variant.traversal} and Embree, {rounds} rounds...") as status:
                rows.append(bench_cpu(batch, backend, variant, rounds, embree,
                                      progress=lambda i: status.update(f"{view} {variant.traversal}: round {i + 1} "
                                                                       f"of {rounds}")))
            console.print("  ".join(table_rows(rows[-1:])[0]))
    table = Table(title=f"rtlab on {backend.device_name} against Embree (one thread), same rays")
    for col in COLUMNS:
        table.add_column(col, justify="right")
    for cells in table_rows(rows):
        table.add_row(*cells)
    console.print(table)
    if md:
        with open(md, "a") as f:
            f.write(cpu_markdown(rows, _command("cpu"), rounds) + "\n")


@bench_app.command("intersect")
def bench_intersect(scenes: str = typer.Option("bunny,sponza", help="comma-separated presets"),
                    backends: str = typer.Option("auto", help="comma-separated: opencl, cuda, auto"),
                    device: Optional[str] = typer.Option(None, help="device name substring (OpenCL)"),
                    isects: str = typer.Option("moller,wald,plucker,watertight", help="tests to time"),
                    size: int = typer.Option(1024, min=1, help="rays: width = height of the camera (paper: 1024)"),
                    triangles: int = typer.Option(1000, min=1, help="triangles in the loop (paper: the first 1000)"),
                    repeats: int = typer.Option(5, min=1, help="timed launches; the median is reported"),
                    render_size: int = typer.Option(1024, min=0, help="in-render effect at this size; 0: skip it"),
                    check: bool = typer.Option(True, help="error against the float64 reference"),
                    md: Optional[Path] = typer.Option(None, help="append the table as markdown to this file")):
    """The paper's Table 3: each triangle test on the first 1000 triangles (time, registers, bytes per
    triangle, error), then in the renderer (Mrays/s and error)."""
    from ..backends import get_backend
    from ..benches.intersect import PAPER_TABLE3_MS, PAPER_TABLE3_REGISTERS, bench_table3, table3_markdown
    bes = [get_backend(b, device if b == "opencl" else None) for b in backends.split(",")]
    names = [i for i in isects.split(",") if i]
    rows = []
    for name in [s for s in scenes.split(",") if s]:
        scene = _load_scene(name, render_size or size)
        _tree(scene)
        for be in bes:
            with console.status(f"Table 3 on {scene.name}, {be.name}..."):
                rows += bench_table3(scene, be, names, size, triangles, repeats, render_size or None, check=check)
    table = Table(title=f"Table 3: first {triangles} triangles, {size}x{size} rays; renderer at {render_size}²")
    for col in ("scene", "test", "backend", "loop ms", "Mtests/s", "paper ms", "nvcc regs", "paper regs",
                "B/tri read", "B/tri extra", "loop error", "render Mrays/s", "render error"):
        table.add_column(col, justify="right")
    for r in rows:
        paper = PAPER_TABLE3_MS.get(r.scene, {}).get(r.isect)
        table.add_row(r.scene, r.isect, r.backend, f"{r.median_ms:.2f}", f"{r.mtests:,.0f}",
                      f"{paper}" if paper else "-", str(r.nvcc["registers"]) if r.nvcc else "-",
                      str(PAPER_TABLE3_REGISTERS.get(r.isect, "-")), str(r.bytes_read), str(r.bytes_precomputed),
                      r.error_text(), f"{r.render.mrays:,.1f}" if r.render else "-",
                      r.render.error_text() if r.render else "-")
    Console(width=max(console.width, 200)).print(table)   # too wide to fold legibly in 80 columns
    if any(not be.is_gpu() for be in bes):
        console.print("CPU device: times are not comparable with the paper's GPU figures.")
    if md:
        cmd = "rtlab bench intersect " + " ".join(sys.argv[3:]) if len(sys.argv) > 3 else "rtlab bench intersect"
        with open(md, "a") as f:
            f.write(table3_markdown(rows, cmd) + "\n")


@bench_app.command("robustness")
def bench_robustness(backends: str = typer.Option("auto", help="comma-separated: opencl, cuda, auto"),
                     device: Optional[str] = typer.Option(None, help="device name substring (OpenCL)"),
                     isects: Optional[str] = typer.Option(None, help="tests (default: every one)"),
                     traversals: Optional[str] = typer.Option(None, help="traversals (default: every one)"),
                     families: str = typer.Option("1,2,3,4,5,6,7,8,9,10,11,12",
                                                  help="families 1-9 (issue 4) and 10-12 (issue 13)"),
                     size: str = typer.Option("bench", help="'bench' (127² stairs, 10^5 rays) or 'test' (small)"),
                     conservative: str = typer.Option("default", help="RT_CONSERVATIVE: default, 0, 1 or 0,1"),
                     detail: bool = typer.Option(False, help="one row per case instead of per family"),
                     md: Optional[Path] = typer.Option(None, help="append the table as markdown to this file")):
    """Stiff and extreme cases (issue 4): leaks, misses, mismatches, ties, false hits, NaN t, crashes
    and hangs of every triangle test x traversal against the float64 reference."""
    from ..backends import get_backend
    from ..robustness import TABLE_COLUMNS, aggregate, row_cells, rows_table, run_robustness
    if any(c not in ("default", "0", "1") for c in conservative.split(",")):
        raise RtlabError(f"--conservative takes default, 0, 1 or 0,1, got '{conservative}'")
    cons = [None if c == "default" else int(c) for c in conservative.split(",")]
    fams = _int_list(families, "--families")
    rows = []
    for b in backends.split(","):
        be = get_backend(b, device if b == "opencl" else None)
        with console.status(f"robustness suite on {be.name}...") as status:
            rows += run_robustness(be, isects.split(",") if isects else None,
                                   traversals.split(",") if traversals else None, fams, size, cons,
                                   progress=lambda m: status.update(f"{be.name}: {m}"))
    shown = rows if detail else aggregate(rows)
    table = Table(title=f"robustness ({size} sizes)")
    for col in TABLE_COLUMNS:
        table.add_column(col, justify="right")
    for r in shown:
        table.add_row(*row_cells(r))
    Console(width=max(console.width, 180)).print(table)   # too wide to fold legibly in 80 columns
    if md:
        cmd = "rtlab bench robustness " + " ".join(sys.argv[3:]) if len(sys.argv) > 3 else "rtlab bench robustness"
        with open(md, "a") as f:
            f.write(f"### Robustness suite\n\nCommand: `{cmd}`\n\n" + rows_table(shown) + "\n")


@bench_app.command("shading")
def bench_shading(shadow_scenes: str = typer.Option("bunny,sponza,kitchen", help="Table 5 shadow rows (presets)"),
                  bounce_scenes: str = typer.Option("sponza,kitchen", help="Table 5 bounce rows (presets)"),
                  bounces: str = typer.Option("1,2,3", help="bounce depths of the bounce rows"),
                  special_bounces: int = typer.Option(3, min=-1, help="depth of the specialised-vs-general rows; -1: skip"),
                  backends: str = typer.Option("auto", help="comma-separated: opencl, cuda, auto"),
                  device: Optional[str] = typer.Option(None, help="device name substring (OpenCL)"),
                  size: int = typer.Option(1024, min=1, help="image width = height (paper: 1024)"),
                  repeats: int = typer.Option(10, min=1, help="timed frames; the median is reported"),
                  check_size: int = typer.Option(128, min=0, help="error against the float64 reference at this size; 0: skip"),
                  materials: str = typer.Option("paper", help="materials of the bounce rows (rtlab.scene.materials)"),
                  md: Optional[Path] = typer.Option(None, help="append the tables as markdown to this file")):
    """The paper's Table 5 (shadows one-pass vs two-pass, 1-3 bounces) and specialised vs general kernels."""
    from ..backends import get_backend
    from ..benches.shading import (PAPER_OCCUPANCY, PAPER_REGISTERS, bench_bounces, bench_shadows,
                                  bench_specialisation, table5_markdown)
    bes = [get_backend(b, device if b == "opencl" else None) for b in backends.split(",")]
    rows = []
    scenes = {}
    for name in dict.fromkeys([s for s in (shadow_scenes + "," + bounce_scenes).split(",") if s]):
        scenes[name] = _load_scene(name, size)
        _tree(scenes[name])
    for be in bes:
        for name in [s for s in shadow_scenes.split(",") if s]:
            for mode in ("one-pass", "two-pass"):
                with console.status(f"{name} shadows {mode} on {be.name}..."):
                    rows.append(bench_shadows(scenes[name], be, mode, size, repeats, check_size))
        for name in [s for s in bounce_scenes.split(",") if s]:
            for depth in _int_list(bounces, "--bounces"):
                with console.status(f"{name} {depth} bounces on {be.name}..."):
                    rows.append(bench_bounces(scenes[name], be, depth, size, repeats, check_size, materials=materials))
        if special_bounces >= 0:
            for name in scenes:
                with console.status(f"{name} specialised vs general on {be.name}..."):
                    rows += bench_specialisation(scenes[name], be, special_bounces, size, repeats)
    cpu = any(not be.is_gpu() for be in bes)
    table = Table(title=f"Table 5: shadows, {size}x{size}")
    for col in ("scene", "shadows", "backend", "ms", "fps", "paper fps", "regs", "paper regs", "occupancy",
                "paper occ.", "error vs float64"):
        table.add_column(col, justify="right")
    for r in (r for r in rows if r.table == "shadows"):
        table.add_row(r.scene, r.mode, r.backend, f"{r.median_ms:.2f}", f"{r.fps:,.1f}", str(r.paper_fps or "-"),
                      r.regs_text(), PAPER_REGISTERS[r.mode], r.occupancy_text(), PAPER_OCCUPANCY[r.mode], r.error_text())
    console.print(table)
    table = Table(title=f"Table 5: reflection/refraction kernel tree, {size}x{size}, materials {materials}")
    for col in ("scene", "bounces", "backend", "ms", "fps", "paper fps", "compacted fps", "wavefront fps",
                "launches", "rays", "regs", "occupancy", "error vs float64"):
        table.add_column(col, justify="right")
    for r in (r for r in rows if r.table == "bounces"):
        e = r.extra
        wave = "wave_fps" in e
        table.add_row(r.scene, r.mode, r.backend, f"{r.median_ms:.2f}", f"{r.fps:,.1f}", str(r.paper_fps or "-"),
                      f"{e['compact_fps']:,.1f}" + ("" if e["same_image"] else " (image differs!)"),
                      f"{e['wave_fps']:,.1f} (±{e['wave_max_diff']})" if wave else "-",
                      f"{r.launches} / {e['compact_launches']}" + (f" / {e['wave_launches']}" if wave else ""),
                      f"{r.rays:,} / {e['compact_rays']:,}" + (f" / {e['wave_rays']:,}" if wave else ""),
                      r.regs_text(), r.occupancy_text(), r.error_text())
    console.print(table)
    table = Table(title=f"scene-specialised vs general kernels, scene materials, {special_bounces} bounces, {size}x{size}")
    for col in ("scene", "kernel", "backend", "depth", "ms", "fps", "regs", "occupancy", "same image"):
        table.add_column(col, justify="right")
    for r in (r for r in rows if r.table == "specialised"):
        table.add_row(r.scene, r.mode, r.backend, str(r.extra["depth"]), f"{r.median_ms:.2f}", f"{r.fps:,.1f}",
                      r.regs_text(), r.occupancy_text(),
                      "yes" if r.extra["same_image"] else f"NO (max diff {r.extra['max_diff']})")
    console.print(table)
    console.print("regs/occupancy per kernel in launch order; errors at "
                  f"{check_size}x{check_size}" + ("; CPU device: times are not comparable with the paper's GPU "
                                                  "figures" if cpu else ""))
    if md:
        cmd = "rtlab bench shading " + " ".join(sys.argv[3:]) if len(sys.argv) > 3 else "rtlab bench shading"
        with open(md, "a") as f:
            f.write(table5_markdown(rows, cmd) + "\n")


# Course commands: rtlab lab ..., rtlab grade, rtlab inspect (rtlab/labs/cli.py)
from .course import register as _register_course_commands  # noqa: E402

_register_course_commands(app)


@bench_app.command("traversal")
def bench_traversal(scenes: str = typer.Option("bunny,sponza,kitchen,dragon,conference", help="comma-separated presets"),
                    backends: str = typer.Option("auto", help="comma-separated: opencl, cuda, auto"),
                    device: Optional[str] = typer.Option(None, help="device name substring (OpenCL)"),
                    size: int = typer.Option(1024, min=1, help="image width = height (paper: 1024)"),
                    views: str = typer.Option("preset", help="'preset' or bench views, e.g. far,fill,inside"),
                    repeats: int = typer.Option(25, min=1, help="timed launches; the median is reported"),
                    check: bool = typer.Option(True, help="error against the float64 reference"),
                    traversals: str = typer.Option("stack,packet,restart,shortstack,ropes,bvh"),
                    short_stack: int = typer.Option(4, min=1, help="short-stack entries"),
                    isect: str = typer.Option("moller"), block: str = typer.Option("32x4"),
                    md: Optional[Path] = typer.Option(None, help="append the table as markdown to this file")):
    """The paper's Table 4: every traversal variant (and the BVH): fps, Mrays/s, registers,
    occupancy and error, beside the paper's figures."""
    from ..backends import get_backend
    from ..benches.traversal import bench_table4, resources_text, speedup_text, table4_markdown
    from ..device.kernels import Variant
    base = Variant(intersection=isect, block=_block_shape(block), short_stack=short_stack)
    names = [t for t in traversals.split(",") if t]
    for t in names:
        base.with_(traversal=t)                   # unknown names fail here, before any work
    bes = [get_backend(b, device if b == "opencl" else None) for b in backends.split(",")]
    rows = []
    for scene, view in _bench_scenes(scenes, views, size):
        _tree(scene)
        for be in bes:
            with console.status(f"Table 4 on {scene.name}/{view}, {be.name}...") as status:
                group = bench_table4(scene, be, names, repeats, check, view, base,
                                     progress=lambda msg: status.update(msg))
            for r in group:
                b = r.bench
                console.print(f"{b.scene}/{b.view} {b.backend} {r.traversal}: {b.median_ms:.3f} ms, {b.fps:,.1f} fps, "
                              f"{b.mrays:,.1f} Mrays/s, {resources_text(r)}; {b.error_text()}")
            rows += group
    table = Table(title=f"Table 4: traversals, primary rays, {size}x{size}")
    for col in ("scene", "view", "backend", "traversal", "ms", "fps", "paper fps", "speed-up", "Mrays/s",
                "regs, occ.", "nvcc regs/stack/shared", "error"):
        table.add_column(col, justify="right")
    for r in rows:
        b, n = r.bench, r.nvcc
        table.add_row(b.scene, b.view, b.backend, b.variant.split("/")[0], f"{b.median_ms:.3f}", f"{b.fps:,.1f}",
                      f"{r.paper_fps}" if r.paper_fps and size == 1024 else "-", speedup_text(r), f"{b.mrays:,.1f}",
                      resources_text(r), f"{n['registers']}/{n['local_bytes']}/{n['shared_bytes']}" if n else "-",
                      b.error_text())
    console.print(table)
    if any(not be.is_gpu() for be in bes):
        console.print("CPU device: times are not comparable with the paper's GPU figures.")
    if md:
        cmd = "rtlab bench traversal " + " ".join(sys.argv[3:]) if len(sys.argv) > 3 else "rtlab bench traversal"
        with open(md, "a") as f:
            f.write(table4_markdown(rows, cmd) + "\n")


def _command(name: str) -> str:
    """The command line that made a table, for the markdown beside it."""
    return f"rtlab bench {name} " + " ".join(sys.argv[3:]) if len(sys.argv) > 3 else f"rtlab bench {name}"


def _blocks(text: str) -> list[tuple[int, int]]:
    return [_block_shape(b, "--blocks") for b in text.split(",") if b]


@bench_app.command("memory")
def bench_memory_cmd(scenes: str = typer.Option("bunny,dragon", help="comma-separated presets"),
                     backends: str = typer.Option("auto", help="comma-separated: opencl, cuda, auto"),
                     device: Optional[str] = typer.Option(None, help="device name substring (OpenCL)"),
                     size: int = typer.Option(1024, min=1, help="image width = height (paper: 1024)"),
                     views: str = typer.Option("preset", help="'preset' or bench views, e.g. far,fill"),
                     repeats: int = typer.Option(25, min=1, help="timed launches; the median is reported"),
                     check: bool = typer.Option(True, help="error against the float64 reference"),
                     placements: str = typer.Option("global,texture,const-global,ray-shared,ray-indexed,paper",
                                                    help="placements (rtlab.benches.memory.PLACEMENTS)"),
                     md: Optional[Path] = typer.Option(None, help="append the table as markdown to this file")):
    """Memory placement (§3.1.1, lab step 01): textures vs global loads, constants in constant vs global
    memory, the ray in registers / shared memory / indexed arrays; time, registers, occupancy, error."""
    from ..backends import get_backend
    from ..benches.memory import PLACEMENTS, bench_memory, compiler_report, diff_text, memory_markdown
    names = [n for n in placements.split(",") if n]
    unknown = [n for n in names if n not in PLACEMENTS]
    if unknown:
        raise RtlabError(f"unknown placement(s) {', '.join(unknown)}; choose from {', '.join(PLACEMENTS)}")
    bes = [get_backend(b, device if b == "opencl" else None) for b in backends.split(",")]
    rows = []
    for scene, view in _bench_scenes(scenes, views, size):
        _tree(scene)
        for be in bes:
            with console.status(f"memory placements on {scene.name}/{view}, {be.name}...") as status:
                rows += bench_memory(scene, be, names, repeats, check, view, progress=lambda m: status.update(m))
    table = Table(title=f"memory placement (§3.1.1), {size}x{size}")
    for col in ("scene", "backend", "placement", "ms", "Mrays/s", "regs", "occ.", "nvcc regs/stack/spills/smem",
                "differs from global", "error vs float64"):
        table.add_column(col, justify="right")
    for r in rows:
        b, n = r.bench, r.nvcc
        table.add_row(b.scene, b.backend, r.placement, f"{b.median_ms:.3f}", f"{b.mrays:,.1f}", str(b.registers or "-"),
                      f"{b.occupancy:.0%}" if b.occupancy is not None else "-",
                      f"{n['registers']}/{n['local_bytes']}/{n['spill_bytes']}/{n['shared_bytes']}" if n else "-",
                      diff_text(r), b.error_text())
    console.print(table)
    report = compiler_report()
    if report:
        from ..benches.memory import compiler_report_markdown
        console.print(compiler_report_markdown(report))
    if md:
        with open(md, "a") as f:
            f.write(memory_markdown(rows, _command("memory"), report) + "\n")


@bench_app.command("launch")
def bench_launch_cmd(scene: str = typer.Option("bunny", help="preset"),
                     backends: str = typer.Option("auto", help="comma-separated: opencl, cuda, auto"),
                     device: Optional[str] = typer.Option(None, help="device name substring (OpenCL)"),
                     size: int = typer.Option(1024, min=1, help="image width = height (paper: 1024)"),
                     repeats: int = typer.Option(10, min=1, help="timed launches; the median is reported"),
                     check: bool = typer.Option(True, help="error of the default launch against the float64 reference"),
                     blocks: Optional[str] = typer.Option(None, help="block shapes XxY (default: Fig. 4's set)"),
                     orders: str = typer.Option("rows,morton", help="ray orders within a block"),
                     traversals: str = typer.Option("stack,restart,shortstack,ropes", help="Fig. 5 traversals"),
                     caps: str = typer.Option("0,64,48,40,32,24", help="Fig. 5 register caps (0: none)"),
                     figures: str = typer.Option("4,5", help="which figures: 4, 5 or 4,5"),
                     out: Path = typer.Option(Path("."), help="folder for fig4.png / fig5.png"),
                     md: Optional[Path] = typer.Option(None, help="append the tables as markdown to this file")):
    """Block size (Fig. 4) with pixel vs Morton ray order, and registers/occupancy (Fig. 5): register caps
    and (CUDA) occupancy held down by unused shared memory. Every launch checked against the default's hits."""
    from ..backends import get_backend
    from ..benches.launch import (FIG4_BLOCKS, block_sweep, launch_markdown, occupancy_sweep, plot_fig4, plot_fig5,
                                 register_sweep)
    shapes = _blocks(blocks) if blocks else list(FIG4_BLOCKS)
    cap_list = _int_list(caps, "--caps")
    figs = {f.strip() for f in figures.split(",")}
    bes = [get_backend(b, device if b == "opencl" else None) for b in backends.split(",")]
    sc = _load_scene(scene, size)
    _tree(sc)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for be in bes:
        with console.status(f"launch shapes on {be.name}...") as status:
            step = lambda m: status.update(m)
            if "4" in figs:
                rows += block_sweep(sc, be, shapes, tuple(o for o in orders.split(",") if o), repeats, check,
                                    progress=step)
            if "5" in figs:
                rows += register_sweep(sc, be, tuple(t for t in traversals.split(",") if t), tuple(cap_list), repeats,
                                       check, progress=step)
                rows += occupancy_sweep(sc, be, repeats=repeats, progress=step)
    text = launch_markdown(rows, _command("launch"))
    console.print(text)
    if "4" in figs:
        plot_fig4(rows, out / "fig4.png")
    if "5" in figs:
        plot_fig5(rows, out / "fig5.png")
    console.print(f"plots in {out}")
    if md:
        with open(md, "a") as f:
            f.write(text + "\n")


@bench_app.command("paper")
def bench_paper_cmd(backend: Optional[str] = typer.Option(None, help="opencl, cuda or auto ($RTLAB_BACKEND)"),
                    device: Optional[str] = typer.Option(None, help="device name substring or index ($RTLAB_DEVICE)"),
                    out: Path = typer.Option(Path("paper-results"), help="folder for markdown, CSV and PNG plots"),
                    size: int = typer.Option(1024, min=1, help="image width = height (paper: 1024)"),
                    scenes: str = typer.Option("bunny,sponza,kitchen,dragon", help="comma-separated presets"),
                    sections: str = typer.Option("table2,table3,table4,table5,memory,fig4,fig5",
                                                 help="sections to run, in this order"),
                    repeats: int = typer.Option(10, min=1, help="timed launches per variant; the median is reported"),
                    check: bool = typer.Option(True, help="error against the float64 reference"),
                    budget_s: Optional[float] = typer.Option(None, min=0, help="start no section after this many seconds"),
                    force: bool = typer.Option(False, help="rerun sections finished by an earlier run")):
    """The paper's evaluation on the current device: Tables 2-5, Figs. 4-5 and §3.1.1's memory placement,
    as markdown + CSV + PNG plots in OUT/<backend>-<device>/ (sections finished before are kept)."""
    from ..backends import get_backend
    from ..benches.paper import SECTIONS, run_paper
    names = [s for s in sections.split(",") if s]
    unknown = [s for s in names if s not in SECTIONS]
    if unknown:
        raise RtlabError(f"unknown section(s) {', '.join(unknown)}; choose from {', '.join(SECTIONS)}")
    be = get_backend(backend, device)
    scene_names = [s for s in scenes.split(",") if s]
    for name in scene_names:
        _tree(_load_scene(name, size))
    d = run_paper(be, out, scene_names, size, repeats, names, check, budget_s, force, _command("paper"), console)
    console.print(f"wrote {d / 'paper.md'}, {d / 'paper.csv'} and plots in {d}")


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _usage_error_line(e: typer.TyperException) -> str:
    """A typer usage error (unknown option, bad value, missing argument) as one line naming the
    command, instead of typer's boxed usage panel."""
    ctx = getattr(e, "ctx", None)
    command = ctx.command_path if ctx is not None else "rtlab"
    return f"{command}: {_one_line(e.format_message())} (see {command} --help)"


def main(argv: Optional[list[str]] = None) -> int:
    """Run the command line; returns the exit status. Errors the user can act on (usage errors,
    RtlabError, files that cannot be read or written) are one line on stderr and a non-zero
    status, never a traceback; anything else is a bug, reported in one line too unless
    RTLAB_TRACEBACK=1 asks for the traceback."""
    try:
        status = app(args=argv, prog_name="rtlab", standalone_mode=False)
    except RtlabError as e:
        err_console.print(f"[bold red]rtlab:[/] {escape(str(e))}", highlight=False)
        return 2
    except (typer.Abort, KeyboardInterrupt):
        err_console.print("rtlab: interrupted")
        return 130
    except typer.Exit as e:
        return e.exit_code
    except typer.TyperException as e:    # typer's usage errors (its own click since typer 0.2x)
        if e.format_message().strip():   # (empty after `rtlab` alone: the help is the message)
            print(_usage_error_line(e), file=sys.stderr)
        return getattr(e, "exit_code", 2) or 2
    except OSError as e:                 # a file or folder that cannot be read or written
        where = f" {e.filename}" if e.filename else ""
        err_console.print(f"[bold red]rtlab:[/]{escape(where)}: {escape(e.strerror or str(e))}", highlight=False)
        return 1
    except Exception as e:
        if os.environ.get("RTLAB_TRACEBACK", "").strip() not in ("", "0"):
            raise
        err_console.print(f"[bold red]rtlab: unexpected error[/] ({escape(type(e).__name__)}: "
                          f"{escape(_one_line(e))}); this is a bug: RTLAB_TRACEBACK=1 shows where", highlight=False)
        return 1
    return status if isinstance(status, int) else 0


if __name__ == "__main__":
    sys.exit(main())
