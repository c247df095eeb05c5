"""rtlab bench: the paper's tables and figures, and this project's own measurements, on the current
device. Each command measures through its rtlab.benches module, prints that module's tables and with
--md appends them as markdown (the same tables) with the command that made them."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Optional

import typer

from ..errors import RtlabError
from .common import (append_markdown, backend_list, block_shape, block_shapes, command_line, console, int_list,
                     kd_tree, load_scene, names, print_tables, use_kernels)

bench_app = typer.Typer(no_args_is_help=True, help="Benchmarks: the paper's tables on the current device.")

BACKENDS_HELP = "comma-separated: opencl, cuda, auto"
DEVICE_HELP = "device name substring (OpenCL)"
MD_HELP = "append the table as markdown to this file"
CPU_NOTE = "CPU device: times are not comparable with the paper's GPU figures."


@bench_app.callback()
def bench_options(kernels: Optional[Path] = typer.Option(None, "--kernels", help="kernel tree to compile (default "
                                                         "$RTLAB_KERNEL_DIR or the installation's)")):
    """Benchmarks: the paper's tables on the current device (rtlab bench --kernels DIR SECTION ...)."""
    use_kernels(kernels)


def bench_scenes(scenes: str, views: str, size: int):
    """(scene, view label) pairs: preset cameras, or the benchmark views of ../shared/bench; each
    scene's kd-tree built (or loaded) once."""
    from ..scene import bench_camera
    from ..scene import load_scene as load
    out = []
    for name in names(scenes):
        scene = load_scene(name, size)
        kd_tree(scene)
        if views == "preset":
            out.append((scene, "preset"))
            continue
        for view in names(views):
            vs = load(name, size=size)
            vs.camera = bench_camera(f"{name}/{view}", size)
            out.append((vs, view))
    return out


def _cpu_note(backends) -> None:
    if any(not be.is_gpu() for be in backends):
        console.print(CPU_NOTE)


@bench_app.command("primary")
def bench_primary(ctx: typer.Context,
                  scenes: str = typer.Option("bunny,sponza,kitchen,dragon", help="comma-separated presets"),
                  backends: str = typer.Option("auto", help=BACKENDS_HELP),
                  device: Optional[str] = typer.Option(None, help=DEVICE_HELP),
                  size: int = typer.Option(1024, min=1, help="image width = height"),
                  views: str = typer.Option("preset", help="'preset' or bench views, e.g. far,fill,inside"),
                  repeats: int = typer.Option(25, min=1, help="timed launches; the median is reported"),
                  check: bool = typer.Option(True, help="error against the float64 reference"),
                  traversal: str = typer.Option("stack"), isect: str = typer.Option("moller"),
                  block: str = typer.Option("32x4"),
                  md: Optional[Path] = typer.Option(None, help=MD_HELP)):
    """Primary rays with simple shading (the paper's Table 4 setting): time, Mrays/s, error."""
    from ..benches.primary import bench_render, primary_markdown, primary_tables
    from ..device.kernels import Variant
    variant = Variant(traversal=traversal, intersection=isect, block=block_shape(block))
    bes = backend_list(backends, device)
    rows = []
    for scene, view in bench_scenes(scenes, views, size):
        for be in bes:
            with console.status(f"{scene.name}/{view} on {be.name}..."):
                rows.append(bench_render(scene, be, variant, repeats=repeats, check=check, view=view))
            r = rows[-1]
            console.print(f"{r.scene}/{r.view} {r.backend}: {r.median_ms:.3f} ms, {r.mrays:,.0f} Mrays/s; {r.error_text()}")
    title = f"primary rays, {size}x{size}, {variant.label()}"
    print_tables(primary_tables(rows, title))
    append_markdown(md, primary_markdown(rows, f"Primary rays, {size}x{size}", command_line(ctx)))


@bench_app.command("rays")
def bench_rays(ctx: typer.Context,
               kind: str = typer.Option("primary", help="ray kinds, comma-separated: primary, diffuse"),
               views: str = typer.Option("bunny/far,bunny/fill,dragon/fill,sponza/inside,kitchen/inside,"
                                         "conference/inside", help="benchmark views (scene/view), comma-separated"),
               backends: str = typer.Option("auto", help=BACKENDS_HELP),
               device: Optional[str] = typer.Option(None, help=DEVICE_HELP),
               sizes: str = typer.Option("1024", help="image sides, comma-separated"),
               traversals: str = typer.Option("bvh,stack", help="traversals to time, comma-separated"),
               isect: str = typer.Option("moller"),
               block: str = typer.Option("8x16", help="block of the image-shaped launches (primary rays)"),
               repeats: int = typer.Option(22, help="timed launches; the median is reported"),
               render: bool = typer.Option(True, help="also time the render kernel on primary views"),
               md: Optional[Path] = typer.Option(None, help=MD_HELP)):
    """Rays through the trace API on the peers' benchmark views (../shared/bench): kernel time, Mrays/s,
    the error against the float64 reference, the render kernel on the same camera, the best peer."""
    from ..benches.rays import bench_rays as bench, make_rays, rays_markdown, rays_tables, table_rows
    from ..device.kernels import Variant
    bes = backend_list(backends, device)
    variants = [Variant(traversal=t, intersection=isect, block=block_shape(block)) for t in names(traversals)]
    rows = []
    for size in int_list(sizes, "--sizes"):
        for view in names(views):
            for k in names(kind):
                with console.status(f"{view} {k} rays at {size}² and their float64 reference..."):
                    batch = make_rays(view, k, size)
                for be in bes:
                    for variant in variants:
                        with console.status(f"{view} {k} {size}² on {be.name} {variant.traversal}..."):
                            rows.append(bench(batch, be, variant, repeats=repeats, render=render))
                        console.print("  ".join(table_rows(rows[-1:])[0]))
    print_tables(rays_tables(rows))
    append_markdown(md, rays_markdown(rows, command_line(ctx)))


@bench_app.command("cpu")
def bench_cpu(ctx: typer.Context,
              views: str = typer.Option("bunny/fill,sponza/inside,default",
                                        help="benchmark views (scene/view) or presets with their own camera"),
              size: int = typer.Option(1024, help="image side: size² primary rays"),
              traversal: str = typer.Option("bvh-packet", help="rtlab's traversals, comma-separated"),
              isect: str = typer.Option("moller"),
              device: Optional[str] = typer.Option(None, help="OpenCL device name substring (default: the CPU)"),
              threads: Optional[int] = typer.Option(None, help="PoCL worker threads (POCL_MAX_PTHREAD_COUNT; "
                                                               "default: one a core)"),
              rounds: int = typer.Option(7, help="alternating timed rounds; medians are reported"),
              md: Optional[Path] = typer.Option(None, help=MD_HELP)):
    """rtlab on PoCL against Embree (embreex, one thread), the same rays in the same run: Mrays/s of
    each, the ratio, and each one's error against the float64 reference."""
    if threads is not None:
        if threads < 1:
            raise RtlabError(f"--threads must be at least 1, got {threads}")
        os.environ["POCL_MAX_PTHREAD_COUNT"] = str(threads)    # read when PoCL starts, below
    from ..backends import get_backend
    from ..benches.cpu import EmbreeTracer, bench_cpu as bench, cpu_markdown, cpu_tables, table_rows
    from ..benches.rays import make_rays
    from ..device.kernels import Variant
    variants = [Variant(traversal=t, intersection=isect) for t in names(traversal)]
    backend = get_backend("opencl", device if device is not None else os.environ.get("RTLAB_DEVICE", "cpu"))
    rows = []
    for view in names(views):
        with console.status(f"{view}: {size}² rays and their float64 reference..."):
            batch = make_rays(view, "primary", size)
        with console.status(f"{view}: Embree's BVH..."):
            embree = EmbreeTracer(batch.scene.vertices, batch.scene.faces)
        for variant in variants:
            with console.status(f"{view}: rtlab {variant.traversal} and Embree, {rounds} rounds...") as status:
                rows.append(bench(batch, backend, variant, rounds, embree,
                                  progress=lambda i: status.update(f"{view} {variant.traversal}: round {i + 1} "
                                                                   f"of {rounds}")))
            console.print("  ".join(table_rows(rows[-1:])[0]))
    print_tables(cpu_tables(rows, f"rtlab on {backend.device_name} against Embree (one thread), same rays"))
    append_markdown(md, cpu_markdown(rows, command_line(ctx), rounds))


@bench_app.command("intersect")
def bench_intersect(ctx: typer.Context,
                    scenes: str = typer.Option("bunny,sponza", help="comma-separated presets"),
                    backends: str = typer.Option("auto", help=BACKENDS_HELP),
                    device: Optional[str] = typer.Option(None, help=DEVICE_HELP),
                    isects: str = typer.Option("moller,wald,plucker,watertight", help="tests to time"),
                    size: int = typer.Option(1024, min=1, help="rays: width = height of the camera (paper: 1024)"),
                    triangles: int = typer.Option(1000, min=1, help="triangles in the loop (paper: the first 1000)"),
                    repeats: int = typer.Option(5, min=1, help="timed launches; the median is reported"),
                    render_size: int = typer.Option(1024, min=0, help="in-render effect at this size; 0: skip it"),
                    check: bool = typer.Option(True, help="error against the float64 reference"),
                    md: Optional[Path] = typer.Option(None, help=MD_HELP)):
    """The paper's Table 3: each triangle test on the first 1000 triangles (time, registers, bytes per
    triangle, error), then in the renderer (Mrays/s and error)."""
    from ..benches.intersect import bench_table3, table3_markdown, table3_tables
    bes = backend_list(backends, device)
    rows = []
    for scene, _ in bench_scenes(scenes, "preset", render_size or size):
        for be in bes:
            with console.status(f"Table 3 on {scene.name}, {be.name}..."):
                rows += bench_table3(scene, be, names(isects), size, triangles, repeats, render_size or None,
                                     check=check)
    print_tables(table3_tables(rows), width=200)
    _cpu_note(bes)
    append_markdown(md, table3_markdown(rows, command_line(ctx)))


@bench_app.command("robustness")
def bench_robustness(ctx: typer.Context,
                     backends: str = typer.Option("auto", help=BACKENDS_HELP),
                     device: Optional[str] = typer.Option(None, help=DEVICE_HELP),
                     isects: Optional[str] = typer.Option(None, help="tests (default: every one)"),
                     traversals: Optional[str] = typer.Option(None, help="traversals (default: every one)"),
                     families: str = typer.Option("1,2,3,4,5,6,7,8,9,10,11,12",
                                                  help="families 1-9 (issue 4) and 10-12 (issue 13)"),
                     size: str = typer.Option("bench", help="'bench' (127² stairs, 10^5 rays) or 'test' (small)"),
                     conservative: str = typer.Option("default", help="RT_CONSERVATIVE: default, 0, 1 or 0,1"),
                     detail: bool = typer.Option(False, help="one row per case instead of per family"),
                     md: Optional[Path] = typer.Option(None, help=MD_HELP)):
    """Stiff and extreme cases (issue 4): leaks, misses, mismatches, ties, false hits, NaN t, crashes
    and hangs of every triangle test x traversal against the float64 reference."""
    from ..benches.tables import report_markdown
    from ..robustness import aggregate, robustness_table, run_robustness
    if any(c not in ("default", "0", "1") for c in names(conservative)):
        raise RtlabError(f"--conservative takes default, 0, 1 or 0,1, got '{conservative}'")
    cons = [None if c == "default" else int(c) for c in names(conservative)]
    fams = int_list(families, "--families")
    rows = []
    for be in backend_list(backends, device):
        with console.status(f"robustness suite on {be.name}...") as status:
            rows += run_robustness(be, names(isects) if isects else None, names(traversals) if traversals else None,
                                   fams, size, cons, progress=lambda m: status.update(f"{be.name}: {m}"))
    table = robustness_table(rows if detail else aggregate(rows), f"robustness ({size} sizes)")
    print_tables([table], width=180)
    append_markdown(md, report_markdown("Robustness suite", command_line(ctx),
                                        sorted({f"{r.backend}: {r.device}" for r in rows}), [table]))


@bench_app.command("shading")
def bench_shading(ctx: typer.Context,
                  shadow_scenes: str = typer.Option("bunny,sponza,kitchen", help="Table 5 shadow rows (presets)"),
                  bounce_scenes: str = typer.Option("sponza,kitchen", help="Table 5 bounce rows (presets)"),
                  bounces: str = typer.Option("1,2,3", help="bounce depths of the bounce rows"),
                  special_bounces: int = typer.Option(3, min=-1, help="depth of the specialised-vs-general rows; -1: skip"),
                  backends: str = typer.Option("auto", help=BACKENDS_HELP),
                  device: Optional[str] = typer.Option(None, help=DEVICE_HELP),
                  size: int = typer.Option(1024, min=1, help="image width = height (paper: 1024)"),
                  repeats: int = typer.Option(10, min=1, help="timed frames; the median is reported"),
                  check_size: int = typer.Option(128, min=0, help="error against the float64 reference at this size; 0: skip"),
                  materials: str = typer.Option("paper", help="materials of the bounce rows (rtlab.scene.materials)"),
                  md: Optional[Path] = typer.Option(None, help="append the tables as markdown to this file")):
    """The paper's Table 5 (shadows one-pass vs two-pass, 1-3 bounces) and specialised vs general kernels."""
    from ..benches.shading import (NOTE, bench_bounces, bench_shadows, bench_specialisation, table5_markdown,
                                   table5_tables)
    bes = backend_list(backends, device)
    depths = int_list(bounces, "--bounces")
    scenes = {name: load_scene(name, size) for name in dict.fromkeys(names(shadow_scenes) + names(bounce_scenes))}
    for scene in scenes.values():
        kd_tree(scene)
    rows = []
    for be in bes:
        for name in names(shadow_scenes):
            for mode in ("one-pass", "two-pass"):
                with console.status(f"{name} shadows {mode} on {be.name}..."):
                    rows.append(bench_shadows(scenes[name], be, mode, size, repeats, check_size))
        for name in names(bounce_scenes):
            for depth in depths:
                with console.status(f"{name} {depth} bounces on {be.name}..."):
                    rows.append(bench_bounces(scenes[name], be, depth, size, repeats, check_size, materials=materials))
        if special_bounces >= 0:
            for name in scenes:
                with console.status(f"{name} specialised vs general on {be.name}..."):
                    rows += bench_specialisation(scenes[name], be, special_bounces, size, repeats)
    print_tables(table5_tables(rows), width=160)
    console.print(NOTE + f" Errors at {check_size}x{check_size}.")
    _cpu_note(bes)
    append_markdown(md, table5_markdown(rows, command_line(ctx)))


@bench_app.command("traversal")
def bench_traversal(ctx: typer.Context,
                    scenes: str = typer.Option("bunny,sponza,kitchen,dragon,conference", help="comma-separated presets"),
                    backends: str = typer.Option("auto", help=BACKENDS_HELP),
                    device: Optional[str] = typer.Option(None, help=DEVICE_HELP),
                    size: int = typer.Option(1024, min=1, help="image width = height (paper: 1024)"),
                    views: str = typer.Option("preset", help="'preset' or bench views, e.g. far,fill,inside"),
                    repeats: int = typer.Option(25, min=1, help="timed launches; the median is reported"),
                    check: bool = typer.Option(True, help="error against the float64 reference"),
                    traversals: str = typer.Option("stack,packet,restart,shortstack,ropes,bvh"),
                    short_stack: int = typer.Option(4, min=1, help="short-stack entries"),
                    isect: str = typer.Option("moller"), block: str = typer.Option("32x4"),
                    md: Optional[Path] = typer.Option(None, help=MD_HELP)):
    """The paper's Table 4: every traversal variant (and the BVH): fps, Mrays/s, registers,
    occupancy and error, beside the paper's figures."""
    from ..benches.traversal import bench_table4, resources_text, table4_markdown, table4_tables
    from ..device.kernels import Variant
    base = Variant(intersection=isect, block=block_shape(block), short_stack=short_stack)
    chosen = names(traversals)
    for t in chosen:
        base.with_(traversal=t)                   # unknown names fail here, before any work
    bes = backend_list(backends, device)
    rows = []
    for scene, view in bench_scenes(scenes, views, size):
        for be in bes:
            with console.status(f"Table 4 on {scene.name}/{view}, {be.name}...") as status:
                group = bench_table4(scene, be, chosen, repeats, check, view, base,
                                     progress=lambda msg: status.update(msg))
            for r in group:
                b = r.bench
                console.print(f"{b.scene}/{b.view} {b.backend} {r.traversal}: {b.median_ms:.3f} ms, {b.fps:,.1f} fps, "
                              f"{b.mrays:,.1f} Mrays/s, {resources_text(r)}; {b.error_text()}")
            rows += group
    print_tables(table4_tables(rows), width=200)
    _cpu_note(bes)
    append_markdown(md, table4_markdown(rows, command_line(ctx)))


@bench_app.command("memory")
def bench_memory(ctx: typer.Context,
                 scenes: str = typer.Option("bunny,dragon", help="comma-separated presets"),
                 backends: str = typer.Option("auto", help=BACKENDS_HELP),
                 device: Optional[str] = typer.Option(None, help=DEVICE_HELP),
                 size: int = typer.Option(1024, min=1, help="image width = height (paper: 1024)"),
                 views: str = typer.Option("preset", help="'preset' or bench views, e.g. far,fill"),
                 repeats: int = typer.Option(25, min=1, help="timed launches; the median is reported"),
                 check: bool = typer.Option(True, help="error against the float64 reference"),
                 placements: str = typer.Option("global,texture,const-global,ray-shared,ray-indexed,paper",
                                                help="placements (rtlab.benches.memory.PLACEMENTS)"),
                 md: Optional[Path] = typer.Option(None, help=MD_HELP)):
    """Memory placement (§3.1.1, lab step 01): textures vs global loads, constants in constant vs global
    memory, the ray in registers / shared memory / indexed arrays; time, registers, occupancy, error."""
    from ..benches.memory import PLACEMENTS, bench_memory as bench, compiler_report, memory_markdown, memory_tables
    chosen = names(placements)
    unknown = [n for n in chosen if n not in PLACEMENTS]
    if unknown:
        raise RtlabError(f"unknown placement(s) {', '.join(unknown)}; choose from {', '.join(PLACEMENTS)}")
    bes = backend_list(backends, device)
    rows = []
    for scene, view in bench_scenes(scenes, views, size):
        for be in bes:
            with console.status(f"memory placements on {scene.name}/{view}, {be.name}...") as status:
                rows += bench(scene, be, chosen, repeats, check, view, progress=lambda m: status.update(m))
    report = compiler_report()
    print_tables(memory_tables(rows, report), width=200)
    append_markdown(md, memory_markdown(rows, command_line(ctx), report))


@bench_app.command("launch")
def bench_launch(ctx: typer.Context,
                 scene: str = typer.Option("bunny", help="preset"),
                 backends: str = typer.Option("auto", help=BACKENDS_HELP),
                 device: Optional[str] = typer.Option(None, help=DEVICE_HELP),
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
    from ..benches.launch import (FIG4_BLOCKS, INTRO, block_sweep, launch_markdown, launch_tables, occupancy_sweep,
                                  plot_fig4, plot_fig5, register_sweep)
    shapes = block_shapes(blocks) if blocks else list(FIG4_BLOCKS)
    cap_list = int_list(caps, "--caps")
    figs = set(names(figures))
    bes = backend_list(backends, device)
    sc = load_scene(scene, size)
    kd_tree(sc)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for be in bes:
        with console.status(f"launch shapes on {be.name}...") as status:
            step = lambda m: status.update(m)
            if "4" in figs:
                rows += block_sweep(sc, be, shapes, tuple(names(orders)), repeats, check, progress=step)
            if "5" in figs:
                rows += register_sweep(sc, be, tuple(names(traversals)), tuple(cap_list), repeats, check,
                                       progress=step)
                rows += occupancy_sweep(sc, be, repeats=repeats, progress=step)
    console.print(INTRO)
    print_tables(launch_tables(rows), width=200)
    if "4" in figs:
        plot_fig4(rows, out / "fig4.png")
    if "5" in figs:
        plot_fig5(rows, out / "fig5.png")
    console.print(f"plots in {out}")
    append_markdown(md, launch_markdown(rows, command_line(ctx)))


@bench_app.command("paper")
def bench_paper(ctx: typer.Context,
                backend: Optional[str] = typer.Option(None, help="opencl, cuda or auto ($RTLAB_BACKEND)"),
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
    chosen = names(sections)
    unknown = [s for s in chosen if s not in SECTIONS]
    if unknown:
        raise RtlabError(f"unknown section(s) {', '.join(unknown)}; choose from {', '.join(SECTIONS)}")
    be = get_backend(backend, device)
    scene_names = names(scenes)
    bench_scenes(scenes, "preset", size)                # every scene's kd-tree, before the timed sections
    d = run_paper(be, out, scene_names, size, repeats, chosen, check, budget_s, force, command_line(ctx), console)
    console.print(f"wrote {d / 'paper.md'}, {d / 'paper.csv'} and plots in {d}")


def register(app: typer.Typer) -> None:
    app.add_typer(bench_app, name="bench")
