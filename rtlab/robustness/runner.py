"""Running the robustness suite (rtlab.robustness): each case traced (or rendered, family 11) by every
test and traversal, counted against the float64 reference, in a child process where a kernel may
crash or hang; rows summed per family and shown as a table."""
from __future__ import annotations

import multiprocessing as mp
import queue as queue_mod
import time
from dataclasses import dataclass, field, replace
from typing import Callable, Iterable

import numpy as np

from ..benches.tables import Table
from ..kernel_constants import kernel_constant
from .cases import FAMILY_NAMES, GOALS, PIXEL_OFF, ROBUST_STACK_SIZE, Case
from .families import family_cases

# The relative t error the kernels promise for the closest-hit choice (the watertight test's
# plane_t_fp64); a same-triangle hit whose t is further from the float64 reference counts as t_off
T_ERR = float(kernel_constant("RT_T_ERR"))


@dataclass
class RobustnessRow:
    family: int
    case: str
    isect: str
    traversal: str
    conservative: int
    backend: str
    device: str
    rays: int
    ref_hits: int = 0
    leaks: int = 0
    misses: int = 0
    mismatches: int = 0
    ties: int = 0
    false_hits: int = 0
    nan_t: int = 0
    t_off: int = 0                      # same triangle as the reference, t off by more than RT_T_ERR
    differs: int = -1                   # id not the traversals' majority (same test); -1: not compared
    px_off: int = -1                    # family 11 only
    failure: str = ""
    t_rel_err_max: float = float("nan")
    kernel_ms: float = 0.0
    first_bad: list = field(default_factory=list)   # a few ray indices of mismatches/leaks, for debugging

    @property
    def failures(self) -> int:
        return int(bool(self.failure))

    def goal_violations(self) -> dict[str, int]:
        """Counts that miss the suite's goal (meaningful for the watertight, conservative rows)."""
        return {k: getattr(self, k) for k, fams in GOALS.items() if self.family in fams and getattr(self, k) > 0}


def trace_case(case: Case, backend, isect: str, traversal: str, conservative: int | None = None, **defines):
    """Closest hits of the case's rays: (tri, t, kernel ms). ``conservative`` None keeps the test's
    default RT_CONSERVATIVE (on for watertight), 0/1 forces it; ``defines`` add -D switches
    (e.g. RT_HAS_FP64=0 for the watertight test's float-only path). One stack size for every scene
    (ROBUST_STACK_SIZE), so that a program serves all cases."""
    from ..device.kernels import Variant
    from ..device.tracing import trace
    extra = dict(defines)
    if conservative is not None:
        extra["RT_CONSERVATIVE"] = int(conservative)
    result = trace(case.scene, case.origins, case.directions, backend=backend,
                   variant=Variant(traversal=traversal, intersection=isect), defines=extra,
                   min_stack_size=ROBUST_STACK_SIZE)
    return result.tri, result.t, result.kernel_ms


def count_case(case: Case, ref, tri: np.ndarray, t: np.ndarray, row: RobustnessRow) -> RobustnessRow:
    """Fill the counts of ``row`` from the kernel's hits against the reference."""
    from ..reference import compare_hits, intersect_ray_triangles_f64, usable_triangle_mask
    from ..reference.metrics import barycentric_slack
    v, f = case.scene.vertices, case.scene.faces
    tri = np.where(np.asarray(tri) < 0, -1, tri).astype(np.int64)
    cmp = compare_hits(ref, tri, t, v, f, case.origins, case.directions, tie_eps=case.tie_eps, tie_abs=case.tie_abs())
    k_hit, r_hit = tri >= 0, ref.tri >= 0
    row.ref_hits = int(r_hit.sum())
    row.misses = int((r_hit & ~k_hit).sum())
    row.mismatches, row.ties = cmp.n_mismatch, cmp.n_ties
    row.t_rel_err_max = cmp.t_rel_err_max
    row.nan_t = int(np.isnan(t).sum())
    same = k_hit & (tri == ref.tri)
    with np.errstate(invalid="ignore"):
        off = np.abs(np.asarray(t, np.float64)[same] - ref.t[same]) > T_ERR * np.abs(ref.t[same])
    row.t_off = int(np.sum(off | np.isnan(np.asarray(t, np.float64)[same])))
    reached = k_hit if case.target_tris is None else np.isin(tri, case.target_tris)
    if case.must_hit is not None:
        row.leaks = int((case.must_hit & ~reached).sum())
    false = np.zeros(case.n_rays, bool)
    if case.bad is not None:
        false |= case.bad & k_hit
    known = k_hit & (tri < f.shape[0])
    false |= k_hit & ~known
    if known.any():
        idx = np.flatnonzero(known)
        vv = v.astype(np.float64)
        ff = f[tri[idx]]
        usable = usable_triangle_mask(vv[ff[:, 0]], vv[ff[:, 1]], vv[ff[:, 2]])
        # the kernel's triangle in float64 with the same slack compare_hits gives a tie
        eps = barycentric_slack(tri[idx], case.directions[idx].astype(np.float64), v, f, 1e-4, case.tie_abs())
        t64, _, _ = intersect_ray_triangles_f64(case.origins[idx], case.directions[idx], tri[idx], v, f, eps=eps)
        false[idx] |= ~usable | ~np.isfinite(t64)
    row.false_hits = int(false.sum())
    bad_idx = np.flatnonzero(cmp.mismatch | false | ((case.must_hit if case.must_hit is not None else False) & ~reached))
    row.first_bad = bad_idx[:5].tolist()
    return row


def render_case(case: Case, backend, isect: str, traversal: str, conservative: int | None = None):
    """Family 11: the case's Whitted render, (image, primary hit ids, kernel ms). Shadows one-pass,
    case.render["bounces"] bounces; ``conservative`` as in trace_case (passed as a define)."""
    from ..device.kernels import Variant
    from ..device.whitted import render_whitted
    variant = Variant(traversal=traversal, intersection=isect)
    extra = {} if conservative is None else {"RT_CONSERVATIVE": int(conservative)}
    result = render_whitted(case.scene, backend, variant, bounces=case.render["bounces"], defines=extra)
    return result.image, result.median_ms


def count_render(case: Case, ref, image: np.ndarray, row: RobustnessRow) -> RobustnessRow:
    """Family 11: pixels more than PIXEL_OFF/255 off the float64 reference."""
    delta = np.abs(image.astype(np.int32) - ref.image.astype(np.int32)).max(axis=2)
    row.px_off = int((delta > PIXEL_OFF).sum())
    row.first_bad = np.flatnonzero(delta.reshape(-1) > PIXEL_OFF)[:5].tolist()
    return row


def _trace_or_failure(case, backend, isect, traversal, conservative):
    """trace_case (render_case for family 11), or the error as a failure string (a build error
    fails this combination only)."""
    try:
        if case.render is not None:
            return render_case(case, backend, isect, traversal, conservative)
        return trace_case(case, backend, isect, traversal, conservative)
    except Exception as e:
        return f"error: {type(e).__name__}: {e}"


def _isolated_worker(spec, family, size, case_index, combos, out):
    """Child process: trace one case for each (isect, traversal, conservative), reporting each."""
    from ..backends import get_backend
    backend = get_backend(*spec)
    case = family_cases(family, size)[case_index]
    for i, (isect, traversal, cons) in enumerate(combos):
        out.put(("start", i))
        result = _trace_or_failure(case, backend, isect, traversal, cons)
        out.put(("error", i, result) if isinstance(result, str) else ("done", i, *result))


def _run_isolated(backend, family, size, case_index, combos, timeout_s):
    """Results per combo: (tri, t, ms) or a failure string, surviving crashes and hangs."""
    from ..backends import backend_spec
    ctx = mp.get_context("spawn")
    results: dict[int, object] = {}
    pending = list(range(len(combos)))
    while pending:
        q = ctx.Queue()
        todo = [combos[i] for i in pending]
        proc = ctx.Process(target=_isolated_worker, args=(backend_spec(backend), family, size, case_index,
                                                          todo, q), daemon=True)
        proc.start()
        current, deadline = None, time.monotonic() + timeout_s
        while True:
            try:
                msg = q.get(timeout=max(0.1, min(1.0, deadline - time.monotonic())))
            except queue_mod.Empty:
                if not proc.is_alive() and q.empty():
                    failed = pending[current] if current is not None else pending[0]
                    results[failed] = f"crash: child exited with code {proc.exitcode}"
                    break
                if time.monotonic() > deadline:
                    failed = pending[current] if current is not None else pending[0]
                    results[failed] = f"hang (> {timeout_s:.0f} s)"
                    proc.terminate()
                    proc.join(5)
                    if proc.is_alive():
                        proc.kill()
                    break
                continue
            kind, local = msg[0], msg[1]
            if kind == "start":
                current, deadline = local, time.monotonic() + timeout_s
            elif kind == "done":
                results[pending[local]] = msg[2:]
            else:
                results[pending[local]] = msg[2]
            if len([p for p in pending if p in results]) == len(pending):
                break
        proc.join(5)
        if proc.is_alive():
            proc.kill()
        pending = [p for p in pending if p not in results]
    return [results[i] for i in range(len(combos))]


# Why many parameters: the options of `rtlab bench robustness`, passed through.
def run_robustness(backend, isects: Iterable[str] | None = None, traversals: Iterable[str] | None = None,
                   families: Iterable[int] = tuple(range(1, 10)), size: str = "test",
                   conservative: Iterable[int | None] = (None,), isolate: Iterable[int] = (8,),
                   timeout_s: float = 300.0, progress: Callable[[str], None] | None = None) -> list[RobustnessRow]:
    """Every case of ``families`` x every test x every traversal on ``backend``; one row each.

    isects/traversals default to every name in rtlab.device.kernels.INTERSECTIONS/TRAVERSALS, read at
    call time. ``conservative``: RT_CONSERVATIVE settings to run (None = the test's default).
    Families in ``isolate`` run in a child process, so a crash or a hang (``timeout_s`` per test
    and traversal, compile included) is counted instead of ending the run."""
    from ..backends import get_backend
    from ..device.kernels import INTERSECTIONS, TRAVERSALS, Variant
    if not hasattr(backend, "compile"):
        backend = get_backend(backend)
    isects = list(isects) if isects is not None else list(INTERSECTIONS)
    traversals = list(traversals) if traversals is not None else list(TRAVERSALS)
    for isect in isects:
        Variant(intersection=isect)          # an unknown name fails here, before any work
    for traversal in traversals:
        Variant(traversal=traversal)
    all_combos = [(i, tr, c) for i in isects for tr in traversals for c in conservative]
    isolate = set(isolate)
    rows = []
    for family in families:
        for ci, case in enumerate(family_cases(family, size)):
            if progress:
                progress(f"family {family} ({FAMILY_NAMES[family]}): {case.label}")
            # the packet traversal has no Whitted kernels (its shared stack lives in lab step 03's)
            combos = [c for c in all_combos if case.render is None or c[1] != "packet"]
            ref = case.reference()
            if family in isolate:
                outcomes = _run_isolated(backend, family, size, ci, combos, timeout_s)
            else:
                outcomes = [_trace_or_failure(case, backend, i, tr, c) for i, tr, c in combos]
            for (isect, traversal, cons), out in zip(combos, outcomes):
                eff = int(cons) if cons is not None else int(isect == "watertight")
                row = RobustnessRow(family, case.label, isect, traversal, eff, backend.name, backend.device_name,
                                    case.n_rays)
                if isinstance(out, str):
                    row.failure = out
                elif case.render is not None:
                    image, row.kernel_ms = out
                    count_render(case, ref, image, row)
                else:
                    tri, t, row.kernel_ms = out
                    count_case(case, ref, tri, t, row)
                rows.append(row)
            count_differs(rows[len(rows) - len(combos):], outcomes)
    return rows


def majority_ids(ids: list[np.ndarray]) -> np.ndarray:
    """Per ray, the id most of the arrays report (misses as -1); among equally common ids, the lowest."""
    stack = np.stack([np.where(np.asarray(i) < 0, -1, i).astype(np.int64) for i in ids])
    counts = (stack[:, None, :] == stack[None, :, :]).sum(axis=1)
    best = counts.max(axis=0)
    return np.where(counts == best, stack, np.iinfo(np.int64).max).min(axis=0)


def count_differs(rows: list[RobustnessRow], outcomes: list) -> None:
    """Fill ``differs`` of one case's rows: per test and RT_CONSERVATIVE setting traced by two or more
    traversals, the rays whose id is not the one most traversals report ("the same ids in every
    traversal"). Rows that failed or rendered are left at -1."""
    groups: dict[tuple, list[int]] = {}
    for i, (row, out) in enumerate(zip(rows, outcomes)):
        if isinstance(out, tuple) and len(out) == 3:
            groups.setdefault((row.isect, row.conservative), []).append(i)
    for members in groups.values():
        if len(members) < 2:
            continue
        ids = [np.asarray(outcomes[i][0]) for i in members]
        majority = majority_ids(ids)
        for i, tri in zip(members, ids):
            differ = np.where(tri < 0, -1, tri) != majority
            rows[i].differs = int(differ.sum())
            if differ.any() and not rows[i].first_bad:
                rows[i].first_bad = np.flatnonzero(differ)[:5].tolist()


def aggregate(rows: list[RobustnessRow]) -> list[RobustnessRow]:
    """Rows summed over the cases of each family (per test, traversal, RT_CONSERVATIVE, backend)."""
    out: dict[tuple, RobustnessRow] = {}
    for r in rows:
        key = (r.family, r.isect, r.traversal, r.conservative, r.backend)
        a = out.get(key)
        if a is None:
            out[key] = replace(r, case=FAMILY_NAMES[r.family], first_bad=list(r.first_bad))
            continue
        for k in ("rays", "ref_hits", "leaks", "misses", "mismatches", "ties", "false_hits", "nan_t", "t_off"):
            setattr(a, k, getattr(a, k) + getattr(r, k))
        if r.differs >= 0:                                     # -1: not compared
            a.differs = max(a.differs, 0) + r.differs
        if r.px_off >= 0:                                      # -1: not counted (families other than 11)
            a.px_off = max(a.px_off, 0) + r.px_off
        a.failure = a.failure or r.failure
        a.kernel_ms += r.kernel_ms
        a.t_rel_err_max = float(np.nanmax([a.t_rel_err_max, r.t_rel_err_max]))
    return list(out.values())


TABLE_COLUMNS = ("family", "case", "test", "traversal", "cons.", "rays", "leaks", "misses", "mismatches",
                 "ties", "differs", "false hits", "NaN t", "t off", "px off", "failure", "max rel dt", "ms")


def row_cells(r: RobustnessRow) -> tuple[str, ...]:
    dt = "-" if np.isnan(r.t_rel_err_max) else f"{r.t_rel_err_max:.1e}"
    return (str(r.family), r.case, r.isect, r.traversal, str(r.conservative), f"{r.rays:,}", str(r.leaks),
            str(r.misses), str(r.mismatches), str(r.ties), "-" if r.differs < 0 else str(r.differs),
            str(r.false_hits), str(r.nan_t), str(r.t_off), "-" if r.px_off < 0 else str(r.px_off), r.failure or "-",
            dt, f"{r.kernel_ms:.1f}")


def robustness_table(rows: list[RobustnessRow], title: str = "robustness") -> Table:
    """The rows (per case, or per family after :func:`aggregate`) under TABLE_COLUMNS."""
    return Table(TABLE_COLUMNS, [row_cells(r) for r in rows], title)
