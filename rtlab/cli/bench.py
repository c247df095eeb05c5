"""rtlab bench: the paper's tables and figures (rtlab.cli.bench_paper) and rtlab's own measurements
(here: primary rays, rays through the trace API, the CPU against Embree, the robustness suite), on
the current device. Each command measures through its rtlab.benches module, prints that module's
tables and with --md appends them as markdown (the same tables) with the command that made them."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Optional

import typer

from .. import settings
from ..errors import RtlabError
from .common import (append_markdown, backend_list, block_shape, command_line, console, int_list, kd_tree, load_scene,
                     names, print_tables, use_kernels)

bench_app = typer.Typer(no_args_is_help=True, help="Benchmarks: the paper's tables on the current device.")

# Options every bench takes alike
BACKENDS = typer.Option("auto", help="comma-separated: opencl, cuda, auto")
DEVICE = typer.Option(None, help="device name substring (OpenCL)")
CHECK = typer.Option(True, help="error against the float64 reference")
MD = typer.Option(None, help="append the tables as markdown to this file (a block for docs/results/)")
SIZE = typer.Option(1024, min=1, help="image width = height (paper: 1024)")
VIEWS = typer.Option("preset", help="'preset' or bench views, e.g. far,fill,inside")
CPU_NOTE = "CPU device: times are not comparable with the paper's GPU figures."


@bench_app.callback()
def bench_options(kernels: Optional[Path] = typer.Option(None, "--kernels", help="kernel sources to compile (default "
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


def scenes_option(default: str):
    return typer.Option(default, help="comma-separated presets")


def repeats_option(default: int):
    return typer.Option(default, min=1, help="timed launches; the median is reported")


def cpu_note(backends) -> None:
    if any(not be.is_gpu() for be in backends):
        console.print(CPU_NOTE)


@bench_app.command("primary")
def bench_primary(ctx: typer.Context,
                  scenes: str = scenes_option("bunny,sponza,kitchen,dragon"),
                  backends: str = BACKENDS,
                  device: Optional[str] = DEVICE,
                  size: int = SIZE,
                  views: str = VIEWS,
                  repeats: int = repeats_option(25),
                  check: bool = CHECK,
                  traversal: str = typer.Option("stack"), isect: str = typer.Option("moller"),
                  block: str = typer.Option("32x4"),
                  md: Optional[Path] = MD):
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
               backends: str = BACKENDS,
               device: Optional[str] = DEVICE,
               sizes: str = typer.Option("1024", help="image sides, comma-separated"),
               traversals: str = typer.Option("default", help="traversals to time, comma-separated; 'default': "
                                                              "the one trace() runs on the device"),
               isect: Optional[str] = typer.Option(None, help="triangle test (default: trace()'s on the device)"),
               block: Optional[str] = typer.Option(None, help="block of the image-shaped launches (primary rays; "
                                                              "default: trace()'s on the device)"),
               repeats: int = typer.Option(22, help="timed launches; the median is reported"),
               render: bool = typer.Option(True, help="also time the render kernel on primary views"),
               md: Optional[Path] = MD):
    """Rays through the trace API on the peers' benchmark views (../shared/bench): kernel time, Mrays/s,
    the error against the float64 reference, the render kernel on the same camera, the best peer."""
    from ..benches.rays import RAY_KINDS, bench_rays as bench, make_rays, rays_markdown, rays_tables, table_rows
    from ..device.kernels import Variant
    kinds = names(kind)
    if not kinds or any(k not in RAY_KINDS for k in kinds):     # before the first kind runs for minutes
        raise RtlabError(f"--kind takes {', '.join(RAY_KINDS)} (comma-separated), got {kind!r}")
    bes = backend_list(backends, device)
    # parts left None are trace()'s default on each backend (bench resolves them)
    variants = [Variant(traversal=None if t == "default" else t, intersection=isect,
                        block=block_shape(block) if block else None) for t in names(traversals)]
    rows = []
    for size in int_list(sizes, "--sizes"):
        for view in names(views):
            for k in kinds:
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
              views: str = typer.Option("bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside,default",
                                        help="benchmark views (scene/view) or presets with their own camera"),
              kind: str = typer.Option("primary,diffuse", help="ray kinds, comma-separated: primary, diffuse "
                                                                "(../shared/bench/README.md)"),
              size: int = typer.Option(1024, help="image side: size² primary rays (and a diffuse ray a hit pixel)"),
              variants: str = typer.Option("default,bvh-packet/moller,bvh-wide,stack",
                                           help="rtlab's variants, comma-separated: 'default' (the library's on this "
                                                "device), a traversal, a test or traversal/test (the rest from the "
                                                "default)"),
              device: Optional[str] = typer.Option(None, help="OpenCL device name substring (default: the CPU)"),
              threads: Optional[int] = typer.Option(None, help="PoCL worker threads (POCL_MAX_PTHREAD_COUNT; "
                                                               "default: one a core)"),
              rounds: int = typer.Option(7, help="alternating timed rounds; medians are reported"),
              md: Optional[Path] = MD):
    """rtlab on PoCL against Embree (embreex, one thread), the same rays in the same run, each round
    every rtlab variant then Embree: Mrays/s of each, the ratio, and each one's error against the
    float64 reference."""
    if threads is not None:
        if threads < 1:
            raise RtlabError(f"--threads must be at least 1, got {threads}")
        os.environ["POCL_MAX_PTHREAD_COUNT"] = str(threads)    # read when PoCL starts, below
    from ..backends import get_backend
    from ..benches.cpu import EmbreeTracer, bench_cpu_variants, cpu_markdown, cpu_tables, table_rows
    from ..benches.rays import RAY_KINDS, make_rays
    from ..device.tracing import default_variant, resolve_variant
    backend = get_backend("opencl", device if device is not None else settings.get("RTLAB_DEVICE", "cpu"))
    chosen = [default_variant(backend) if v == "default" else resolve_variant(v, backend) for v in names(variants)]
    kinds = names(kind)
    if not chosen or not kinds or any(k not in RAY_KINDS for k in kinds):
        raise RtlabError(f"--kind takes {', '.join(RAY_KINDS)} and --variants at least one variant, got "
                         f"--kind {kind!r} --variants {variants!r}")
    rows = []
    for view in names(views):
        embree = None
        for k in kinds:
            with console.status(f"{view}: {k} rays at {size}² and their float64 reference..."):
                batch = make_rays(view, k, size)
            if embree is None:
                with console.status(f"{view}: Embree's BVH..."):
                    embree = EmbreeTracer(batch.scene.vertices, batch.scene.faces)
            with console.status(f"{view} {k}: rtlab and Embree, {rounds} rounds...") as status:
                rows += bench_cpu_variants(batch, backend, chosen, rounds, embree,
                                           progress=lambda i: status.update(f"{view} {k}: round {i + 1} of {rounds}"))
            for cells in table_rows(rows[-len(chosen):]):
                console.print("  ".join(cells))
    print_tables(cpu_tables(rows, f"rtlab on {backend.device_name} against Embree (one thread), same rays"))
    append_markdown(md, cpu_markdown(rows, command_line(ctx), rounds))


@bench_app.command("robustness")
def bench_robustness(ctx: typer.Context,
                     backends: str = BACKENDS,
                     device: Optional[str] = DEVICE,
                     isects: Optional[str] = typer.Option(None, help="tests (default: every one)"),
                     traversals: Optional[str] = typer.Option(None, help="traversals (default: every one)"),
                     families: str = typer.Option("1,2,3,4,5,6,7,8,9,10,11,12,13,14,15",
                                                  help="families 1-15 (rtlab.robustness)"),
                     size: str = typer.Option("bench", help="'bench' (127² stairs, 10^5 rays) or 'test' (small)"),
                     conservative: str = typer.Option("default", help="RT_CONSERVATIVE: default, 0, 1 or 0,1"),
                     detail: bool = typer.Option(False, help="one row per case instead of per family"),
                     md: Optional[Path] = MD):
    """Stiff and extreme cases: leaks, misses, mismatches, ties, ids that differ between
    traversals, false hits, NaN t, t beyond its error bound, crashes and hangs of every triangle test
    x traversal against the float64 reference."""
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


def register(app: typer.Typer) -> None:
    app.add_typer(bench_app, name="bench")
