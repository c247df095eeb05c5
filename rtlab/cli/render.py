"""rtlab render: primary rays with simple shading, or Whitted ray tracing (--shadows, --bounces)."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.markup import escape

from ..errors import RtlabError
from .common import block_shape, console, image_file, load_scene, traversal_structure, use_kernels

# beside the time where --check was not given: the error column is missing, not zero
NOT_CHECKED = "; error: not checked (--check)"


def render(scene: str = typer.Argument("default", help="preset name, 'default' or a mesh file"),
           backend: Optional[str] = typer.Option(None, help="opencl, cuda or auto ($RTLAB_BACKEND)"),
           device: Optional[str] = typer.Option(None, help="device name substring or index ($RTLAB_DEVICE)"),
           size: Optional[int] = typer.Option(None, min=1, help="image width = height (default: the preset's, 1024)"),
           out: Path = typer.Option(Path("render.png"), help="PNG to write"),
           check: bool = typer.Option(False, help="compare with the float64 reference and print the error"),
           repeats: int = typer.Option(5, min=1, help="timed launches (median reported)"),
           traversal: Optional[str] = typer.Option(None, help="traversal (default: bvh on a GPU, bvh-packet on a CPU)"),
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
           kernels: Optional[Path] = typer.Option(None, "--kernels", help="kernel sources to compile (a copy of "
                                                  "kernels/ with your work; default $RTLAB_KERNEL_DIR or the "
                                                  "installation's)")):
    """Render a scene (primary rays, simple shading; with --shadows or --bounces Whitted ray tracing:
    shadows, reflection, refraction), print time and Mrays/s, write a PNG."""
    from ..backends import get_backend
    from ..device.rendering import render as do_render, save_png
    from ..device.tracing import default_variant
    image_file(out)                                   # before the work: a bad --out fails at once
    be = get_backend(backend, device)
    chosen = {"traversal": traversal, "intersection": isect, "block": block_shape(block) if block else None}
    variant = default_variant(be).with_(**{k: v for k, v in chosen.items() if v is not None})
    whitted = shadows is not None or bounces is not None
    if whitted:
        step, entries = whitted_kernels(variant, shadows or "one-pass", bounces or 0, schedule)
        use_kernels(kernels, variant if step else None, step, entries)
    else:
        warn_unused_options(materials, fresnel, compact, schedule)
        use_kernels(kernels, variant)
    sc = load_scene(scene, size)
    traversal_structure(sc, be, variant)
    if whitted:
        render_whitted_frame(sc, be, variant, shadows or "one-pass", bounces or 0, materials, fresnel, compact,
                             repeats, check, out, schedule)
        return
    with console.status(f"rendering {sc.name} {sc.camera.width}x{sc.camera.height}..."):
        result = do_render(sc, be, variant, repeats=repeats, warmup=1, write_hits=check)
    print_primary(sc, result, variant, check)
    save_png(result.image, out)                       # after the figures: they are never lost to a failed write
    console.print(f"wrote {out}")


def print_primary(sc, result, variant, check: bool) -> None:
    """A primary render's figures: time, Mrays/s and what the compiler gave the kernel; the error
    against the float64 reference with --check, else that it was not checked."""
    res = result.resources
    regs = f", {res['registers']} registers" if res.get("registers") else ""
    occ = f", occupancy {res['occupancy']:.0%}" if res.get("occupancy") else ""
    console.print(f"{sc.name} {sc.camera.width}x{sc.camera.height} on {result.backend} ({result.device}), "
                  f"{variant.label()}: {result.median_ms:.2f} ms (median of {len(result.kernel_ms)}), "
                  f"{result.mrays_per_s:.1f} Mrays/s{regs}{occ}; host {result.host_ms:.2f} ms per launch"
                  f"{'' if check else NOT_CHECKED}")
    if check:
        from ..reference.check import check_render
        with console.status("float64 reference..."):
            report = check_render(sc, result, sc.camera)
        console.print(f"error vs float64 reference: {report.summary()}")


def warn_unused_options(materials: str, fresnel: str, compact: bool, schedule: str) -> None:
    """One line naming the Whitted options a primary render (no --shadows, no --bounces) leaves unused."""
    given = [f"--{name} {value}" for name, value, default in (("materials", materials, "auto"),
             ("fresnel", fresnel, "schlick"), ("schedule", schedule, "tree")) if value != default]
    given += ["--compact"] if compact else []
    if given:
        console.print(escape(f"warning: {', '.join(given)} {'has' if len(given) == 1 else 'have'} no effect "
                             "without --shadows or --bounces (this is a primary render)"), highlight=False)


def whitted_kernels(variant, shadows: str, bounces: int, schedule: str) -> tuple:
    """(program, entry kernels) a Whitted render launches (rtlab.device.whitted and whitted_frames'
    runners), whose stubs the kernel-sources summary names as it does a primary render's; (None, ())
    where the variant has no Whitted kernels (render_whitted says why)."""
    from ..device.variants import program_for
    tree = bounces > 0 or schedule == "wavefront"
    try:
        program = program_for("bounces" if tree else "shadows", variant)
    except RtlabError:
        return None, ()
    if tree:     # the wavefront's kernels too: they exist under RT_WAVEFRONT alone, which the summary does not
        # set, and call the tree's traversal, shading and spawn functions (rt_wavefront.h)
        return program, ("trace_primary_tree", "trace_reflection", "trace_refraction", "shade_records", "pack_frame")
    return program, ("trace_primary_hits", "shade_hits") if shadows == "two-pass" else ("render_shadows",)


# Why many parameters: the render command's options, passed on.
def render_whitted_frame(scene, backend, variant, shadows: str, bounces: int, materials: str, fresnel: str,
                         compact: bool, repeats: int, check: bool, out: Path, schedule: str = "tree"):
    """`rtlab render --shadows/--bounces`: render with a material preset, print the figures, write the PNG."""
    from ..device.rendering import save_png
    from ..device.whitted import render_whitted
    from ..scene.materials import apply_materials
    scene = apply_materials(scene, materials)
    cam = scene.camera
    with console.status(f"rendering {scene.name} {cam.width}x{cam.height}, shadows {shadows}, {bounces} bounces..."):
        result = render_whitted(scene, backend, variant, shadows=shadows, bounces=bounces, compact=compact,
                                repeats=repeats, warmup=1, write_hits=check, fresnel=fresnel, schedule=schedule)
    kernels = ", ".join(f"{k} {ms:.2f} ms" + (f" ({result.resources[k]['registers']} regs)"
                                              if result.resources.get(k, {}).get("registers") else "")
                        for k, ms in result.kernel_ms().items())
    console.print(f"{scene.name} {cam.width}x{cam.height} on {result.backend} ({result.device}), materials "
                  f"{materials}, shadows {shadows}, {bounces} bounces (depth {result.depth}, {schedule}"
                  f"{', compacted' if result.compact else ''}): "
                  f"{result.median_ms:.2f} ms a frame ({result.fps:,.1f} fps), {len(result.launches)} launches, "
                  f"{result.rays_launched():,} rays; {kernels}{'' if check else NOT_CHECKED}")
    for block in (result.light_buffer or {}).get("lights", []):
        console.print(f"shadow rays through a light buffer: {block['resolution']}² cells a face, {block['mib']:.1f} MiB, "
                      f"built in {result.light_buffer['build_s']:.1f} s")
    if bounces > 0 and result.depth == 0:
        console.print(f"no material of {scene.name} reflects or transmits with materials {materials!r}, so no "
                      "secondary rays were traced; the paper's Fig. 6 materials: --materials paper")
    if check:
        from ..reference.whitted import reference_whitted, whitted_error
        with console.status("float64 Whitted reference..."):
            ref = reference_whitted(scene, cam, bounces=result.depth, shadows=shadows != "none", fresnel=fresnel)
        tree = result.tree if result.tree is not None else {"P": result.hits.tri}
        console.print(f"error vs float64 reference: {whitted_error(result.image, tree, ref).summary()}")
    save_png(result.image, out)
    console.print(f"wrote {out}")
    return result


def register(app: typer.Typer) -> None:
    app.command()(render)
