"""Two of the benchmark's peers timed on this machine's GPU in the same run as trace(): NVIDIA Warp's
``mesh_query_ray`` (its SAH BVH) and OptiX through Mitsuba 3 (``cuda_ad_rgb``,
``Scene.ray_intersect_preliminary``: the closest hit's t and triangle, what trace() returns), at the
versions of ../shared/bench/README.md (Warp 1.19.0, Mitsuba 3.9.1), on the benchmark views' rays
(rtlab.benches.rays.make_rays: the same rays, in row order for the peers, as the README has them).

Why: the README's peer figures were taken on an H100, and the lent machine is an H200. Two of the three
peers can be installed there (wheels carried; tinybvh, the best peer, cannot), so their figures on this
GPU say how far the README's figures move between the two machines, and trace()'s ratio to each of them
becomes a same-run ratio. The lent machine reaches no registry: the wheels (warp-lang 1.19.0, mitsuba
3.9.1, drjit 1.5.0; Warp's alone is 149 MB, over a call's 64 MiB) travel in parts over back-to-back calls
into /tmp there, then ``PYTHONPATH`` takes them; a CPU try runs with ``--device cpu --mitsuba-variant
llvm_ad_rgb --peers warp,optix``.

    python experiments/peers_same_run.py --md peers.md [--rows dragon/fill:diffuse:1024,...] \
        [--peers rtlab,warp,optix,warp-idle] [--rounds 3] [--repeats 22] [--warmup 3]

Timing, as the README's "kernel time only, median of 22 launches after warm-up":
- rtlab: ``bench_rays``, as ``rtlab bench rays`` times trace() (the default on CUDA; events bracketing
  the kernel behind a GPU spin).
- warp: CUDA events around one ``wp.launch``, recorded behind an untimed launch of the same kernel, so
  that the start event fires once the GPU has the timed launch queued (Warp's launch overhead in
  Python stays outside the span, as rtlab's spin keeps pycuda's out).
- warp-idle: events around one launch on an idle GPU (the launch's overhead inside the span), the
  form a plain harness measures.
- optix: Dr.Jit's kernel history (``JitFlag.KernelHistory``): the ``execution_time`` of the launch that
  evaluates t and the triangle index, which Dr.Jit brackets with events around ``optixLaunch``.
Each configuration's median is taken over ``--repeats`` launches after ``--warmup``; rounds alternate the
tracers on the same rays and the table gives the median of the rounds. Error: every tracer's hits
against the float64 reference on the bench's checked subsample (``RayBatch.error``).
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from rtlab.benches.rays import make_rays, peer_figures, peer_source

MAX_T = 1.0e30          # no far limit (the rays' t are in units of |d| = 1)
TRACERS = ("rtlab", "warp", "optix", "warp-idle")

try:        # Warp's kernel must be defined at import; the script runs without Warp for the other tracers
    import warp as wp

    @wp.kernel
    def warp_closest_hit(mesh: wp.uint64, origins: wp.array(dtype=wp.vec3),
                         directions: wp.array(dtype=wp.vec3), max_t: float, t_out: wp.array(dtype=float),
                         tri_out: wp.array(dtype=int)):
        i = wp.tid()
        q = wp.mesh_query_ray(mesh, origins[i], directions[i], max_t)
        if q.result:
            t_out[i] = q.t
            tri_out[i] = q.face
        else:
            t_out[i] = max_t
            tri_out[i] = -1
except ImportError:          # pragma: no cover - Warp is not a dependency of the project
    wp = None


class RtlabTracer:
    name = "rtlab"

    def __init__(self, device: str | None):
        from rtlab.backends import get_backend
        self.backend = get_backend("cuda", device)
        self.device_name = self.backend.device_name

    def prepare(self, batch):
        self.batch = batch

    def time(self, repeats: int, warmup: int):
        from rtlab.benches.rays import bench_rays
        from rtlab.device.kernels import Variant
        row = bench_rays(self.batch, self.backend, Variant(), repeats=repeats, warmup=warmup, render=False)
        return row.median_ms, row.error


class WarpTracer:
    name = "warp"

    def __init__(self, device: str | None, idle: bool = False):
        self.idle = idle            # warp-idle: events around a launch on an idle GPU (launch overhead inside)
        self.name = "warp-idle" if idle else "warp"
        if wp is None:
            raise SystemExit("warp-lang is not installed (pip install warp-lang==1.19.0)")
        wp.config.quiet = True
        wp.init()
        self.device = device or "cuda:0"
        self.device_name = wp.get_device(self.device).name
        self.events = ((wp.Event(self.device, enable_timing=True), wp.Event(self.device, enable_timing=True))
                       if wp.get_device(self.device).is_cuda else None)
        self._mesh_key = None

    def prepare(self, batch):
        key = batch.view.split("/")[0]       # the scene: its views and sizes share the geometry
        if key != self._mesh_key:     # one BVH a scene, as the README's figures (prebuilt, not timed)
            v = np.ascontiguousarray(batch.scene.vertices, np.float32)
            f = np.ascontiguousarray(batch.scene.faces, np.int32).ravel()
            self.points = wp.array(v, dtype=wp.vec3, device=self.device)
            self.indices = wp.array(f, dtype=wp.int32, device=self.device)
            self.mesh = wp.Mesh(points=self.points, indices=self.indices, bvh_constructor="sah")
            self._mesh_key = key
        n = batch.n
        self.n = n
        self.batch = batch
        self.o = wp.array(np.ascontiguousarray(batch.origins, np.float32), dtype=wp.vec3, device=self.device)
        self.d = wp.array(np.ascontiguousarray(batch.directions, np.float32), dtype=wp.vec3, device=self.device)
        self.t = wp.empty(n, dtype=float, device=self.device)
        self.tri = wp.empty(n, dtype=int, device=self.device)

    def _launch(self):
        wp.launch(warp_closest_hit, dim=self.n, inputs=[self.mesh.id, self.o, self.d, MAX_T],
                  outputs=[self.t, self.tri], device=self.device)

    def _timed_launch(self) -> float:
        if self.events is None:                          # a CPU try of the script: wall time
            t0 = time.perf_counter()
            self._launch()
            wp.synchronize_device(self.device)
            return (time.perf_counter() - t0) * 1e3
        start, end = self.events
        if self.idle:
            wp.synchronize_device(self.device)
        else:
            self._launch()                       # untimed: keeps the GPU busy while the next is queued
        wp.record_event(start)
        self._launch()
        wp.record_event(end)
        return wp.get_event_elapsed_time(start, end, synchronize=True)

    def time(self, repeats: int, warmup: int):
        spans = []
        for i in range(warmup + repeats):
            ms = self._timed_launch()
            if i >= warmup:
                spans.append(ms)
        t = self.t.numpy().astype(np.float32)
        tri = self.tri.numpy().astype(np.int64)
        t[tri < 0] = np.inf
        return float(np.median(spans)), self.batch.error(tri, t)


class OptixTracer:
    name = "optix"

    def __init__(self, device: str | None, variant: str = "cuda_ad_rgb"):
        try:
            import drjit as dr
            import mitsuba as mi
        except ImportError as e:
            raise SystemExit(f"mitsuba is not installed (pip install mitsuba==3.9.1): {e}")
        mi.set_variant(variant)
        self.dr, self.mi = dr, mi
        self.device_name = f"Mitsuba {mi.__version__} {variant}"
        self._scene_key = None

    def prepare(self, batch):
        dr, mi = self.dr, self.mi
        key = batch.view.split("/")[0]
        if key != self._scene_key:
            v = np.ascontiguousarray(batch.scene.vertices, np.float32)
            f = np.ascontiguousarray(batch.scene.faces, np.uint32)
            mesh = mi.Mesh("peer", vertex_count=v.shape[0], face_count=f.shape[0], has_vertex_normals=False,
                           has_vertex_texcoords=False)
            params = mi.traverse(mesh)
            params["vertex_positions"] = mi.Float(v.ravel())
            params["faces"] = mi.UInt32(f.ravel())
            params.update()
            self.scene = mi.load_dict({"type": "scene", "shape": mesh})
            self._scene_key = key
        o, d = np.asarray(batch.origins, np.float32), np.asarray(batch.directions, np.float32)
        self.ray = mi.Ray3f(o=mi.Point3f(*(mi.Float(np.ascontiguousarray(o[:, k])) for k in range(3))),
                            d=mi.Vector3f(*(mi.Float(np.ascontiguousarray(d[:, k])) for k in range(3))))
        dr.eval(self.ray)
        dr.sync_thread()
        self.coherent = batch.kind == "primary"
        self.batch = batch

    def time(self, repeats: int, warmup: int):
        dr = self.dr
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        spans = []
        for i in range(warmup + repeats):
            dr.kernel_history()                  # empties the history
            pi = self.scene.ray_intersect_preliminary(self.ray, coherent=self.coherent)
            dr.eval(pi.t, pi.prim_index)
            dr.sync_thread()
            launches = [k for k in dr.kernel_history() if "execution_time" in k]
            if i >= warmup:
                spans.append(sum(k["execution_time"] for k in launches))
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        t = np.asarray(pi.t, np.float32)
        tri = np.where(np.isfinite(t), np.asarray(pi.prim_index, np.int64), -1)
        t = np.where(tri >= 0, t, np.inf).astype(np.float32)
        return float(np.median(spans)), self.batch.error(tri, t)


def parse_rows(text: str | None):
    """rows "view:kind:size,...", or None for every row of the README's table"""
    if not text:
        return sorted(peer_figures(), key=lambda r: (r[1] != "diffuse", r[2], r[0]))   # diffuse rows first
    rows = []
    for item in text.split(","):
        view, kind, size = item.split(":")
        rows.append((view, kind, int(size)))
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", help="view:kind:size,... (default: every row of the README's table)")
    ap.add_argument("--peers", default=",".join(TRACERS), help="tracers to time, of " + ", ".join(TRACERS))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=22)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--device", default=None, help="CUDA device (rtlab's name filter / Warp's 'cuda:N')")
    ap.add_argument("--mitsuba-variant", default="cuda_ad_rgb", help="llvm_ad_rgb to try the script on a CPU")
    ap.add_argument("--md", help="write the table as markdown here")
    a = ap.parse_args(argv)
    names = [p.strip() for p in a.peers.split(",") if p.strip()]
    unknown = [p for p in names if p not in TRACERS]
    if unknown:
        raise SystemExit(f"unknown tracer(s) {unknown}; choose from {', '.join(TRACERS)}")
    tracers = []
    for name in names:
        if name == "rtlab":
            tracers.append(RtlabTracer(a.device))
        elif name in ("warp", "warp-idle"):
            tracers.append(WarpTracer(a.device, idle=name == "warp-idle"))
        else:
            tracers.append(OptixTracer(a.device, a.mitsuba_variant))
    figures = peer_figures()
    peer_device, peer_date = peer_source()
    lines = []
    header = ("| view | kind | size | rays | " + " | ".join(f"{t.name} Mrays/s" for t in tracers)
              + " | " + " | ".join(f"{t.name} this GPU ÷ README" for t in tracers if t.name != "rtlab")
              + (" | " + " | ".join(f"rtlab ÷ {t.name}, this run" for t in tracers if t.name != "rtlab")
                 if any(t.name == "rtlab" for t in tracers) else "")
              + " | error vs float64 reference (mismatches / checked) |")
    lines.append(header)
    lines.append("|" + "---|" * (header.count("|") - 1))
    print(f"devices: {', '.join(f'{t.name}: {t.device_name}' for t in tracers)}; README figures: "
          f"{peer_device}, {peer_date}", flush=True)
    for view, kind, size in parse_rows(a.rows):
        t0 = time.time()
        batch = make_rays(view, kind, size)
        for t in tracers:
            t.prepare(batch)
        per_round = {t.name: [] for t in tracers}
        errors = {}
        for _ in range(a.rounds):
            for t in tracers:
                ms, error = t.time(a.repeats, a.warmup)
                per_round[t.name].append(ms)
                errors.setdefault(t.name, error)
        mrays = {name: batch.n / (statistics.median(v) * 1e-3) / 1e6 for name, v in per_round.items()}
        readme = figures.get((view, kind, size), {})
        cells = [view, kind, f"{size}²", f"{batch.n:,}"] + [f"{mrays[t.name]:,.0f}" for t in tracers]
        cells += [f"{mrays[t.name] / readme[t.name.split('-')[0]]:.2f}" if t.name.split("-")[0] in readme else "-" for t in tracers
                  if t.name != "rtlab"]
        if "rtlab" in mrays:
            cells += [f"{mrays['rtlab'] / mrays[t.name]:.2f}" for t in tracers if t.name != "rtlab"]
        cells.append("; ".join(f"{name} {e['mismatches']} / {e['rays']:,}" for name, e in errors.items()))
        lines.append("| " + " | ".join(cells) + " |")
        print(lines[-1], f"({time.time() - t0:.0f} s)", flush=True)
    if a.md:
        with open(a.md, "w") as fh:
            fh.write(f"Command: `python experiments/peers_same_run.py {' '.join(sys.argv[1:] if argv is None else argv)}`\n\n")
            fh.write(f"devices: {', '.join(f'{t.name}: {t.device_name}' for t in tracers)}\n\n")
            fh.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
