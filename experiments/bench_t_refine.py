"""What the watertight test's refined t costs: trace() on the same rays with RT_REFINE_T=1 (the default:
each accepted hit's t is the plane distance computed in double, plane_t_fp64 in rt_intersect.h) and
RT_REFINE_T=0 (Woop et al.'s scaled-barycentric t), alternating within one run, with the error of each
against the float64 reference beside its time.

    python experiments/bench_t_refine.py [--backend opencl] [--device NAME] [--views sponza/inside,...]
        [--kinds primary,diffuse] [--size 512] [--traversals stack,bvh] [--max-registers 0,64]
        [--rounds 7] [--repeats 5] [--md out.md]

Per view, ray kind and traversal (the benchmark rays of ../shared/bench/README.md, rtlab.benches.rays):
  ms        trace() kernel time: the median over --rounds of the best of --repeats launches, the two
            settings alternating round by round on the same rays (so drift hits both alike)
  Mrays/s   rays / that time;  cost = refined / Woop's time - 1
  mism.     mismatches against the float64 reference on the checked subsample (ties apart)
  t off     hits on the reference's triangle whose t is off by more than RT_T_ERR (2 ulps)
  max dt    largest relative t error there
With --max-registers, each traversal also runs under those register caps (Variant.max_registers; 0 = none):
the refined t raises the watertight trace kernel's registers on sm_90 (nvcc: bvh 55 -> 72, stack 48 -> 66),
and a cap shows what the occupancy it costs is worth.
Then the grazing-sliver case of the robustness suite (family 13, bench size): mismatches with a blocker
2e-5 of t away, the same two settings.
"""
from __future__ import annotations

import argparse
import datetime
import platform

import numpy as np

from rtlab.backends import get_backend
from rtlab.benches.rays import make_rays
from rtlab.device.tracing import default_variant, trace
from rtlab.kernel_constants import kernel_constant

T_ERR = float(kernel_constant("RT_T_ERR"))


def t_off(batch, tri, t) -> tuple[int, float]:
    idx = batch.check_index
    ref = batch.reference
    same = (tri[idx] == ref.tri) & (ref.tri >= 0)
    rel = np.abs(t[idx][same].astype(np.float64) - ref.t[same]) / np.abs(ref.t[same])
    return int(np.sum(rel > T_ERR)), float(rel.max()) if rel.size else float("nan")


def time_pair(batch, backend, variant, rounds: int, repeats: int):
    """Alternating rounds of RT_REFINE_T=0 and 1: (median of best-of-repeats ms per setting, results)."""
    width = batch.size if batch.kind == "primary" else None
    best = {0: [], 1: []}
    last = {}
    for _ in range(rounds):
        for refine in (0, 1):
            r = trace(batch.scene, batch.origins, batch.directions, backend, variant, repeats=repeats, warmup=1,
                      width=width, defines={"RT_REFINE_T": refine})
            best[refine].append(min(r.launches_ms))
            last[refine] = r
    return {k: float(np.median(v)) for k, v in best.items()}, last


def sliver_rows(backend, variant):
    from rtlab.robustness import RobustnessRow, count_case, family_cases, trace_case
    out = []
    for case in family_cases(13, "bench"):
        if "blockers" not in case.label:
            continue
        ref = case.reference()
        for refine in (0, 1):
            tri, t, ms = trace_case(case, backend, variant.intersection, variant.traversal, RT_REFINE_T=refine)
            row = count_case(case, ref, tri, t, RobustnessRow(13, case.label, variant.intersection, variant.traversal,
                                                              1, backend.name, backend.device_name, case.n_rays))
            out.append((case.label, refine, row.mismatches, row.t_off, row.t_rel_err_max, ms))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--backend", default="opencl")
    ap.add_argument("--device", default=None)
    ap.add_argument("--views", default="bunny/fill,sponza/inside,kitchen/inside,conference/inside")
    ap.add_argument("--kinds", default="primary,diffuse")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--traversals", default=None, help="default: the backend's default traversal")
    ap.add_argument("--max-registers", default="0", help="register caps to run each traversal under (0: none)")
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--slivers", action=argparse.BooleanOptionalAction, default=True)
    ap.add_argument("--md", default=None)
    args = ap.parse_args(argv)
    backend = get_backend(args.backend, args.device)
    base = default_variant(backend)
    traversals = args.traversals.split(",") if args.traversals else [base.traversal]
    header = ("| view | kind | rays | variant | ms Woop t | ms refined t | Mrays/s Woop | Mrays/s refined | cost | "
              "mism. Woop / refined | t off Woop / refined | max dt Woop / refined |")
    lines = [f"Command: `python experiments/bench_t_refine.py {' '.join(argv or __import__('sys').argv[1:])}`",
             f"Device: {backend.name}: {backend.device_name} ({platform.node()}), {datetime.date.today()}", "",
             header, "|" + "---|" * (header.count("|") - 1)]
    print("\n".join(lines[:2]))
    for view in args.views.split(","):
        for kind in args.kinds.split(","):
            batch = make_rays(view, kind, args.size, check_rays=16384)
            for traversal, cap in [(t, int(c)) for t in traversals for c in args.max_registers.split(",")]:
                variant = base.with_(traversal=traversal, max_registers=cap)
                ms, res = time_pair(batch, backend, variant, args.rounds, args.repeats)
                err = {k: batch.error(res[k].tri, res[k].t) for k in (0, 1)}
                off = {k: t_off(batch, res[k].tri, res[k].t) for k in (0, 1)}
                cost = ms[1] / ms[0] - 1.0
                line = (f"| {view} | {kind} | {batch.n:,} | {variant.label()} | {ms[0]:.3f} | {ms[1]:.3f} | "
                        f"{batch.n / ms[0] / 1e3:,.1f} | {batch.n / ms[1] / 1e3:,.1f} | {100 * cost:+.1f} % | "
                        f"{err[0]['mismatches']} / {err[1]['mismatches']} | {off[0][0]} / {off[1][0]} | "
                        f"{off[0][1]:.1e} / {off[1][1]:.1e} |")
                print(line, flush=True)
                lines.append(line)
    if args.slivers:
        lines += ["", "| family 13 case | RT_REFINE_T | mismatches | t off | max rel dt | ms |", "|---|---|---|---|---|---|"]
        for label, refine, mism, toff, dt, ms in sliver_rows(backend, base):
            line = f"| {label} | {refine} | {mism} | {toff} | {dt:.1e} | {ms:.2f} |"
            print(line, flush=True)
            lines.append(line)
    if args.md:
        with open(args.md, "a") as fh:
            fh.write("\n".join(lines) + "\n\n")


if __name__ == "__main__":
    main()
