"""Memory placement (the paper's §3.1.1, lab step 01): where the tree, the triangles, the per-frame
constants and the ray live, each placement timed on the current device.

Rows: the plain global-memory variant (read-only loads through ``__ldg``; constants in constant
memory; the ray in registers), then one change at a time: the texture path for the seven scene
buffers, camera/lights/materials in global memory, the ray in shared memory (CUDA only, see
kernels/opencl/01_memory.cl), the ray as arrays indexed by the split axis (what 2008's compiler put in
local memory), and the paper's own choice (textures and a shared-memory ray). Every row gives the
median device time, Mrays/s, the device's registers and occupancy, nvcc's offline report for sm_90
(registers, stack bytes, spills, shared bytes, occupancy), and the error column: hits that differ
from the global variant's (must be 0: a placement moves data, never changes a result) beside the
global variant's error against the float64 reference.

:func:`compiler_report` is the "why": nvcc's report for each ray placement under register caps,
showing that an indexed ray costs local memory and that a ray in shared memory frees registers,
which is what mattered on 2008's register-starved GPUs (§3.1.1).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from ..device.kernels import Variant, build_defines, build_options, kernel_source
from ..scene.model import Scene
from .primary import BenchRow, bench_render, nvcc_render_report
from .tables import Table, fmt, report_markdown

# name -> (variant fields beyond the base, what it moves)
PLACEMENTS = {
    "global": ({}, "tree/triangles via __ldg global loads, constants in constant memory, ray in registers"),
    "texture": ({"node_memory": "texture"}, "tree, object list, vertices, normals through textures/images"),
    "const-global": ({"constants": "global"}, "camera, lights, materials in global instead of constant memory"),
    "ray-shared": ({"ray_memory": "shared"}, "ray origin/direction in shared memory (CUDA only)"),
    "ray-indexed": ({"ray_memory": "indexed"}, "ray vectors indexed by the split axis (2008: local memory)"),
    "paper": ({"node_memory": "texture", "ray_memory": "shared"}, "the paper's: textures + shared-memory ray"),
}
CUDA_ONLY = {"ray-shared", "paper"}
RAY_PLACEMENTS = ("registers", "shared", "indexed")
REPORT_CAPS = (0, 40, 32, 24)       # -maxrregcount of the compiler report; 0: none. ptxas's floor is 24


@dataclass
class MemoryRow:
    placement: str
    description: str
    bench: BenchRow
    nvcc: dict | None                   # offline nvcc report of render_primary (sm_90)
    diff: dict = field(default_factory=dict)   # hits/pixels differing from the global variant
    error_from: str = "own"             # "own": checked itself; "global": same hits as global, its error

    def as_dict(self) -> dict:
        d = asdict(self)
        return d


def placement_variant(name: str, base: Variant | None = None) -> Variant:
    return (base or Variant.paper()).with_(**PLACEMENTS[name][0])


def _hits(scene, backend, variant):
    from ..device.rendering import render
    return render(scene, backend, variant, write_hits=True, lab=True)


def hit_difference(result, base) -> dict:
    """How a render differs from the global variant's: triangle ids, t bits, pixels."""
    return {"tri": int(np.count_nonzero(result.hits.tri != base.hits.tri)),
            "t_bits": int(np.count_nonzero(result.hits.t.view(np.int32) != base.hits.t.view(np.int32))),
            "pixels": int(np.count_nonzero(np.any(result.image != base.image, axis=-1)))}


def bench_memory(scene: Scene, backend, placements=None, repeats: int = 25, check: bool = True,
                 view: str = "preset", base: Variant | None = None, progress=None) -> list[MemoryRow]:
    """Every placement on ``scene``'s camera on ``backend`` (CUDA-only ones skipped elsewhere)."""
    from ..device.device_scene import device_scene
    names = [n for n in (placements or PLACEMENTS) if backend.language == "cuda" or n not in CUDA_ONLY]
    base = base or Variant.paper()
    reference = _hits(scene, backend, base)
    rows: list[MemoryRow] = []
    global_error: dict = {}
    for name in names:
        variant = placement_variant(name, base)
        if progress is not None:
            progress(f"{scene.name}/{view} {name} on {backend.name}")
        own_check = check and name == "global"
        row = bench_render(scene, backend, variant, repeats=repeats, check=own_check, view=view)
        diff = hit_difference(_hits(scene, backend, variant), reference)
        error_from = "own"
        if name == "global":
            global_error = row.error
        elif check and diff["tri"] == 0 and diff["t_bits"] == 0 and global_error:
            row.error, error_from = dict(global_error), "global"
        elif check:
            from ..reference.check import check_render
            from ..device.rendering import render
            row.error = check_render(scene, render(scene, backend, variant, write_hits=True, lab=True), scene.camera).as_dict()
        features = device_scene(scene, backend).features(variant)
        rows.append(MemoryRow(name, PLACEMENTS[name][1], row, nvcc_render_report(variant, features), diff, error_from))
    return rows


def compiler_report(features=None, block: tuple[int, int] = (32, 4), caps=REPORT_CAPS) -> list[dict]:
    """nvcc's sm_90 report of lab step 01's render kernel for each ray placement and register cap:
    registers, stack (local) bytes, spill bytes, shared bytes, occupancy. Empty without nvcc."""
    from ..device.kernels import SceneFeatures
    from ..backends.nvcc import nvcc_available
    if not nvcc_available():
        return []
    features = features or SceneFeatures(stack_size=32)
    out = []
    for ray in RAY_PLACEMENTS:
        for cap in caps:
            v = Variant.paper(ray_memory=ray, max_registers=cap, block=block)
            # every ray placement through the same kernel file, so only the placement differs
            from ..backends.nvcc import nvcc_resources
            report = nvcc_resources(kernel_source("01_memory", "cuda"), build_defines(v, features),
                                    block_threads=block[0] * block[1], extra_options=build_options(v, "cuda"))
            r = report["render_primary"]
            row = {"ray": ray, "cap": cap, "registers": r.registers, "local_bytes": r.local_bytes,
                   "spill_bytes": r.spill_bytes, "shared_bytes": r.shared_bytes, "occupancy": r.occupancy}
            if not cap:
                row.update(ptx_memory_ops(kernel_source("01_memory", "cuda"), build_defines(v, features)))
            out.append(row)
    return out


def ptx_memory_ops(path, defines: dict, kernel: str = "render_primary", arch: str = "sm_90") -> dict:
    """Local- and shared-memory loads/stores in the kernel's PTX (before register allocation, so
    spills are not among them): where the ray's components are read from."""
    import re
    from ..backends.nvcc import nvcc_ptx
    text = nvcc_ptx(path, defines, arch)
    m = re.search(rf"\.entry {kernel}\b.*?\n}}", text, re.S)
    body = m.group(0) if m else ""
    return {op.replace(".", "_"): len(re.findall(rf"\b{re.escape(op)}\b", body))
            for op in ("ld.local", "st.local", "ld.shared", "st.shared")}


def diff_text(r: MemoryRow) -> str:
    d = r.diff
    return "0 (identical)" if d and not any(d.values()) else f"{d['tri']} ids, {d['t_bits']} t, {d['pixels']} px"


COLUMNS = ("scene", "backend", "placement", "median ms", "Mrays/s", "vs global", "regs", "occupancy",
           "nvcc regs / stack B / spills B / shared B / occ.", "differs from global", "error vs float64 reference",
           "moves")


def table_rows(rows: list[MemoryRow]) -> list[tuple[str, ...]]:
    """Cells under COLUMNS; speed against the global variant of the same scene and backend."""
    base_ms = {(r.bench.scene, r.bench.backend): r.bench.median_ms for r in rows if r.placement == "global"}
    out = []
    for r in rows:
        b, n = r.bench, r.nvcc
        g = base_ms.get((b.scene, b.backend))
        nv = (f"{n['registers']} / {n['local_bytes']} / {n['spill_bytes']} / {n['shared_bytes']} / "
              f"{n['occupancy']:.0%}" if n else "-")
        err = b.error_text() + (" (= global: same hits)" if r.error_from == "global" else "")
        out.append((b.scene, b.backend, r.placement, f"{b.median_ms:.3f}", f"{b.mrays:,.1f}",
                    f"{g / b.median_ms:.2f}×" if g else "-", fmt(b.registers or None, "d"), fmt(b.occupancy, ".0%"),
                    nv, diff_text(r), err, r.description))
    return out


REPORT_COLUMNS = ("ray", "cap", "registers", "stack (local) B", "spill stores+loads B", "shared B", "occupancy",
                  "PTX ld/st.local", "PTX ld/st.shared")


def report_table(report: list[dict]) -> Table:
    """:func:`compiler_report` as a table."""
    cells = []
    for r in report:
        loc = f"{r['ld_local']}/{r['st_local']}" if "ld_local" in r else "-"
        sh = f"{r['ld_shared']}/{r['st_shared']}" if "ld_shared" in r else "-"
        cells.append((r["ray"], str(r["cap"] or "none"), str(r["registers"]), str(r["local_bytes"]),
                      str(r["spill_bytes"]), str(r["shared_bytes"]), f"{r['occupancy']:.0%}", loc, sh))
    return Table(REPORT_COLUMNS, cells,
                 note="nvcc's report for `render_primary` of lab step 01 (sm_90, block 32x4), per ray placement and "
                      "register cap (-maxrregcount; ptxas will not go below 24); uncapped rows also count the PTX's "
                      "local and shared loads/stores (the kd stack is 3+3 local ones; an indexed ray adds local ones, "
                      "a shared ray turns its reads into shared loads):")


def memory_tables(rows: list[MemoryRow], report: list[dict] | None = None) -> list[Table]:
    """The placements; with nvcc, its report of the ray placements under register caps."""
    return [Table(COLUMNS, table_rows(rows), "memory placement (§3.1.1)")] + ([report_table(report)] if report else [])


def memory_markdown(rows: list[MemoryRow], command: str, report: list[dict] | None = None) -> str:
    return report_markdown("Memory placement (§3.1.1, lab step 01)", command,
                           [f"{r.bench.backend}: {r.bench.device}" for r in rows], memory_tables(rows, report))
