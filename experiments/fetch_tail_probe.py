"""How much of a diffuse batch's kernel time is its tail: the benchmark rays traced once, twice and
three times over in one batch (the batch repeated end to end, so cost and coherence are the same),
kernel time fitted as T(m) = fixed + m x per_batch. ``fixed`` is what a launch costs besides its rays:
the launch itself and the tail, when the ray counter is empty and warps finish the rays they hold
with nothing to refill them.

    python experiments/fetch_tail_probe.py --backend cuda --views dragon/fill,conference/inside [--repeats 10]
"""
from __future__ import annotations

import argparse

import numpy as np

from rtlab.backends import get_backend
from rtlab.benches.rays import make_rays
from rtlab.device.tracing import trace


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--backend", default="cuda")
    ap.add_argument("--device", default=None)
    ap.add_argument("--views", default="dragon/fill,conference/inside,sponza/inside")
    ap.add_argument("--kind", default="diffuse")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--copies", default="1,2,3")
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--defines", default="", help="NAME=V,... compiled into the kernels")
    a = ap.parse_args(argv)
    backend = get_backend(a.backend, a.device)
    copies = [int(c) for c in a.copies.split(",")]
    defines = {k: int(v) for k, v in (x.split("=") for x in a.defines.split(",") if x)}
    print(f"device: {backend.name}: {backend.device_name}; median over rounds of the best of {a.repeats}")
    print("| view | kind | rays | " + " | ".join(f"x{m} ms" for m in copies) + " | fixed ms | per batch ms | fixed / x1 |")
    print("|---|---|---:|" + "---:|" * len(copies) + "---:|---:|---:|")
    for view in a.views.split(","):
        batch = make_rays(view, a.kind, a.size)
        times = {m: [] for m in copies}
        hits = {}
        for _ in range(a.rounds):
            for m in copies:
                o, d = np.tile(batch.origins, (m, 1)), np.tile(batch.directions, (m, 1))
                r = trace(batch.scene, o, d, backend, repeats=a.repeats, warmup=1, defines=defines)
                times[m].append(min(r.launches_ms))
                hits[m] = r.tri[:batch.n]
        ms = [float(np.median(times[m])) for m in copies]
        slope, fixed = np.polyfit(copies, ms, 1)
        same = all(np.array_equal(hits[m], hits[copies[0]]) for m in copies)
        print(f"| {view} | {a.kind} | {batch.n:,} | " + " | ".join(f"{t:.3f}" for t in ms)
              + f" | {fixed:.3f} | {slope:.3f} | {fixed / ms[0]:.2f} |" + ("" if same else " hits differ!"), flush=True)


if __name__ == "__main__":
    main()
