"""rtlab on a CPU against Embree, measured live in the same run (``rtlab bench cpu``).

The same rays (rtlab.benches.rays: a benchmark view's camera, or a preset's own camera for a bare
preset name such as "default") are traced by rtlab.trace on the OpenCL CPU device (PoCL, all its
threads unless told otherwise) and by Embree through embreex (``rtcIntersect1`` in a loop on the
calling thread: one core). The two are timed in turns, round after round, so that both see the same
machine load, and each answer is checked against the float64 reference on the same subsample.

rtlab's time is the kernel's device time (OpenCL profiling events, as every rtlab figure);
Embree's is the wall time of ``EmbreeScene.run``, which includes embreex's loop over the rays.
On a machine shared with other work the wall-clock ratio depends on how many cores the two got, so
each side's CPU time is measured too: the process's CPU time minus the calling thread's during a
trace (PoCL's worker threads: the kernel) and the calling thread's during Embree's run. Mrays per
CPU-second is throughput per core, whatever the load.

    rows = bench_cpu_variants(make_rays("bunny/fill", "diffuse", 1024), backend,
                              [default_variant(backend), Variant("bvh-wide", "watertight")])

Several variants are timed in the same rounds as one Embree run each round (every row of a batch
shares Embree's figures), the library's default (rtlab.device.tracing.default_variant) marked.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np

from ..device.kernels import Variant
from ..errors import RtlabError
from .tables import Table, report_markdown

EMBREE_HINT = "Embree is not installed: `pip install 'rtlab[bench]'` (or `pip install embreex`)"
DEFAULT_VIEWS = "bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside,default"
# What `rtlab bench cpu` times beside Embree: the library's default, then the packet traversal with
# the paper's test, the wide single-ray traversal alone, and the kd stack traversal (the CPU default
# before the packet traversal was)
DEFAULT_VARIANTS = "default,bvh-packet/moller,bvh-wide,stack"


def embree_version() -> str:
    try:
        from importlib.metadata import version
        return f"embreex {version('embreex')}"
    except Exception:
        return "embreex"


class EmbreeTracer:
    """Closest hits through Embree (embreex): one triangle mesh, one thread."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        try:
            from embreex import mesh_construction, rtcore_scene
        except ImportError:
            raise RtlabError(EMBREE_HINT) from None
        self._scene = rtcore_scene.EmbreeScene()
        mesh_construction.TriangleMesh(self._scene, np.ascontiguousarray(vertices, np.float32),
                                       np.ascontiguousarray(faces, np.int32))
        self._scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))   # commits (builds) the BVH

    def trace(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
        """(triangle id or -1, t, wall seconds, CPU seconds) of each ray's closest hit in (0, inf)."""
        o = np.ascontiguousarray(origins, np.float32)
        d = np.ascontiguousarray(directions, np.float32)
        c0, t0 = thread_cpu_seconds(), time.perf_counter()
        out = self._scene.run(o, d, output=1)
        seconds, cpu = time.perf_counter() - t0, thread_cpu_seconds() - c0
        tri = np.where(out["geomID"] >= 0, out["primID"], -1).astype(np.int32)
        t = np.where(tri >= 0, out["tfar"], np.inf).astype(np.float32)
        return tri, t, seconds, cpu


def thread_cpu_seconds() -> float:
    """CPU time of the calling thread."""
    return time.thread_time()


def process_cpu_seconds() -> float:
    """CPU time of every thread of this process (PoCL's workers included)."""
    return time.process_time()


@dataclass
class CpuRow:
    view: str
    size: int
    rays: int
    variant: str
    device: str
    threads: int                     # the OpenCL device's compute units (PoCL: its worker threads)
    rtlab_ms: list[float]            # kernel time of each round
    embree_ms: list[float]           # Embree's wall time of each round
    rtlab_cpu_ms: list[float]        # CPU time of PoCL's threads in each round's trace
    embree_cpu_ms: list[float]       # CPU time of Embree's (the calling) thread in each round
    rtlab_error: dict = field(default_factory=dict)
    embree_error: dict = field(default_factory=dict)
    load: float = 0.0                # 1-minute load average when the view was done
    kind: str = "primary"            # the rays: "primary" or "diffuse" (rtlab.benches.rays)

    @property
    def rtlab_mrays(self) -> float:
        return self.rays / (float(np.median(self.rtlab_ms)) * 1e3)

    @property
    def embree_mrays(self) -> float:
        return self.rays / (float(np.median(self.embree_ms)) * 1e3)

    @property
    def ratio(self) -> float:
        """rtlab's throughput over Embree's (medians of the rounds)."""
        return self.rtlab_mrays / self.embree_mrays

    @property
    def rtlab_mrays_cpu(self) -> float:
        """Mrays per CPU-second of PoCL's threads: per core, whatever the machine's load."""
        return self.rays / (float(np.median(self.rtlab_cpu_ms)) * 1e3)

    @property
    def embree_mrays_cpu(self) -> float:
        return self.rays / (float(np.median(self.embree_cpu_ms)) * 1e3)

    @property
    def ratio_per_core(self) -> float:
        return self.rtlab_mrays_cpu / self.embree_mrays_cpu


def error_text(e: dict) -> str:
    """"mismatches (ties) / checked rays, largest relative t error"."""
    if not e:
        return "-"
    return f"{e['mismatches']} ({e['ties']}) / {e['rays']:,}, dt {e['t_rel_err_max']:.0e}"


def bench_cpu(batch, backend, variant: Variant | None = None, rounds: int = 7, embree: EmbreeTracer | None = None,
              progress=None) -> CpuRow:
    """One variant (None: the library's default) against Embree: bench_cpu_variants' row."""
    from ..device.tracing import default_variant
    return bench_cpu_variants(batch, backend, [variant or default_variant(backend)], rounds, embree, progress)[0]


def bench_cpu_variants(batch, backend, variants: list[Variant], rounds: int = 7, embree: EmbreeTracer | None = None,
                       progress=None) -> list[CpuRow]:
    """Trace ``batch`` (a rtlab.benches.rays.RayBatch) with rtlab on ``backend`` in each variant and
    with Embree, in turns, ``rounds`` times after one untimed round each: a row per variant with
    the medians, the ratio to Embree's run of the same rounds and both errors."""
    from ..device.tracing import default_variant, resolve_variant, trace
    variants = [resolve_variant(v, backend) for v in variants]
    if rounds < 1:
        raise RtlabError(f"rounds must be at least 1, got {rounds}")
    if not variants:
        raise RtlabError("bench_cpu_variants needs at least one variant")
    embree = embree or EmbreeTracer(batch.scene.vertices, batch.scene.faces)
    results = [trace(batch.scene, batch.origins, batch.directions, backend, v) for v in variants]  # compiles, uploads
    e_tri, e_t, _, _ = embree.trace(batch.origins, batch.directions)
    rtlab_ms = [[] for _ in variants]
    rtlab_cpu = [[] for _ in variants]
    embree_ms, embree_cpu = [], []
    for i in range(rounds):
        if progress:
            progress(i)
        for k, v in enumerate(variants):
            p0, c0 = process_cpu_seconds(), thread_cpu_seconds()
            results[k] = trace(batch.scene, batch.origins, batch.directions, backend, v)
            rtlab_cpu[k].append(((process_cpu_seconds() - p0) - (thread_cpu_seconds() - c0)) * 1e3)
            rtlab_ms[k].append(results[k].kernel_ms)
        e_tri, e_t, seconds, cpu = embree.trace(batch.origins, batch.directions)
        embree_ms.append(seconds * 1e3)
        embree_cpu.append(cpu * 1e3)
    threads = int(getattr(getattr(backend, "device", None), "max_compute_units", 1) or 1)
    default = default_variant(backend)
    embree_error = batch.error(e_tri, e_t)
    return [CpuRow(batch.view, batch.size, batch.n, _variant_name(v, default), backend.device_name, threads, rtlab_ms[k],
                   embree_ms, rtlab_cpu[k], embree_cpu, batch.error(results[k].tri, results[k].t), embree_error,
                   os.getloadavg()[0], kind=batch.kind)
            for k, v in enumerate(variants)]


def _variant_name(variant: Variant, default: Variant) -> str:
    """traversal/test, with " (default)" for the library's default variant."""
    name = f"{variant.traversal}/{variant.intersection}"
    return name + " (default)" if variant == default else name


COLUMNS = ("view", "kind", "rays", "rtlab variant", "threads", "rtlab Mrays/s", "Embree Mrays/s", "ratio",
           "rtlab Mrays/CPU-s", "Embree Mrays/CPU-s", "per core", "rtlab error", "Embree error", "load")


def table_rows(rows: list[CpuRow]) -> list[tuple[str, ...]]:
    """Cells under COLUMNS. Errors: mismatches (ties) among the checked rays, largest relative t error."""
    return [(r.view, r.kind, f"{r.size}²" if r.kind == "primary" else f"{r.rays:,}", r.variant, str(r.threads),
             f"{r.rtlab_mrays:.2f}",
             f"{r.embree_mrays:.2f}", f"{r.ratio:.2f}×", f"{r.rtlab_mrays_cpu:.2f}", f"{r.embree_mrays_cpu:.2f}",
             f"{r.ratio_per_core:.2f}×", error_text(r.rtlab_error), error_text(r.embree_error), f"{r.load:.1f}")
            for r in rows]


def cpu_tables(rows: list[CpuRow], title: str = "rtlab on the CPU against Embree (one thread), same rays") -> list[Table]:
    return [Table(COLUMNS, table_rows(rows), title)]


def cpu_markdown(rows: list[CpuRow], command: str, rounds: int) -> str:
    intro = (f"{os.cpu_count()} cores; rtlab: OpenCL, variants traversal/test (the library's default marked); Embree: "
             f"{embree_version()}, one thread, run once a round after rtlab's variants; medians of {rounds} "
             "alternating rounds; rays: the view's size² primary rays, or the number of its diffuse rays (one a hit "
             "pixel, ../shared/bench/README.md); ratio = rtlab / Embree in "
             "Mrays/s (wall clock: rtlab's kernel time with all its threads, Embree's one thread); per core = the "
             "same in Mrays per CPU-second (PoCL's threads' CPU time, Embree's thread's), which the machine's load "
             "does not change; errors: mismatches (ties) among the rays checked against the float64 reference, "
             "largest relative t error; load: 1-minute load average")
    return report_markdown("rtlab on the CPU against Embree, same rays, same run", command,
                           [r.device for r in rows], cpu_tables(rows), intro)
