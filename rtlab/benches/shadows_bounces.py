"""The paper's Table 5 (shadows one-pass vs two-pass; 1-, 2-, 3-bounce reflection/refraction) and
the scene-specialised vs general kernels, on the current device.

Every row gives frames per second of the whole frame (the device time of all its launches, median
of ``repeats`` frames), the registers and occupancy of each kernel (the CUDA backend's own report;
elsewhere nvcc's offline report for sm_90 when nvcc is installed), and the error against the float64
Whitted reference (rtlab.reference.whitted) at a smaller size (the reference is numpy). The paper's
figures (GeForce 8800 GTS, 1024x1024) stand beside them.

Shadow rows render the scene's materials as loaded ("file": the paper's Table 5 shadow columns
have no secondary rays). Bounce rows use the Fig. 6 material overrides ("paper", see
rtlab.scene.materials) with one-pass shadows in every tree node, measured without and with the
compaction of live rays between levels (beyond the paper), to show whether compaction pays, and
with the wavefront schedule (beyond the paper: one launch per level over a queue of all its rays,
rtlab.device.whitted), whose image may differ from the tree's by one 8-bit step (order of additions).
Specialised-vs-general rows render the scenes' own materials ("file"): with the Fig. 6 overrides
every scene has lights, mirrors and glass, and the two kernels would be one.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..device.kernels import Variant, kernel_source
from ..device.whitted import WhittedResult, render_whitted
from ..device.whitted_frames import PACK_KERNELS
from ..scene.materials import apply_materials
from ..scene.model import Scene
from .paper_figures import PAPER_BOUNCE_FPS, PAPER_SHADOW_FPS, PAPER_TABLE5_OCCUPANCY, PAPER_TABLE5_REGISTERS
from .tables import Table, fmt, report_markdown

# nvcc's offline report per (step, defines, block): one compile serves every frame of a kernel
_NVCC_CACHE: dict = {}


def kernel_resources(backend, result: WhittedResult) -> dict[str, dict]:
    """kernel -> {registers, occupancy, local_bytes, source} for the kernels a render launched."""
    threads = int(np.prod(result.variant.block))
    out = {}
    if backend.name != "cuda":
        from ..backends.nvcc import nvcc_available, nvcc_resources
        if nvcc_available():
            key = (result.step, tuple(sorted(result.defines.items())), threads)
            if key not in _NVCC_CACHE:
                _NVCC_CACHE[key] = nvcc_resources(kernel_source(result.step, "cuda"), result.defines,
                                                  block_threads=threads)
            for name in result.resources:
                r = _NVCC_CACHE[key].get(name)
                if r is not None:
                    out[name] = {"registers": r.registers, "occupancy": r.occupancy, "local_bytes": r.local_bytes,
                                 "source": "nvcc sm_90"}
            return out
    for name, r in result.resources.items():
        out[name] = {"registers": r.get("registers"), "occupancy": r.get("occupancy"),
                     "local_bytes": r.get("local_bytes"), "source": backend.name}
    return out


@dataclass
class ShadingRow:
    table: str                       # "shadows", "bounces" or "specialised"
    scene: str
    mode: str                        # one-pass / two-pass / "3 bounces" / "general" ...
    backend: str
    device: str
    size: int
    median_ms: float
    fps: float
    paper_fps: float | None
    kernels: dict                    # kernel -> resources (kernel_resources)
    launches: int
    rays: int
    error: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)

    def regs_text(self) -> str:
        return "/".join(str(k["registers"]) if k.get("registers") is not None else "-"
                        for name, k in self.kernels.items() if name not in PACK_KERNELS)

    def occupancy_text(self) -> str:
        return "/".join(f"{k['occupancy']:.0%}" if k.get("occupancy") is not None else "-"
                        for name, k in self.kernels.items() if name not in PACK_KERNELS)

    def error_text(self) -> str:
        e = self.error
        if not e:
            return "-"
        psnr = "inf" if np.isinf(e["psnr"]) else f"{e['psnr']:.1f} dB"
        return (f"PSNR {psnr}, tree {e['tree_pixels']}/{e['pixels']} px, same tree max "
                f"{e['color_max_same_tree']}/255 p99 {e['color_p99_same_tree']:.0f}/255")


def _check(scene: Scene, backend, variant, check_size: int, **kw) -> dict:
    """Error of a render at ``check_size`` against the float64 Whitted reference."""
    if not check_size:
        return {}
    from ..reference.whitted import reference_whitted, whitted_error
    result = render_whitted(scene, backend, variant, lab=True, size=check_size, write_hits=True, **kw)
    ref = reference_whitted(scene, scene.camera.with_size(check_size), bounces=result.depth,
                            shadows=kw.get("shadows", "one-pass") != "none", fresnel=kw.get("fresnel", "schlick"))
    tree = result.tree if result.tree is not None else {"P": result.hits.tri}
    err = whitted_error(result.image, tree, ref).as_dict()
    err["size"] = check_size
    return err


def _row(table, scene, mode, backend, result: WhittedResult, paper, error) -> ShadingRow:
    return ShadingRow(table, scene.name, mode, backend.name, backend.device_name, result.image.shape[1],
                      result.median_ms, result.fps, paper,
                      kernel_resources(backend, result), len(result.launches), result.rays_launched(), error)


def bench_shadows(scene: Scene, backend, mode: str, size: int, repeats: int = 10, check_size: int = 128,
                  variant: Variant | None = None, materials: str = "file") -> ShadingRow:
    """Table 5, shadow columns: one-pass or two-pass shadows, no secondary rays."""
    variant = variant or Variant.paper()
    scene = apply_materials(scene, materials)   # a copy; the upload is shared (by content)
    result = render_whitted(scene, backend, variant, lab=True, size=size, shadows=mode, repeats=repeats, warmup=2)
    error = _check(scene, backend, variant, check_size, shadows=mode)
    return _row("shadows", scene, mode, backend, result, PAPER_SHADOW_FPS.get(scene.name, {}).get(mode), error)


# Why many parameters: the table's knobs, passed through from its `rtlab bench` command.
def bench_bounces(scene: Scene, backend, bounces: int, size: int, repeats: int = 10, check_size: int = 128,
                  variant: Variant | None = None, materials: str = "paper", shadows: str = "one-pass") -> ShadingRow:
    """Table 5, bounce columns: the kernel tree at ``bounces``, without and with compaction, and the
    wavefront schedule."""
    variant = variant or Variant.paper()
    scene = apply_materials(scene, materials)
    plain = render_whitted(scene, backend, variant, lab=True, size=size, shadows=shadows, bounces=bounces, repeats=repeats,
                           warmup=2)
    compact = render_whitted(scene, backend, variant, lab=True, size=size, shadows=shadows, bounces=bounces, compact=True,
                             repeats=repeats, warmup=2)
    wave = (render_whitted(scene, backend, variant, lab=True, size=size, shadows=shadows, bounces=bounces, repeats=repeats,
                           warmup=2, schedule="wavefront") if shadows != "two-pass" else None)
    error = _check(scene, backend, variant, check_size, shadows=shadows, bounces=bounces)
    row = _row("bounces", scene, f"{bounces} bounce{'s' if bounces > 1 else ''}", backend, plain,
               PAPER_BOUNCE_FPS.get(scene.name, {}).get(bounces), error)
    row.extra.update(compact_ms=compact.median_ms, compact_fps=compact.fps, compact_launches=len(compact.launches),
                     compact_rays=compact.rays_launched(), same_image=bool(np.array_equal(plain.image, compact.image)),
                     depth=plain.depth)
    if wave is not None:
        row.extra.update(wave_ms=wave.median_ms, wave_fps=wave.fps, wave_launches=len(wave.launches),
                         wave_rays=wave.rays_launched(),
                         wave_max_diff=int(np.abs(wave.image.astype(int) - plain.image).max()))
    return row


def bench_specialisation(scene: Scene, backend, bounces: int, size: int, repeats: int = 10,
                         variant: Variant | None = None, materials: str = "file",
                         shadows: str = "one-pass") -> list[ShadingRow]:
    """The scene-specialised kernel and the general one: registers, time, and whether the images agree."""
    variant = variant or Variant.paper()
    scene = apply_materials(scene, materials)
    rows = []
    results = {}
    for specialise in (True, False):
        result = render_whitted(scene, backend, variant, lab=True, size=size, shadows=shadows, bounces=bounces,
                                repeats=repeats, warmup=2, specialise=specialise)
        results[specialise] = result
        row = _row("specialised", scene, "specialised" if specialise else "general", backend, result, None, {})
        row.extra.update(depth=result.depth, defines={k: result.defines[k] for k in
                                                      ("RT_LIGHTS", "RT_SHADOWS", "RT_REFLECTION", "RT_REFRACTION",
                                                       "RT_MAX_DEPTH")})
        rows.append(row)
    same = np.array_equal(results[True].image, results[False].image)
    diff = int(np.abs(results[True].image.astype(int) - results[False].image).max())
    for row in rows:
        row.extra.update(same_image=bool(same), max_diff=diff)
    return rows


SHADOW_COLUMNS = ("scene", "backend", "shadows", "size", "ms", "fps", "paper fps", "regs", "paper regs", "occupancy",
                  "paper occ.", "error vs float64")
BOUNCE_COLUMNS = ("scene", "backend", "bounces", "size", "ms", "fps", "paper fps", "compacted fps", "wavefront fps",
                  "launches (compacted, wavefront)", "rays (compacted, wavefront)", "regs", "occupancy",
                  "error vs float64")
SPECIAL_COLUMNS = ("scene", "backend", "kernel", "size", "depth", "ms", "fps", "regs", "occupancy", "defines", "image")


def shadow_rows(rows: list[ShadingRow]) -> list[tuple[str, ...]]:
    return [(r.scene, r.backend, r.mode, f"{r.size}²", f"{r.median_ms:.3f}", f"{r.fps:,.1f}", fmt(r.paper_fps, ""),
             r.regs_text(), PAPER_TABLE5_REGISTERS[r.mode], r.occupancy_text(), PAPER_TABLE5_OCCUPANCY[r.mode],
             r.error_text()) for r in rows if r.table == "shadows"]


def bounce_rows(rows: list[ShadingRow]) -> list[tuple[str, ...]]:
    out = []
    for r in (r for r in rows if r.table == "bounces"):
        e = r.extra
        wave = (f"{e['wave_fps']:,.1f} (image ±{e['wave_max_diff']})", f", {e['wave_launches']}",
                f", {e['wave_rays']:,}") if "wave_fps" in e else ("-", "", "")
        compact = f"{e['compact_fps']:,.1f}" + ("" if e["same_image"] else " (image differs!)")
        out.append((r.scene, r.backend, r.mode, f"{r.size}²", f"{r.median_ms:.3f}", f"{r.fps:,.1f}",
                    fmt(r.paper_fps, ""), compact, wave[0], f"{r.launches} ({e['compact_launches']}{wave[1]})",
                    f"{r.rays:,} ({e['compact_rays']:,}{wave[2]})", r.regs_text(), r.occupancy_text(), r.error_text()))
    return out


def special_rows(rows: list[ShadingRow]) -> list[tuple[str, ...]]:
    out = []
    for r in (r for r in rows if r.table == "specialised"):
        flags = " ".join(f"{k[3:].lower()}={v}" for k, v in r.extra["defines"].items())
        image = "same" if r.extra["same_image"] else f"DIFFERENT (max diff {r.extra['max_diff']})"
        out.append((r.scene, r.backend, r.mode, f"{r.size}²", str(r.extra["depth"]), f"{r.median_ms:.3f}",
                    f"{r.fps:,.1f}", r.regs_text(), r.occupancy_text(), flags, image))
    return out


def table5_tables(rows: list[ShadingRow]) -> list[Table]:
    """The tables that have rows: shadows, bounces (the kernel tree, compacted, wavefront), and the
    scene-specialised kernels against the general ones."""
    tables = [Table(SHADOW_COLUMNS, shadow_rows(rows), "Table 5: shadows"),
              Table(BOUNCE_COLUMNS, bounce_rows(rows), "Table 5: reflection/refraction kernel tree"),
              Table(SPECIAL_COLUMNS, special_rows(rows), "scene-specialised vs general kernels, scene materials")]
    return [t for t in tables if t.rows]


NOTE = ("Registers and occupancy per kernel in launch order (shadows: render_shadows, or "
        "trace_primary_hits/shade_hits; tree: trace_primary_tree/trace_reflection/trace_refraction). "
        "Wavefront: one launch per level (rtlab.device.whitted, beyond the paper); ±N: its image's largest "
        "8-bit difference from the tree's.")


def table5_markdown(rows: list[ShadingRow], command: str) -> str:
    """Markdown for a fragment of docs/results/: command, devices, date, then the tables."""
    return report_markdown("Table 5: shadows and secondary rays", command,
                           [f"{r.backend}: {r.device}" for r in rows], table5_tables(rows)) + "\n" + NOTE + "\n"
