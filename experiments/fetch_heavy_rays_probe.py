"""Do a diffuse batch's costliest rays set the ray fetch's launch time? Times trace() on the benchmark's
diffuse rays, on the batch without its costliest q % (ranked by the float64 host mirror of the 4-wide
walk: node visits x NODE_INSTR + triangle tests x TRI_INSTR), without a random q % (the same count, so
the difference is which rays, not how many), and on the costliest q % alone (what a second launch of
them would cost; beside it a random q % alone). Configurations alternate round by round on the same
rays; a subset's hits must be the full batch's bit for bit, and the full batch is checked against the
float64 reference.

    python experiments/fetch_heavy_rays_probe.py --backend cuda --views dragon/fill,bunny/fill,conference/inside \
        --size 1024 --percents 0.05,0.2,1,3 --rounds 3 --repeats 5

If "without the costliest q %" + "the costliest q % alone" is well under "all", a budget that parks
rays past it for a launch of their own would pay; if "without the costliest" is no faster than "without
a random q %", the heavy rays do not set the launch's length.

``--lone`` times the costliest rays by themselves on an idle GPU instead (lone_sets): a ray's own
latency, without the load of a launch; ``--configs "default;RT_FETCH_POP_IN_LOOP=0"`` repeats the
fetch's sets under other -D switches of its walk. ``--describe`` (host only, no device) says what the
costliest rays are: their walks at 4 and 8 children a node, their angle to the surface they leave,
how many hit.
"""
from __future__ import annotations

import argparse
from unittest import mock

import numpy as np

from diffuse_cost_proxies import NODE_INSTR, TRI_INSTR
from rtlab.accel.bvh4 import load_or_build_bvh4
from rtlab.accel.bvh_wide_stats import traversal_counts_bvh4
from rtlab.backends import get_backend
from rtlab.benches.rays import make_rays
from rtlab.device import tracing
from rtlab.device.tracing import trace

WARP = 32


def lone_sets(cost: np.ndarray, origins, directions, seed: int = 7) -> dict[str, tuple]:
    """--lone: how long the costliest rays take by themselves on an idle GPU, as (origins, directions,
    whether trace_rays_fetch takes them): the costliest ray alone; the
    costliest 32 as one warp; the same 32 one a warp, each with 31 rays that miss the scene (trace_rays,
    one ray a thread, so no lane takes another's ray); 32 random rays as one warp; one ray that
    misses (the launch's floor)."""
    ranked = np.argsort(-cost, kind="stable")
    rand = np.sort(np.random.default_rng(seed).choice(len(cost), WARP, replace=False))
    top = ranked[:WARP]
    miss_o = np.full((1, 3), 1e6, np.float32)             # far outside any benchmark scene, pointing away
    miss_d = np.ones((1, 3), np.float32)
    spread_o = np.repeat(miss_o, WARP * WARP, 0)
    spread_d = np.repeat(miss_d, WARP * WARP, 0)
    spread_o[::WARP] = origins[top]
    spread_d[::WARP] = directions[top]
    pick = lambda idx: (origins[idx], directions[idx])  # noqa: E731
    return {"costliest ray alone": (*pick(ranked[:1]), True),
            "costliest ray alone (trace_rays)": (*pick(ranked[:1]), False),
            "costliest 32, one warp": (*pick(top), True),
            "costliest 32, one warp (trace_rays)": (*pick(top), False),
            "costliest 32, one a warp (trace_rays)": (spread_o, spread_d, False),
            "32 random rays, one warp (trace_rays)": (*pick(rand), False),
            "one ray that misses": (miss_o, miss_d, True)}


def parse_defines(config: str) -> dict:
    """``default`` or ``D=V,D=V``: -D switches of trace_rays_fetch's walk (rt_bvh4.h)"""
    return {} if config == "default" else dict(p.split("=", 1) for p in config.split(","))


def time_lone(batch, cost, backend, rounds: int, repeats: int, configs: list[str]) -> None:
    """lone_sets timed, the fetch's sets once per configuration of -D switches; one column a configuration
    (trace_rays' sets and the floor in the first column only)."""
    sets = lone_sets(cost, batch.origins, batch.directions)
    best = {(k, c): [] for k in sets for c in configs}
    for _ in range(rounds):
        for k, (o, d, fetch) in sets.items():
            for c in configs if fetch else configs[:1]:
                with mock.patch.object(tracing, "fetches_rays", tracing.fetches_rays if fetch else (lambda *_: False)):
                    r = trace(batch.scene, o, d, backend, repeats=repeats, warmup=1, defines=parse_defines(c))
                best[(k, c)].append(min(r.launches_ms))
    print("| rays | " + " | ".join(configs) + " |")
    print("|---|" + "---:|" * len(configs))
    for k in sets:
        cells = [f"{float(np.median(best[(k, c)])):.4f}" if best[(k, c)] else "" for c in configs]
        print(f"| {k} | " + " | ".join(cells) + " |")


def subsets(cost: np.ndarray, percents: list[float], seed: int = 7) -> dict[str, np.ndarray]:
    """Index sets of the batch, each ascending (the rays keep their order): all, and per q the batch
    without its costliest q %, without a random q %, and the costliest q % alone."""
    n = len(cost)
    ranked = np.argsort(-cost, kind="stable")
    rng = np.random.default_rng(seed)
    sets = {"all": np.arange(n)}
    for q in percents:
        k = max(1, int(round(n * q / 100)))
        heavy = np.sort(ranked[:k])
        rand = np.sort(rng.choice(n, k, replace=False))
        sets[f"-top{q}%"] = np.setdiff1d(np.arange(n), heavy)
        sets[f"-rand{q}%"] = np.setdiff1d(np.arange(n), rand)
        sets[f"top{q}% alone"] = heavy
        sets[f"rand{q}% alone"] = rand
    return sets


def describe(batch, nodes, tris, cost) -> None:
    """--describe: the costliest rays against the batch, on the host mirrors. A diffuse ray's cosine to
    the surface it leaves is sqrt(1 - u1), u1 its first draw of the bench's generator
    (rtlab.benches.rays.diffuse_rays)."""
    from bvh_width_chain import wide_walk_arrays
    from rtlab.accel.bvh_wide_stats import traversal_counts_wide
    from rtlab.reference import reference_trace
    n = len(cost)
    cosine = np.sqrt(1.0 - np.random.default_rng(1).random(n))
    ranked = np.argsort(-cost, kind="stable")
    eight = wide_walk_arrays(batch.scene.vertices, batch.scene.faces, 8)
    print("| rays | node visits (trace()'s 4-wide tree) | triangle tests | node visits (8 float children a node, "
          "bvh_width_chain.py's tree) | cosine to the surface, median | cosine < 0.1 | hit the scene |")
    print("|---|---:|---:|---:|---:|---:|---:|")

    def walks(idx):
        """mean node visits at 8 children and the share that hits, of rays idx"""
        o = np.asarray(batch.origins, np.float64)[idx]
        d = np.asarray(batch.directions, np.float64)[idx]
        v8 = traversal_counts_wide(eight, batch.scene.vertices, batch.scene.faces, o, d)[0]
        return np.mean(v8), np.mean(reference_trace(batch.scene.vertices, batch.scene.faces, o, d).tri >= 0)

    sample = np.arange(0, n, max(1, n // 20000))
    rows = [(f"the costliest {k}", ranked[:k], ranked[:k]) for k in (32, 306, 3000)]
    rows.append((f"the batch ({n:,}; 8 children and hits on {len(sample):,} of them)", np.arange(n), sample))
    for label, idx, walked in rows:
        v8, hit = walks(walked)
        print(f"| {label} | {nodes[idx].mean():.1f} | {tris[idx].mean():.1f} | {v8:.1f} | "
              f"{np.median(cosine[idx]):.2f} | {np.mean(cosine[idx] < 0.1):.0%} | {hit:.0%} |")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--backend", default="cuda")
    ap.add_argument("--device", default=None)
    ap.add_argument("--views", default="dragon/fill,bunny/fill,conference/inside")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--percents", default="0.1,0.5,2")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--lone", action="store_true", help="time the costliest rays by themselves (lone_sets)")
    ap.add_argument("--describe", action="store_true", help="host only: what the costliest rays are (describe)")
    ap.add_argument("--configs", default="default",
                    help="--lone: ';'-separated -D sets for the fetch's walk, e.g. 'default;RT_FETCH_POP_IN_LOOP=0'")
    a = ap.parse_args(argv)
    backend = None if a.describe else get_backend(a.backend, a.device)
    percents = [float(p) for p in a.percents.split(",")]
    if backend is not None:
        print(f"device: {backend.name}: {backend.device_name}; {a.rounds} rounds x best of {a.repeats}; ms")
    for view in a.views.split(","):
        batch = make_rays(view, "diffuse", a.size)
        o = np.asarray(batch.origins, np.float64)
        d = np.asarray(batch.directions, np.float64)
        b4, _ = load_or_build_bvh4(batch.scene.vertices, batch.scene.faces)
        nodes, _, tris = traversal_counts_bvh4(b4, batch.scene.vertices, batch.scene.faces, o, d)[:3]
        cost = NODE_INSTR * np.asarray(nodes, np.float64) + TRI_INSTR * np.asarray(tris, np.float64)
        if a.describe:
            print(f"\n{view}: {len(cost):,} diffuse rays at {a.size}²")
            describe(batch, nodes, tris, cost)
            continue
        if a.lone:
            top = int(np.argmax(cost))
            print(f"\n{view}: costliest rays' cost {np.sort(cost)[::-1][:4].astype(int).tolist()}...; "
                  f"visits / triangle tests of the costliest: {int(nodes[top])} / {int(tris[top])}")
            time_lone(batch, cost, backend, a.rounds, a.repeats, a.configs.split(";"))
            continue
        sets = subsets(cost, percents)
        best = {k: [] for k in sets}
        hits = {}
        for _ in range(a.rounds):
            for k, idx in sets.items():
                r = trace(batch.scene, batch.origins[idx], batch.directions[idx], backend, repeats=a.repeats,
                          warmup=1)
                best[k].append(min(r.launches_ms))
                hits[k] = (r.tri, r.t)
        tri, t = hits["all"]
        err = batch.error(tri, t)
        same = all(np.array_equal(hits[k][0], tri[idx]) and np.array_equal(hits[k][1].view(np.int32),
                                                                           t[idx].view(np.int32))
                   for k, idx in sets.items())
        pct = np.percentile(cost, [50, 99, 99.9])
        print(f"\n{view}: {len(cost)} rays; cost mean {cost.mean():.0f}, median {pct[0]:.0f}, p99 {pct[1]:.0f}, "
              f"p99.9 {pct[2]:.0f}, max {cost.max():.0f}; error vs float64: {err['mismatches']} mismatches of "
              f"{err['rays']}; subsets' hits the full batch's bit for bit: {'yes' if same else 'NO'}")
        print("| rays | count | ms | against all |")
        print("|---|---:|---:|---:|")
        t_all = float(np.median(best["all"]))
        for k, idx in sets.items():
            ms = float(np.median(best[k]))
            print(f"| {k} | {len(idx):,} | {ms:.4f} | {ms / t_all - 1:+.1%} |")
        for q in percents:
            split = float(np.median(best[f"-top{q}%"])) + float(np.median(best[f"top{q}% alone"]))
            print(f"without the costliest {q} % + them alone: {split:.4f} ms ({split / t_all - 1:+.1%} against all)")


if __name__ == "__main__":
    main()
