"""Where a warp's lanes idle in the ray fetch's walk (trace_rays_fetch on the 4-wide tree), modelled on the
host: each diffuse ray's walk as rt_bvh4.h takes it, round by round (the float64 mirror,
rtlab.accel.bvh_wide_stats: a round is the inner nodes visited down to a leaf, that leaf's triangles, the
stack entries popped), and a warp of 32 lanes that runs them as bvh4_trace_steps does: the visit loop
until its last lane leaves it, the leaf's triangles until the largest leaf is done, the pops, then
lanes whose ray is done wait until fewer than THRESHOLD lanes still walk, when the idle ones take the
next rays together.

    python experiments/fetch_lane_model.py --views dragon/fill,conference/inside --size 256

Counts warp instructions (a step that any lane takes costs its SASS instructions once) and lane
instructions (once a lane that takes it), from the costs of the fetch kernel's SASS below. The
lanes busy that Nsight Compute measures, to hold the model against, are in docs/results/wide-bvh.md
("A shorter chain on the H100"). "if-if" is the other loop shape of Aila & Laine (2009): each iteration a
lane either visits one node or, at a leaf, tests its triangles and pops, so lanes between nodes do not
wait for the others' leaves, nor lanes at leaves for the others' visits. "pop in loop" (rt_bvh4.h's
RT_FETCH_POP_IN_LOOP): a visit that enters no child pops the next pending one inside the visit loop, so
a round without a leaf joins the next one (its visits added to it; each visit costs POP_IN_LOOP
instructions more for the test, and the pops made in the loop are not counted). --visit-exits and
--leaf-exits: the visit loop's early exit (RT_FETCH_VISIT_EXIT) and the same for the leaf's triangle
loop (experiments/prototypes/fetch_leaf_exit.patch).
"""
from __future__ import annotations

import argparse

import numpy as np

from rtlab.accel.bvh4 import load_or_build_bvh4
from rtlab.accel.bvh_wide_stats import traversal_counts_bvh4
from rtlab.benches.rays import make_rays, view_scene
from rtlab.jit import njit

WARP = 32
MAX_ROUNDS = 256
# SASS instructions (trace_rays_fetch, bvh4/watertight, sm_90; nvcc_kernel_report.py --node-loop 7): a node
# visit (its loop) and a triangle test (the leaf's loop) as counted there; an entry popped, a round's own
# (the leaf's ref decoded, the cut, the warp vote) and a ray started (hit refined and stored, the
# counter, the ray loaded, the walk's constants) estimated from the listing.
COSTS = {"visit": 106, "tri": 143, "pop": 12, "round": 20, "ray": 250}
POP_IN_LOOP = 8                            # the visit loop's test for "no child entered", its branch
VOTE = 9                                   # the visit loop's warp vote, compares and branch (SASS: 106 -> 115)


@njit(cache=True)
def _run_warps(rounds, shape_if, threshold, visit_exit, c_visit, c_tri, c_pop, c_round, c_ray, leaf_exit=1):
    """(warp instructions, lane instructions) by phase: visit, leaf, pop, round, ray start. visit_exit K
    (while-while): the visit loop stops once fewer than K lanes are still in it and another lane is at
    its leaf (1: at its last lane); the lanes still between nodes then go on in the next round, the
    others test their leaf and pop. leaf_exit L: the same for the leaf's triangle loop (a lane that
    stops mid-leaf tests the rest in the next round, before it pops)."""
    n, r_max = rounds.shape[0], rounds.shape[1]
    warp = np.zeros(5)
    lane = np.zeros(5)
    ray = np.full(WARP, -1, np.int64)
    r = np.zeros(WARP, np.int64)
    left_v = np.zeros(WARP, np.int64)          # visits left in the lane's round
    tri_done = np.zeros(WARP, np.int64)        # triangles of the round's leaf tested (leaf_exit)
    nxt = 0
    while True:
        # lanes without a ray take the next ones (a ray outside the scene box is done at once)
        taken = 0
        for k in range(WARP):
            while ray[k] < 0 and nxt < n:
                ray[k], r[k], tri_done[k] = nxt, 0, 0
                nxt += 1
                taken += 1
                if rounds[ray[k], 0, 0] < 0:
                    ray[k] = -1
                else:
                    left_v[k] = rounds[ray[k], 0, 0]
        if taken:
            warp[4] += c_ray
            lane[4] += c_ray * taken
        walking = 0
        for k in range(WARP):
            walking += ray[k] >= 0
        if walking == 0:
            break
        while True:
            if not shape_if:
                # the visit loop, until fewer than visit_exit lanes are still in it
                while True:
                    act, walk = 0, 0
                    for k in range(WARP):
                        act += ray[k] >= 0 and left_v[k] > 0
                        walk += ray[k] >= 0
                    if act == 0 or (act < visit_exit and act < walk):   # some lane at its leaf
                        break
                    warp[0] += c_visit
                    lane[0] += c_visit * act
                    for k in range(WARP):
                        if ray[k] >= 0 and left_v[k] > 0:
                            left_v[k] -= 1
            else:
                # one step a lane: a visit, or (visits done) its leaf and pops
                act = 0
                for k in range(WARP):
                    act += ray[k] >= 0 and left_v[k] > 0
                if act:
                    warp[0] += c_visit
                    lane[0] += c_visit * act
            leafing = np.zeros(WARP, np.bool_)
            for k in range(WARP):
                leafing[k] = ray[k] >= 0 and left_v[k] == 0
            # the leaf's triangles, until fewer than leaf_exit lanes still test and another is done
            n_leafing = 0
            for k in range(WARP):
                n_leafing += leafing[k]
            while True:
                act = 0
                for k in range(WARP):
                    act += leafing[k] and rounds[ray[k], r[k], 1] > tri_done[k]
                if act == 0 or (act < leaf_exit and act < n_leafing):
                    break
                warp[1] += c_tri
                lane[1] += c_tri * act
                for k in range(WARP):
                    if leafing[k] and rounds[ray[k], r[k], 1] > tri_done[k]:
                        tri_done[k] += 1
            for k in range(WARP):                  # a lane with triangles left pops in a later round
                if leafing[k] and rounds[ray[k], r[k], 1] > tri_done[k]:
                    leafing[k] = False
            it = 0
            while True:
                act = 0
                for k in range(WARP):
                    act += leafing[k] and rounds[ray[k], r[k], 2] > it
                if act == 0:
                    break
                warp[2] += c_pop
                lane[2] += c_pop * act
                it += 1
            act = 0
            for k in range(WARP):
                act += leafing[k]
            if act:
                warp[3] += c_round
                lane[3] += c_round * act
            walking = 0
            for k in range(WARP):
                if ray[k] < 0:
                    continue
                if left_v[k] > 0:
                    left_v[k] -= shape_if     # if-if: this iteration's visit (while-while: visits left)
                    walking += 1
                    continue
                if not leafing[k]:            # triangles of its leaf left
                    walking += 1
                    continue
                r[k] += 1
                tri_done[k] = 0
                if r[k] >= r_max or rounds[ray[k], r[k], 0] < 0:
                    ray[k] = -1
                else:
                    left_v[k] = rounds[ray[k], r[k], 0]
                    walking += 1
            if walking == 0 or walking < threshold:
                break
    return warp, lane


@njit(cache=True)
def rounds_with_pops_in_loop(rounds):
    """The rounds as the walk takes them when a visit that enters no child pops in the visit loop: a
    round without a leaf (0 triangles) joins the next one, its visits added to it."""
    out = np.full_like(rounds, -1)
    for i in range(rounds.shape[0]):
        j, v = 0, 0
        for r in range(rounds.shape[1]):
            if rounds[i, r, 0] < 0:
                break
            v += rounds[i, r, 0]
            if rounds[i, r, 1] == 0 and r + 1 < rounds.shape[1] and rounds[i, r + 1, 0] >= 0:
                continue
            out[i, j, 0], out[i, j, 1], out[i, j, 2] = v, rounds[i, r, 1], rounds[i, r, 2]
            j, v = j + 1, 0
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", default="dragon/fill,conference/inside")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--thresholds", default="20")
    ap.add_argument("--visit-exits", default="1,4,8,12", help="while-while: stop the visit loop below K lanes")
    ap.add_argument("--leaf-exits", default="1", help="while-while: stop the leaf's triangle loop below L lanes")
    args = ap.parse_args()
    c = COSTS
    print("| view | loop | threshold | lanes a warp instruction (of 32) | warp instructions a ray | lane instructions a ray "
          "| lanes busy: visits / triangles / pops / ray starts |")
    print("|---|---|---:|---:|---:|---:|---|")
    for view in args.views.split(","):
        scene = view_scene(view, args.size)
        rays = make_rays(view, "diffuse", args.size, check_rays=1, scene=scene)
        b4, _ = load_or_build_bvh4(scene.vertices, scene.faces)
        rounds = np.zeros((len(rays.origins), MAX_ROUNDS, 3), np.int64)
        traversal_counts_bvh4(b4, scene.vertices, scene.faces, rays.origins, rays.directions, rounds=rounds)
        cut = int(np.sum(rounds[:, -1, 0] >= 0))
        if cut:
            print(f"({view}: {cut} rays walk more than {MAX_ROUNDS} rounds; their rest is not counted)")
        n = len(rays.origins)
        merged = rounds_with_pops_in_loop(rounds)
        exits = [int(k) for k in args.visit_exits.split(",")]
        leaf_exits = [int(k) for k in args.leaf_exits.split(",")]
        shapes = ([("while-while", k, False, 1) for k in exits]
                  + [("while-while, pop in loop", k, True, e) for k in exits for e in leaf_exits]
                  + [("if-if", 1, False, 1)])
        for shape, exit_k, pops_in_loop, leaf_k in shapes:
            for thr in (int(t) for t in args.thresholds.split(",")):
                extra = (VOTE if exit_k > 1 else 0) + (POP_IN_LOOP if pops_in_loop else 0)
                warp, lane = _run_warps(merged if pops_in_loop else rounds, shape == "if-if", thr, exit_k,
                                        c["visit"] + extra, c["tri"] + (VOTE if leaf_k > 1 else 0), c["pop"],
                                        c["round"], c["ray"], leaf_k)
                busy = " / ".join(f"{lane[i] / warp[i]:.1f}" if warp[i] else "-" for i in (0, 1, 2, 4))
                name = shape if exit_k == 1 else f"{shape}, visits stop below {exit_k} lanes"
                name += f", triangles below {leaf_k}" if leaf_k > 1 else ""
                print(f"| {view} | {name} | {thr} | {lane.sum() / warp.sum():.2f} | {warp.sum() / n:.0f} | "
                      f"{lane.sum() / n:.0f} | {busy} |")


if __name__ == "__main__":
    main()
