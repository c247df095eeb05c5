"""Where trace() time goes, per backend, on one benchmark view: the same rays timed three ways, and
the compiled code of both backends dumped for comparison.

    python experiments/profile_trace.py --cases bunny/far:primary,bunny/fill:diffuse --size 1024 \
        --traversals bvh,stack --backends cuda,opencl:NVIDIA --out results/

Timings (median of --repeats launches after warm-up, Mrays/s):
  launch      what rtlab reports (Program.launch: CUDA events behind a GPU spin, OpenCL profiling)
  plain       CUDA only: events around pycuda's unprepared call on an idle GPU (how rtlab once timed
              CUDA): the host's argument packing and launch latency fall inside the events
  amortised   one event pair around --repeats back-to-back launches, divided by their number
--sweep times CUDA's trace_rays over nvcc options (--nvcc-options, ';'-separated sets), register caps
(--max-registers) and block sizes (--blocks) beside OpenCL's, with the mismatches of each against
the float64 reference subsample: one line per configuration.
With --ncu the script only launches (for `ncu --kernel-name regex:trace_rays`): no checks, no dumps.
OpenCL programs' binaries (NVIDIA: PTX) are written to --out for `ptxas -v` / SASS comparison.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rtlab.backends import get_backend  # noqa: E402
from rtlab.benches.rays import make_rays  # noqa: E402
from rtlab.device.kernels import Variant, load_program, primary_step  # noqa: E402
from rtlab.device.layout import float4_rows  # noqa: E402
from rtlab.device.device_scene import device_scene  # noqa: E402
from rtlab.device.tracing import TRACE_BLOCK, ray_buffers, trace  # noqa: E402


def _backend(spec: str):
    name, _, dev = spec.partition(":")
    return get_backend(name, dev or None)


def _setup(batch, be, variant):
    ds = device_scene(batch.scene, be)
    program = load_program(be, primary_step(variant), variant, ds.features(variant))
    ds.set_constants(program, None, variant)
    n = batch.n
    o_buf, d_buf, h_buf = ray_buffers(be, n)
    be.fill(o_buf, float4_rows(batch.origins, 0.0))
    be.fill(d_buf, float4_rows(batch.directions, np.inf))
    return program, ds.scene_args(variant) + [o_buf, d_buf, h_buf, np.int32(n)]


def plain_cuda_ms(program, args, n, repeats):
    """Events around pycuda's generic call on an idle GPU (how rtlab timed CUDA before)."""
    drv = program.backend.drv
    f = program.function("trace_rays")
    grid = ((n + TRACE_BLOCK - 1) // TRACE_BLOCK, 1)
    out = []
    for _ in range(repeats):
        start, end = drv.Event(), drv.Event()
        start.record()
        f(*args, block=(TRACE_BLOCK, 1, 1), grid=grid)
        end.record()
        end.synchronize()
        out.append(end.time_since(start))
    return out


def amortised_ms(program, args, n, repeats):
    be = program.backend
    if be.name == "cuda":
        f = program.prepared("trace_rays", args)
        grid = ((n + TRACE_BLOCK - 1) // TRACE_BLOCK, 1)
        be.spin()
        start, end = be.events
        start.record()
        for _ in range(repeats):
            f.prepared_async_call(grid, (TRACE_BLOCK, 1, 1), None, *args)
        end.record()
        end.synchronize()
        return end.time_since(start) / repeats
    import pyopencl as cl
    k = program.kernel("trace_rays")
    consts = [program._constants["frame"][0]]
    gsize = ((n + TRACE_BLOCK - 1) // TRACE_BLOCK * TRACE_BLOCK,)
    events = [k(be.queue, gsize, (TRACE_BLOCK,), *args, *consts) for _ in range(repeats)]
    cl.wait_for_events(events)
    return (events[-1].profile.end - events[0].profile.start) * 1e-6 / repeats


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", default="bunny/far:primary", help="view:kind, comma-separated")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--traversals", default="bvh,stack")
    ap.add_argument("--backends", default="cuda,opencl:NVIDIA")
    ap.add_argument("--repeats", type=int, default=22)
    ap.add_argument("--out", default=os.environ.get("OUT", "."))
    ap.add_argument("--ncu", action="store_true", help="launch only (3 trace() calls a variant), for ncu")
    ap.add_argument("--sweep", action="store_true", help="sweep CUDA compile options, register caps, blocks")
    ap.add_argument("--nvcc-options", default=";--prec-div=false --prec-sqrt=false;-use_fast_math")
    ap.add_argument("--max-registers", default="0,40")
    ap.add_argument("--blocks", default="64,128,256")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    backends = [_backend(spec) for spec in a.backends.split(",")]
    for case in a.cases.split(","):
        view, _, kind = case.partition(":")
        batch = make_rays(view, kind or "primary", a.size, check_rays=1 if a.ncu else 65_536)
        rows += sweep_case(batch, backends, a) if a.sweep else run_case(batch, backends, a, out)
    if rows:
        with open(out / "profile_trace.jsonl", "a") as f:
            for r in rows:
                f.write(json.dumps(r) + "\n")
    return 0


def sweep_case(batch, backends, a) -> list[dict]:
    import rtlab.device.tracing as tracing
    from rtlab.reference import compare_hits
    rows = []
    idx = batch.check_index
    for be in backends:
        option_sets = a.nvcc_options.split(";") if be.name == "cuda" else [""]
        for opts in option_sets:
            os.environ["RTLAB_NVCC_OPTIONS"] = opts
            for trav in a.traversals.split(","):
                for cap in (int(c) for c in a.max_registers.split(",")):
                    if cap and be.name != "cuda":
                        continue
                    variant = Variant.paper(traversal=trav, max_registers=cap)
                    for block in (int(b) for b in a.blocks.split(",")):
                        tracing.TRACE_BLOCK = block
                        res = trace(batch.scene, batch.origins, batch.directions, be, variant,
                                    repeats=a.repeats, warmup=3)
                        cmp = compare_hits(batch.reference, res.tri[idx], res.t[idx], batch.scene.vertices,
                                           batch.scene.faces, batch.origins[idx], batch.directions[idx])
                        row = {"view": batch.view, "kind": batch.kind, "backend": be.name, "options": opts,
                               "traversal": trav, "maxrreg": cap, "block": block, "ms": round(res.kernel_ms, 4),
                               "mrays": round(batch.n / (res.kernel_ms * 1e-3) / 1e6),
                               "mismatches": cmp.n_mismatch}
                        if be.name == "cuda":
                            program = load_program(be, primary_step(variant), variant,
                                                   device_scene(batch.scene, be).features(variant))
                            row["registers"] = program.resources("trace_rays").registers
                        rows.append(row)
                        print(json.dumps(row), flush=True)
    os.environ.pop("RTLAB_NVCC_OPTIONS", None)
    tracing.TRACE_BLOCK = 128
    return rows


def run_case(batch, backends, a, out) -> list[dict]:
    rows = []
    for be in backends:
        for trav in a.traversals.split(","):
            variant = Variant.paper(traversal=trav)
            if a.ncu:
                trace(batch.scene, batch.origins, batch.directions, be, variant, repeats=3)
                continue
            res = trace(batch.scene, batch.origins, batch.directions, be, variant, repeats=a.repeats, warmup=3)
            program, args = _setup(batch, be, variant)
            row = {"view": batch.view, "kind": batch.kind, "size": batch.size, "backend": be.name, "device": be.device_name,
                   "traversal": trav, "rays": batch.n, "launch_ms": res.kernel_ms,
                   "amortised_ms": amortised_ms(program, args, batch.n, a.repeats)}
            if be.name == "cuda":
                row["plain_ms"] = float(np.median(plain_cuda_ms(program, args, batch.n, a.repeats)))
                row["registers"] = program.resources("trace_rays").registers
                row["local_bytes"] = program.resources("trace_rays").local_bytes
            else:
                name = f"opencl_{batch.view.replace('/', '_')}_{batch.kind}_{trav}.ptx"
                import pyopencl as cl
                binary = program._program.get_info(cl.program_info.BINARIES)[0]
                (out / name).write_bytes(binary)
                row["binary"] = name
            for k in ("launch_ms", "plain_ms", "amortised_ms"):
                if k in row:
                    row[k.replace("_ms", "_mrays")] = batch.n / (row[k] * 1e-3) / 1e6
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


if __name__ == "__main__":
    sys.exit(main())
