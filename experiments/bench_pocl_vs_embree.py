"""rtlab on PoCL against Embree on one thread, measured live on the same rays.

For each PoCL thread count asked for (default: one, then one a core) a fresh process (PoCL reads
its thread count when it starts) traces the views' primary rays with rtlab (the bvh-packet
traversal unless told otherwise) and with Embree through embreex (one thread), in alternating
rounds, with each one's error against the float64 reference (rtlab.benches.cpu). Printed: Mrays/s
of each, the ratio, and Mrays per CPU-second (per core, whatever else runs on the machine).

    python experiments/bench_pocl_vs_embree.py [--size 1024] [--rounds 7] [--threads 1,2]
    rtlab bench cpu --threads 2          # the same measurement for one thread count, as a table
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from dataclasses import asdict

VIEWS = "bunny/fill,sponza/inside,default"


def child(args) -> int:
    """Measure in this process (POCL_MAX_PTHREAD_COUNT already set by the parent) and print JSON rows."""
    from rtlab.backends import get_backend
    from rtlab.benches.cpu import EmbreeTracer, bench_cpu
    from rtlab.benches.rays import make_rays
    from rtlab.device.kernels import Variant
    backend = get_backend("opencl", os.environ.get("RTLAB_DEVICE", "cpu"))
    rows = []
    for view in args.views.split(","):
        batch = make_rays(view, "primary", args.size)
        row = bench_cpu(batch, backend, Variant.paper(traversal=args.traversal), args.rounds,
                        EmbreeTracer(batch.scene.vertices, batch.scene.faces))
        d = asdict(row)
        d.update(rtlab_mrays=row.rtlab_mrays, embree_mrays=row.embree_mrays, ratio=row.ratio,
                 rtlab_mrays_cpu=row.rtlab_mrays_cpu, embree_mrays_cpu=row.embree_mrays_cpu,
                 ratio_per_core=row.ratio_per_core)
        rows.append(d)
    print(json.dumps(rows))
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--views", default=VIEWS)
    ap.add_argument("--traversal", default="bvh-packet")
    ap.add_argument("--threads", default=f"1,{os.cpu_count()}", help="PoCL thread counts, comma-separated")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(args)
    from rtlab.benches.cpu import embree_version, error_text
    counts = sorted({int(t) for t in args.threads.split(",") if t})
    results = {}
    for n in counts:
        env = dict(os.environ, POCL_MAX_PTHREAD_COUNT=str(n))
        cmd = [sys.executable, __file__, "--child", "--size", str(args.size), "--rounds", str(args.rounds),
               "--views", args.views, "--traversal", args.traversal]
        r = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if r.returncode != 0:
            raise SystemExit(f"measurement with {n} PoCL threads failed ({r.returncode}):\n{r.stderr[-2000:]}")
        results[n] = json.loads(r.stdout.strip().splitlines()[-1])
    first = results[counts[0]]
    print(f"rtlab {args.traversal} on {first[0]['device']} against {embree_version()} (one thread); "
          f"{args.size}² primary rays; medians of {args.rounds} alternating rounds; {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.2f}")
    head = f"{'view':<15} {'PoCL thr.':>9} {'rtlab Mrays/s':>14} {'Embree Mrays/s':>15} {'ratio':>6} " \
           f"{'rtlab /CPU-s':>13} {'Embree /CPU-s':>14} {'per core':>8}  errors (rtlab | Embree)"
    print(head)
    for i, view_row in enumerate(first):
        for n in counts:
            r = results[n][i]
            print(f"{view_row['view']:<15} {r['threads']:>9} {r['rtlab_mrays']:>14.2f} {r['embree_mrays']:>15.2f} "
                  f"{r['ratio']:>5.2f}x {r['rtlab_mrays_cpu']:>13.2f} {r['embree_mrays_cpu']:>14.2f} "
                  f"{r['ratio_per_core']:>7.2f}x  {error_text(r['rtlab_error'])} | {error_text(r['embree_error'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
