"""rtlab bench for the paper's evaluation: Table 3 (intersect), Table 4 (traversal), Table 5
(shading), §3.1.1 (memory), Figs. 4-5 (launch) and all of them at once (paper). The commands join
rtlab.cli.bench's ``bench`` group."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ..errors import RtlabError
from .bench import (BACKENDS, CHECK, DEVICE, MD, SIZE, VIEWS, bench_app, bench_scenes, cpu_note, repeats_option,
                    scenes_option)
from .common import (append_markdown, backend_list, block_shape, block_shapes, command_line, console, int_list,
                     kd_tree, load_scene, names, output_folder, print_tables)


@bench_app.command("intersect")
def bench_intersect(ctx: typer.Context,
                    scenes: str = scenes_option("bunny,sponza"),
                    backends: str = BACKENDS,
                    device: Optional[str] = DEVICE,
                    isects: str = typer.Option("moller,wald,plucker,watertight", help="tests to time"),
                    size: int = typer.Option(1024, min=1, help="rays: width = height of the camera (paper: 1024)"),
                    triangles: int = typer.Option(1000, min=1, help="triangles in the loop (paper: the first 1000)"),
                    repeats: int = repeats_option(5),
                    render_size: int = typer.Option(1024, min=0, help="in-render effect at this size; 0: skip it"),
                    check: bool = CHECK,
                    md: Optional[Path] = MD):
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
    cpu_note(bes)
    append_markdown(md, table3_markdown(rows, command_line(ctx)))


@bench_app.command("shading")
def bench_shading(ctx: typer.Context,
                  shadow_scenes: str = typer.Option("bunny,sponza,kitchen", help="Table 5 shadow rows (presets)"),
                  bounce_scenes: str = typer.Option("sponza,kitchen", help="Table 5 bounce rows (presets)"),
                  bounces: str = typer.Option("1,2,3", help="bounce depths of the bounce rows"),
                  special_bounces: int = typer.Option(3, min=-1, help="depth of the specialised-vs-general rows; -1: skip"),
                  backends: str = BACKENDS,
                  device: Optional[str] = DEVICE,
                  size: int = SIZE,
                  repeats: int = typer.Option(10, min=1, help="timed frames; the median is reported"),
                  check_size: int = typer.Option(128, min=0, help="error against the float64 reference at this size; 0: skip"),
                  materials: str = typer.Option("paper", help="materials of the bounce rows (rtlab.scene.materials)"),
                  md: Optional[Path] = MD):
    """The paper's Table 5 (shadows one-pass vs two-pass, 1-3 bounces) and specialised vs general kernels."""
    from ..benches.shadows_bounces import (NOTE, bench_bounces, bench_shadows, bench_specialisation, table5_markdown,
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
    cpu_note(bes)
    append_markdown(md, table5_markdown(rows, command_line(ctx)))


@bench_app.command("traversal")
def bench_traversal(ctx: typer.Context,
                    scenes: str = scenes_option("bunny,sponza,kitchen,dragon,conference"),
                    backends: str = BACKENDS,
                    device: Optional[str] = DEVICE,
                    size: int = SIZE,
                    views: str = VIEWS,
                    repeats: int = repeats_option(25),
                    check: bool = CHECK,
                    traversals: str = typer.Option("stack,packet,restart,shortstack,ropes,bvh"),
                    short_stack: int = typer.Option(4, min=1, help="short-stack entries"),
                    isect: str = typer.Option("moller"), block: str = typer.Option("32x4"),
                    md: Optional[Path] = MD):
    """The paper's Table 4: every traversal variant (and the BVH): fps, Mrays/s, registers,
    occupancy and error, beside the paper's figures."""
    from ..benches.traversal import bench_table4, resources_text, table4_markdown, table4_tables
    from ..device.kernels import Variant
    base = Variant.paper(intersection=isect, block=block_shape(block), short_stack=short_stack)
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
    cpu_note(bes)
    append_markdown(md, table4_markdown(rows, command_line(ctx)))


@bench_app.command("memory")
def bench_memory(ctx: typer.Context,
                 scenes: str = scenes_option("bunny,dragon"),
                 backends: str = BACKENDS,
                 device: Optional[str] = DEVICE,
                 size: int = SIZE,
                 views: str = typer.Option("preset", help="'preset' or bench views, e.g. far,fill"),
                 repeats: int = repeats_option(25),
                 check: bool = CHECK,
                 placements: str = typer.Option("global,texture,const-global,ray-shared,ray-indexed,paper",
                                                help="placements (rtlab.benches.memory.PLACEMENTS)"),
                 md: Optional[Path] = MD):
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
                 backends: str = BACKENDS,
                 device: Optional[str] = DEVICE,
                 size: int = SIZE,
                 repeats: int = repeats_option(10),
                 check: bool = typer.Option(True, help="error of the default launch against the float64 reference"),
                 blocks: Optional[str] = typer.Option(None, help="block shapes XxY (default: Fig. 4's set)"),
                 orders: str = typer.Option("rows,morton", help="ray orders within a block"),
                 traversals: str = typer.Option("stack,restart,shortstack,ropes", help="Fig. 5 traversals"),
                 caps: str = typer.Option("0,64,48,40,32,24", help="Fig. 5 register caps (0: none)"),
                 figures: str = typer.Option("4,5", help="which figures: 4, 5 or 4,5"),
                 out: Path = typer.Option(Path("."), help="folder for fig4.png / fig5.png"),
                 md: Optional[Path] = MD):
    """Block size (Fig. 4) with pixel vs Morton ray order, and registers/occupancy (Fig. 5): register caps
    and (CUDA) occupancy held down by unused shared memory. Every launch checked against the default's hits."""
    from ..benches.launch import (FIG4_BLOCKS, INTRO, block_sweep, launch_markdown, launch_tables, occupancy_sweep,
                                  plot_fig4, plot_fig5, register_sweep)
    shapes = block_shapes(blocks) if blocks else list(FIG4_BLOCKS)
    cap_list = int_list(caps, "--caps")
    figs = set(names(figures))
    if not figs or not figs <= {"4", "5"}:
        raise RtlabError(f"--figures takes 4, 5 or 4,5 (the figures this command makes), got {figures!r}")
    output_folder(out)
    bes = backend_list(backends, device)
    sc = load_scene(scene, size)
    kd_tree(sc)
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
                size: int = SIZE,
                scenes: str = scenes_option("bunny,sponza,kitchen,dragon"),
                sections: str = typer.Option("table2,table3,table4,table5,memory,fig4,fig5",
                                             help="sections to run, in this order"),
                repeats: int = typer.Option(10, min=1, help="timed launches per variant; the median is reported"),
                check: bool = CHECK,
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
    output_folder(out)
    be = get_backend(backend, device)
    scene_names = names(scenes)
    bench_scenes(scenes, "preset", size)                # every scene's kd-tree, before the timed sections
    d = run_paper(be, out, scene_names, size, repeats, chosen, check, budget_s, force, command_line(ctx), console)
    console.print(f"wrote {d / 'paper.md'}, {d / 'paper.csv'} and plots in {d}")
