"""The paper's Table 3: the triangle tests on their own, then inside the renderer.

Table 3 times "pure triangle intersection test on 1000 triangles": every pixel's camera ray is
tested against the first 1000 triangles of the scene in a for-loop (§4.2), no acceleration
structure. Lab step 02 (kernels/cuda/02_intersect.cu, kernels/opencl/02_intersect.cl) is that
kernel; RT_ISECT picks the test. Beside each time: the compiler's registers (the paper's
"Reg. usage" row; offline from nvcc for CUDA), the bytes each test reads per triangle, and the
error against the float64 reference over the same 1000 triangles. The in-render effect is the full
renderer (kd-tree, simple shading) with each test: Mrays/s and its error, via
rtlab.benches.primary.bench_render.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..device.kernels import SceneFeatures, Variant, build_defines, kernel_source, load_program
from ..device.layout import HIT_DTYPE
from ..device.variants import LAB_PROGRAMS
from ..scene.model import Camera, Scene
from .paper_figures import PAPER_TABLE3_MS, PAPER_TABLE3_REGISTERS
from .tables import Table, fmt, report_markdown

INTERSECT_STEP = LAB_PROGRAMS["loop"]
TABLE3_TRIANGLES = 1000


@dataclass
class LoopResult:
    """One Table 3 measurement: hits of every pixel's ray over triangles [0, n_tris)."""
    scene: str
    isect: str
    n_tris: int
    camera: Camera
    kernel_ms: list[float]
    tri: np.ndarray
    t: np.ndarray
    resources: dict = field(default_factory=dict)
    backend: str = ""
    device: str = ""

    @property
    def median_ms(self) -> float:
        return float(np.median(self.kernel_ms))

    @property
    def mtests_per_s(self) -> float:
        """Million ray/triangle tests per second."""
        n = self.camera.width * self.camera.height * self.n_tris
        return n / (self.median_ms * 1e-3) / 1e6


def intersect_loop(scene: Scene, backend, isect: str = "moller", n_tris: int = TABLE3_TRIANGLES,
                   camera: Camera | None = None, repeats: int = 1, warmup: int = 0, **defines) -> LoopResult:
    """Run lab step 02: each pixel's camera ray against the first ``n_tris`` triangles with test
    ``isect``; the median of ``repeats`` timed launches after ``warmup`` untimed ones."""
    from ..device.tracing import unpack_hits
    from ..device.device_scene import device_scene
    camera = camera or scene.camera
    n_tris = int(min(n_tris, scene.n_triangles))
    variant = Variant.paper(intersection=isect)
    ds = device_scene(scene, backend)
    program = load_program(backend, INTERSECT_STEP, variant, ds.features(variant), **defines)
    ds.set_constants(program, camera, variant)
    n = camera.width * camera.height
    hits = backend.empty(n * HIT_DTYPE.itemsize)
    args = ds.scene_args(variant) + [hits, np.int32(n_tris)]
    launch = lambda: program.launch("intersect_triangles", (camera.width, camera.height), variant.block, args,
                                    constants=("frame",))
    for _ in range(warmup):
        launch()
    times = [launch() for _ in range(max(1, repeats))]
    t, tri, _, _ = unpack_hits(backend.to_host(hits, np.float32, 4 * n))
    return LoopResult(scene.name, isect, n_tris, camera, times, tri, t,
                      program.resources("intersect_triangles", variant.block).as_dict(),
                      backend.name, backend.device_name)


def check_loop(scene: Scene, result: LoopResult):
    """The loop's hits against the float64 reference over the same triangles (HitComparison)."""
    from ..reference import compare_hits, reference_trace
    from ..scene.model import camera_rays
    o, d = camera_rays(result.camera)
    faces = scene.faces[:result.n_tris]
    ref = reference_trace(scene.vertices, faces, o, d)
    return compare_hits(ref, result.tri, result.t, scene.vertices, faces, o, d)


def nvcc_registers(isect: str, features: SceneFeatures | None = None) -> dict | None:
    """Offline CUDA report of the Table 3 kernel for ``isect`` (registers, stack, spills), or None
    without nvcc."""
    from ..backends.nvcc import nvcc_available, nvcc_resources
    if not nvcc_available():
        return None
    defines = build_defines(Variant.paper(intersection=isect), features or SceneFeatures())
    report = nvcc_resources(kernel_source(INTERSECT_STEP, "cuda"), defines)
    r = report.get("intersect_triangles")
    return None if r is None else {"registers": r.registers, "local_bytes": r.local_bytes,
                                   "spill_bytes": r.spill_bytes, "occupancy": r.occupancy}


@dataclass
class Table3Row:
    scene: str
    isect: str
    backend: str
    device: str
    size: int
    n_tris: int
    median_ms: float
    mtests: float
    nvcc: dict | None
    bytes_read: int
    bytes_precomputed: int
    error: dict
    render: object | None = None       # rtlab.benches.primary.BenchRow with this test in the renderer

    def error_text(self) -> str:
        e = self.error
        return f"{e['mismatches']} mism., {e['ties']} ties, max rel dt {e['t_rel_err_max']:.1e}"


# Why many parameters: the table's knobs, passed through from its `rtlab bench` command.
def bench_table3(scene: Scene, backend, isects, size: int, n_tris: int = TABLE3_TRIANGLES, repeats: int = 5,
                 render_size: int | None = None, render_repeats: int = 5, check: bool = True) -> list[Table3Row]:
    """Table 3 rows for one scene on one backend; with ``render_size`` also the in-render effect."""
    from ..accel.tri_data import tri_bytes_read, tri_data_bytes
    from .primary import bench_render
    rows = []
    camera = scene.camera.with_size(size)
    render_scene = None
    if render_size:
        render_scene = scene if scene.camera.width == render_size else \
            replace(scene, camera=scene.camera.with_size(render_size))
    for isect in isects:
        loop = intersect_loop(scene, backend, isect, n_tris, camera, repeats=repeats, warmup=1)
        if check:
            c = check_loop(scene, loop)
            error = {"mismatches": c.n_mismatch, "ties": c.n_ties, "t_rel_err_max": c.t_rel_err_max,
                     "hits": c.n_hits_ref}
        else:
            error = {"mismatches": -1, "ties": -1, "t_rel_err_max": float("nan"), "hits": -1}
        row = Table3Row(scene.name, isect, backend.name, backend.device_name, size, loop.n_tris, loop.median_ms,
                        loop.mtests_per_s, nvcc_registers(isect), tri_bytes_read(isect), tri_data_bytes(isect),
                        error)
        if render_scene is not None:
            row.render = bench_render(render_scene, backend, Variant.paper(intersection=isect), repeats=render_repeats,
                                      check=check)
        rows.append(row)
    return rows


COLUMNS = ("scene", "test", "backend", "rays", "loop ms", "Mtests/s", "paper ms", "nvcc regs", "paper regs",
           "B/tri read", "B/tri extra", "loop error", "render Mrays/s", "render error")


def table_rows(rows: list[Table3Row]) -> list[tuple[str, ...]]:
    """Cells under COLUMNS: the loop beside the paper's figures, then the test in the renderer."""
    out = []
    for r in rows:
        rend = r.render
        out.append((r.scene, r.isect, r.backend, f"{r.size}²", f"{r.median_ms:.2f}", f"{r.mtests:,.0f}",
                    fmt(PAPER_TABLE3_MS.get(r.scene, {}).get(r.isect), ""), fmt(r.nvcc and r.nvcc["registers"], "d"),
                    fmt(PAPER_TABLE3_REGISTERS.get(r.isect), "d"), str(r.bytes_read), str(r.bytes_precomputed),
                    r.error_text(), f"{rend.mrays:,.1f}" if rend else "-", rend.error_text() if rend else "-"))
    return out


def table3_tables(rows: list[Table3Row]) -> list[Table]:
    n_tris = rows[0].n_tris if rows else TABLE3_TRIANGLES
    return [Table(COLUMNS, table_rows(rows), f"Table 3: first {n_tris} triangles")]


def table3_markdown(rows: list[Table3Row], command: str) -> str:
    """Markdown for docs/results/ (the paper's tables): the command, then Table 3 with the in-render columns."""
    return report_markdown(f"Table 3: triangle tests, first {rows[0].n_tris if rows else TABLE3_TRIANGLES} triangles",
                           command, [f"{r.backend}: {r.device}" for r in rows], table3_tables(rows))
