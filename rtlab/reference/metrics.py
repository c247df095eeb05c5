"""Error metrics against the float64 reference: hit agreement, t error, image error.

Hits are compared by triangle id exactly, but some rays cannot decide between two answers: a ray
through an edge shared by two triangles, or one grazing a silhouette, may rightly report either
side once the geometry is rounded to float32. :func:`compare_hits` calls those "ties" and counts
them apart from real mismatches; the rule is spelled out there.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .tracer import RefHits, intersect_pairs

__all__ = ["HitComparison", "compare_hits", "image_rmse_psnr", "pixels_differing"]

_TINY = np.finfo(np.float64).tiny


@dataclass
class HitComparison:
    """How a kernel's closest hits agree with the reference."""
    n_rays: int
    n_hits_ref: int
    n_same: int               # same triangle id, both misses included
    n_mismatch: int           # different and not a tie
    n_ties: int               # different, but the ray cannot decide (see compare_hits)
    t_rel_err_max: float      # over rays where both hit the same triangle; nan if there are none
    t_rel_err_median: float
    first_mismatch_index: int  # -1 when there is none
    mismatch: np.ndarray = field(default=None, repr=False)  # (R,) bool
    tie: np.ndarray = field(default=None, repr=False)       # (R,) bool

    @property
    def ok(self) -> bool:
        return self.n_mismatch == 0

    def summary(self) -> str:
        hit_pct = 100.0 * self.n_hits_ref / self.n_rays if self.n_rays else 0.0
        dt = "n/a" if np.isnan(self.t_rel_err_max) else f"{self.t_rel_err_max:.1e}"
        s = (f"{self.n_rays} rays, {hit_pct:.1f}% hit: {self.n_mismatch} mismatches, "
             f"{self.n_ties} ties at edges, max rel |dt| {dt}")
        if self.first_mismatch_index >= 0:
            s += f" (first mismatch: ray {self.first_mismatch_index})"
        return s


def _min_barycentric(b0, b1, b2):
    return np.minimum(np.minimum(b0, b1), b2)


FLOAT32_UNIT_ROUNDOFF = 2.0 ** -24


def _condition_slack(tri, origins, directions, vertices, faces, cond_ulps):
    """Barycentric error a float32 ray/triangle test can make: cond_ulps * u * kappa, with
    kappa = |o - v0| * longest edge / |det| (det = e1 . (d x e2), d unit): the barycentrics are
    ratios of triple products whose rounding grows with the origin's distance and shrinks with the
    triangle's projected area. Measured on KITCHEN: float32 Moller-Trumbore errs by 1.4e-4..4e-4
    where kappa is 7.5e3..5e4, i.e. about 1..2 u kappa."""
    slack = np.zeros(tri.shape[0])
    known = tri >= 0
    if cond_ulps <= 0.0 or not known.any():
        return slack
    v = np.asarray(vertices, np.float32).astype(np.float64)
    c = v[np.asarray(faces, np.int64)[tri[known]]]
    e1, e2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
    d = np.asarray(directions, np.float64)[known]
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    s = np.asarray(origins, np.float64)[known] - c[:, 0]
    det = np.abs(np.einsum("ij,ij->i", e1, np.cross(d, e2)))
    longest = np.maximum(np.linalg.norm(e1, axis=1), np.linalg.norm(e2, axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        kappa = np.linalg.norm(s, axis=1) * longest / det
    slack[known] = np.where(np.isfinite(kappa), cond_ulps * FLOAT32_UNIT_ROUNDOFF * kappa, np.inf)
    return slack


def barycentric_slack(tri, directions, vertices, faces, tie_eps, tie_abs, origins=None, cond_ulps=0.0):
    """Per-ray barycentric slack: the larger of tie_eps and the float32 conditioning slack
    (_condition_slack, when origins are given), plus tie_abs (world units) measured across the
    triangle's smallest altitude and stretched by 1/|cos| of the incidence angle, since a position
    error along the ray moves a grazing hit point across the triangle by that factor."""
    eps = np.full(tri.shape[0], float(tie_eps))
    if origins is not None:
        eps = np.maximum(eps, _condition_slack(tri, origins, directions, vertices, faces, cond_ulps))
    if tie_abs <= 0.0:
        return eps
    known = tri >= 0
    v = np.asarray(vertices, np.float32).astype(np.float64)
    c = v[np.asarray(faces, np.int64)[tri[known]]]
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    n_len = np.linalg.norm(n, axis=1)
    longest = np.max(np.linalg.norm(c - np.roll(c, 1, axis=1), axis=2), axis=1)
    d = directions[known]
    with np.errstate(divide="ignore", invalid="ignore"):
        min_altitude = n_len / longest
        cos = np.abs(np.einsum("ij,ij->i", n, d)) / (n_len * np.linalg.norm(d, axis=1))
        extra = tie_abs / (min_altitude * cos)
    eps[known] += np.where(np.isnan(extra), np.inf, extra)
    return eps


# Why long: the tie rule of the module docstring, step by step, each step a few numpy lines.
# Why many parameters: the rays, the scene and the rule's tolerances (keywords with defaults).
def compare_hits(ref: RefHits, tri, t, vertices, faces, origins, directions, tie_eps=1e-4,
                 tmin=0.0, tmax=np.inf, tie_abs=0.0, cond_ulps=4.0) -> HitComparison:
    """Compare a kernel's closest hits (tri: id, negative = miss; t) with the reference.

    A ray whose ids differ is a *tie* when the difference is one the ray cannot decide, judged in
    float64 with barycentric slack ``tie_eps``:

    (a) both hit, and the kernel's triangle, re-intersected with slack, is hit at a t within
        ``tie_eps`` (relative) of the reference t: shared edges and vertices, coplanar overlaps;
    (b) the nearer of the two answers (a miss counts as t = inf) is a triangle hit only near its
        edge (smallest of (1-u-v, u, v) below ``tie_eps``), and the farther one, if a hit, is a
        real one (the kernel's triangle is hit when re-intersected): silhouette grazes, whether
        the ray then leaves the scene or goes on to a triangle behind.

    Everything else is a mismatch, including a kernel id outside the mesh or a kernel triangle
    that the ray does not hit at all. tmin/tmax: the interval the rays were traced with.

    ``cond_ulps`` (default 4): the slack of each triangle is at least cond_ulps float32 rounding
    units times the test's condition number (see _condition_slack), so a small triangle seen at a
    grazing angle from afar, whose float32 barycentrics are uncertain by more than ``tie_eps``,
    counts as undecidable there and nowhere else. 0 turns it off.

    ``tie_abs`` (world units, default 0 = the rule above as is) widens the edge slack of each
    triangle by tie_abs / (smallest altitude x |cos incidence|): a float32 kernel's position error
    of a few ulps of the scene scale, smeared across a small triangle hit at a grazing angle, can
    exceed any fixed barycentric ``tie_eps``. Something like 16 * 2**-24 * (scene extent + eye
    distance) is a fair allowance for float32 kernels.
    """
    n = len(ref)
    k_tri = np.asarray(tri).astype(np.int64).reshape(-1)
    k_t = np.asarray(t, np.float64).reshape(-1)
    if k_tri.shape[0] != n or k_t.shape[0] != n:
        raise ValueError(f"expected {n} hits, got tri {k_tri.shape} and t {k_t.shape}")
    n_faces = np.asarray(faces).shape[0]
    k_tri = np.where(k_tri < 0, -1, k_tri)
    r_tri = ref.tri
    r_hit = r_tri >= 0
    same = k_tri == r_tri
    differ = np.flatnonzero(~same)

    tie = np.zeros(n, bool)
    if differ.size:
        o = np.broadcast_to(np.asarray(origins, np.float64).reshape(-1, 3), (n, 3))[differ]
        d = np.broadcast_to(np.asarray(directions, np.float64).reshape(-1, 3), (n, 3))[differ]
        lo = np.broadcast_to(np.asarray(tmin, np.float64), (n,))[differ]
        hi = np.broadcast_to(np.asarray(tmax, np.float64), (n,))[differ]
        kt = k_tri[differ]
        k_known = (kt >= 0) & (kt < n_faces)
        # the kernel's triangle in float64, with edge slack: where and how close to its edge
        kt_known = np.where(k_known, kt, -1)
        k_eps = barycentric_slack(kt_known, d, vertices, faces, tie_eps, tie_abs, o, cond_ulps)
        r_eps = barycentric_slack(r_tri[differ], d, vertices, faces, tie_eps, tie_abs, o, cond_ulps)
        k_t64, kb0, kb1, kb2 = intersect_pairs(o, d, kt_known, vertices, faces, eps=k_eps,
                                                tmin=lo, tmax=hi)
        k_real = np.isfinite(k_t64)
        k_edge = k_real & (_min_barycentric(kb0, kb1, kb2) < k_eps)
        ref_t = ref.t[differ]
        ru, rv = ref.u[differ], ref.v[differ]
        r_edge = r_hit[differ] & (_min_barycentric(1.0 - ru - rv, ru, rv) < r_eps)
        with np.errstate(invalid="ignore"):
            same_t = k_real & r_hit[differ] & (
                np.abs(k_t64 - ref_t) <= tie_eps * np.maximum(np.abs(ref_t), _TINY))
        kernel_nearer = np.where(k_real, k_t64, np.inf) < ref_t
        nearer_is_graze = np.where(kernel_nearer, k_edge, r_edge)
        farther_is_real = np.where(kernel_nearer, True, k_real | (kt < 0))
        # a miss on both sides never gets here; the kernel naming a triangle it does not hit is
        # never a tie (k_known & k_real are required whenever kt >= 0)
        valid_kernel = (kt < 0) | (k_known & k_real)
        tie[differ] = valid_kernel & (same_t | (nearer_is_graze & farther_is_real))

    mismatch = ~same & ~tie
    both_same_hit = same & r_hit
    if both_same_hit.any():
        t_ref = ref.t[both_same_hit]
        with np.errstate(invalid="ignore"):
            rel = np.abs(k_t[both_same_hit] - t_ref) / np.maximum(np.abs(t_ref), _TINY)
        rel = np.where(np.isnan(rel), np.inf, rel)
        t_max, t_med = float(rel.max()), float(np.median(rel))
    else:
        t_max = t_med = float("nan")
    bad = np.flatnonzero(mismatch)
    return HitComparison(
        n_rays=n, n_hits_ref=int(r_hit.sum()), n_same=int(same.sum()),
        n_mismatch=int(mismatch.sum()), n_ties=int(tie.sum()), t_rel_err_max=t_max,
        t_rel_err_median=t_med, first_mismatch_index=int(bad[0]) if bad.size else -1,
        mismatch=mismatch, tie=tie)


def _as_unit_float(img) -> np.ndarray:
    a = np.asarray(img)
    if a.dtype == np.uint8:
        return a.astype(np.float64) / 255.0
    if a.dtype == np.uint16:
        return a.astype(np.float64) / 65535.0
    return a.astype(np.float64)


def image_rmse_psnr(img, ref) -> tuple[float, float]:
    """Root-mean-square error and PSNR (dB, peak 1) of ``img`` against ``ref``.

    Float images are taken as [0, 1]; uint8 (and uint16) are scaled to [0, 1] first, so a uint8
    image compares with a float one. PSNR is inf for equal images.
    """
    a, b = _as_unit_float(img), _as_unit_float(ref)
    if a.shape != b.shape:
        raise ValueError(f"image shapes differ: {a.shape} vs {b.shape}")
    rmse = float(np.sqrt(np.mean((a - b) ** 2))) if a.size else 0.0
    psnr = float("inf") if rmse == 0.0 else float(20.0 * np.log10(1.0 / rmse))
    return rmse, psnr


def pixels_differing(a_ids, b_ids) -> int:
    """Number of pixels whose triangle ids differ (every negative id counts as the same miss)."""
    a = np.asarray(a_ids).astype(np.int64)
    b = np.asarray(b_ids).astype(np.int64)
    if a.shape != b.shape:
        raise ValueError(f"id image shapes differ: {a.shape} vs {b.shape}")
    return int(np.count_nonzero(np.where(a < 0, -1, a) != np.where(b < 0, -1, b)))
