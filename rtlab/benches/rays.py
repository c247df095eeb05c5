"""Rays through the trace API on the benchmark views: the rays the peers traced
(``../shared/bench/README.md``), kernel time, the error against the float64 reference beside it, and
the best peer's figure from the same README with the ratio.

Ray kinds (the README's definitions):
- ``primary``: one ray through each pixel centre of the view's camera, directions normalised.
- ``diffuse``: one bounce ray per primary hit, in pixel order. Origin: the float64 hit point moved
  1e-4 x the scene's bounding-box diagonal along the face normal turned to face the incoming ray;
  direction: cosine-weighted about that normal from ``numpy.random.default_rng(1)``.

    batch = make_rays("sponza/inside", "diffuse", 1024)
    row = bench_rays(batch, backend, Variant(traversal="bvh"))    # the rest: the device's default
"""
from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..device.kernels import Variant
from ..scene.model import Scene
from .tables import Table, report_markdown

RAY_KINDS = ("primary", "diffuse")
PEER_FIGURES_FILE = Path(__file__).with_name("peer_figures.json")
DIFFUSE_OFFSET = 1e-4        # x the scene's bounding-box diagonal (README)
CHECK_RAYS = 65_536          # rays of a batch checked against the float64 reference


PEERS = ("warp", "optix", "tinybvh")


@functools.lru_cache(maxsize=1)
def _peer_data() -> dict:
    """peer_figures.json, read once a process (every bench row looks its peers up)"""
    return json.loads(PEER_FIGURES_FILE.read_text())


def peer_source() -> tuple[str, str]:
    """The device and date the peers' figures were measured on (peer_figures.json)."""
    data = _peer_data()
    return data["device"], data["date"]


def peer_note(devices) -> str:
    """What the "× best peer" column compares: the peers' machine, and a caution where a row of this
    run was timed on another device (the ratio then spans two machines, not one run)."""
    device, date = peer_source()
    note = f"best peer: ../shared/bench/README.md's figures, measured on the {device} ({date})"
    others = sorted({d for d in devices if d != device})
    if others:
        note += (f"; this run's {', '.join(others)} is another device, so × best peer compares two "
                 f"machines, not one run")
    return note


def peer_figures() -> dict[tuple[str, str, int], dict]:
    """(view, kind, size) -> {"warp": Mrays/s, "optix": ..., "tinybvh": ..., "best": ..., "best_name": ...}."""
    data = _peer_data()
    out = {}
    for r in data["rows"]:
        names = [k for k in PEERS if k in r]
        best_name = max(names, key=lambda k: r[k])
        out[(r["view"], r["kind"], int(r["size"]))] = {**{k: r[k] for k in names}, "best": r[best_name],
                                                      "best_name": best_name}
    return out


@dataclass
class RayBatch:
    """Rays of one benchmark view and kind, with float64 reference hits of a subsample."""
    view: str
    kind: str
    size: int
    scene: Scene
    origins: np.ndarray          # (N, 3) float32
    directions: np.ndarray       # (N, 3) float32
    check_index: np.ndarray      # rays checked against the reference
    reference: object            # rtlab.reference.RefHits of those rays

    @property
    def n(self) -> int:
        return self.origins.shape[0]

    def error(self, tri: np.ndarray, t: np.ndarray) -> dict:
        """A tracer's hits of these rays against the float64 reference, on the checked subsample."""
        from ..reference import compare_hits
        idx = self.check_index
        cmp = compare_hits(self.reference, tri[idx], t[idx], self.scene.vertices, self.scene.faces,
                           self.origins[idx], self.directions[idx])
        return {"rays": cmp.n_rays, "mismatches": cmp.n_mismatch, "ties": cmp.n_ties,
                "t_rel_err_max": float(cmp.t_rel_err_max)}


def view_scene(view: str, size: int) -> Scene:
    """The preset of ``scene/view`` with the benchmark camera at size x size; a bare preset name
    ("default") keeps the preset's own camera."""
    from ..scene import bench_camera, load_scene
    name = view.split("/", 1)[0]
    scene = load_scene(name, size=size)
    if "/" in view:
        scene.camera = bench_camera(view, size)
    return scene


def face_normals_f64(scene: Scene, tri: np.ndarray) -> np.ndarray:
    """Unit geometric normals of triangles ``tri`` in float64."""
    v = np.asarray(scene.vertices, np.float64)
    f = np.asarray(scene.faces)[tri]
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def diffuse_rays(scene: Scene, origins, directions, t, tri) -> tuple[np.ndarray, np.ndarray]:
    """One cosine-weighted bounce ray per hit (tri >= 0), in ray order (README's recipe)."""
    hit = tri >= 0
    o = np.asarray(origins, np.float64)[hit]
    d = np.asarray(directions, np.float64)[hit]
    n = face_normals_f64(scene, tri[hit])
    n = np.where((np.einsum("ij,ij->i", n, d) > 0)[:, None], -n, n)     # face the incoming ray
    lo, hi = np.asarray(scene.bounds(), np.float64)
    p = o + d * np.asarray(t, np.float64)[hit, None] + n * (DIFFUSE_OFFSET * np.linalg.norm(hi - lo))
    rng = np.random.default_rng(1)
    count = p.shape[0]
    u1, u2 = rng.random(count), rng.random(count)
    r, phi = np.sqrt(u1), 2.0 * np.pi * u2
    a = np.where((np.abs(n[:, 0]) > 0.9)[:, None], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    t1 = np.cross(n, a)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    dirs = t1 * (r * np.cos(phi))[:, None] + t2 * (r * np.sin(phi))[:, None] + n * np.sqrt(1.0 - u1)[:, None]
    return p.astype(np.float32), dirs.astype(np.float32)


def make_rays(view: str, kind: str, size: int, check_rays: int = CHECK_RAYS, scene: Scene | None = None) -> RayBatch:
    """The rays of ``view`` (e.g. "sponza/inside") and ``kind`` at size², and reference hits of an
    evenly spread subsample of at most ``check_rays`` of them."""
    from ..reference import reference_trace
    from ..scene.model import camera_rays
    if kind not in RAY_KINDS:
        raise ValueError(f"unknown ray kind {kind!r}; kinds: {', '.join(RAY_KINDS)}")
    scene = scene if scene is not None else view_scene(view, size)
    o, d = camera_rays(scene.camera)
    if kind == "diffuse":
        primary = reference_trace(scene.vertices, scene.faces, o, d)
        o, d = diffuse_rays(scene, o, d, primary.t, primary.tri)
    step = max(1, -(-o.shape[0] // max(1, check_rays)))
    index = np.arange(0, o.shape[0], step)
    ref = reference_trace(scene.vertices, scene.faces, o[index], d[index])
    return RayBatch(view, kind, size, scene, o, d, index, ref)


@dataclass
class RaysRow:
    view: str
    kind: str
    size: int
    backend: str
    device: str
    variant: str
    rays: int
    median_ms: float
    mrays: float
    spread_ms: tuple[float, float]
    error: dict = field(default_factory=dict)
    render_mrays: float | None = None      # the render kernel on the same camera (primary rays)
    peer: dict | None = None

    @property
    def peer_ratio(self) -> float | None:
        return self.mrays / self.peer["best"] if self.peer else None

    @property
    def trace_over_render(self) -> float | None:
        return self.mrays / self.render_mrays if self.render_mrays else None

    def error_text(self) -> str:
        e = self.error
        if not e:
            return "-"
        return (f"{e['mismatches']} mism. / {e['rays']:,} checked, {e['ties']} ties, "
                f"max rel dt {e['t_rel_err_max']:.1e}")


def bench_rays(batch: RayBatch, backend, variant: Variant, repeats: int = 22, warmup: int = 3,
               render: bool = True) -> RaysRow:
    """Time ``trace`` on the batch (median device time of ``repeats`` launches after ``warmup``),
    check the subsample against the float64 reference, and for primary rays time the render kernel
    on the same camera (what trace should match)."""
    from ..device.tracing import resolve_variant, trace
    variant = resolve_variant(variant, backend, rays=True)
    # primary rays are an image: traced in tiles of the variant's block (trace's width=)
    width = batch.size if batch.kind == "primary" else None
    result = trace(batch.scene, batch.origins, batch.directions, backend, variant, repeats=repeats, warmup=warmup,
                   width=width)
    error = batch.error(result.tri, result.t)
    label = variant.label()
    if result.tile_order is not None:     # camera rays launched costliest tiles first: what ordering took
        label += f", costly tiles first (ordered in {result.tile_order.build_seconds * 1e3:.0f} ms)"
    row = RaysRow(batch.view, batch.kind, batch.size, backend.name, backend.device_name, label, batch.n,
                  result.kernel_ms, batch.n / (result.kernel_ms * 1e-3) / 1e6,
                  (float(min(result.launches_ms)), float(max(result.launches_ms))), error,
                  peer=peer_figures().get((batch.view, batch.kind, batch.size)))
    if render and batch.kind == "primary":
        from ..device.rendering import render as render_view
        timed = render_view(batch.scene, backend, variant, repeats=repeats, warmup=warmup)
        row.render_mrays = timed.mrays_per_s
    return row


COLUMNS = ("view", "kind", "size", "backend", "variant", "median ms", "Mrays/s", "render kernel Mrays/s",
           "trace / render", "best peer", "× best peer", "error vs float64 reference")


def table_rows(rows: list[RaysRow]) -> list[tuple[str, ...]]:
    """The rows as text cells under COLUMNS (for rich tables and markdown alike)."""
    out = []
    for r in rows:
        peer = f"{r.peer['best']:,} ({r.peer['best_name']})" if r.peer else "-"
        out.append((r.view, r.kind, f"{r.size}²", r.backend, r.variant, f"{r.median_ms:.3f}", f"{r.mrays:,.0f}",
                    f"{r.render_mrays:,.0f}" if r.render_mrays else "-",
                    f"{r.trace_over_render:.2f}" if r.trace_over_render else "-", peer,
                    f"{r.peer_ratio:.2f}" if r.peer_ratio else "-", r.error_text()))
    return out


def rays_tables(rows: list[RaysRow]) -> list[Table]:
    with_peer = [r for r in rows if r.peer]           # sizes and views the peers did not trace have none
    note = peer_note(r.device for r in with_peer) if with_peer else ""
    return [Table(COLUMNS, table_rows(rows), "rays through rtlab.trace", note=note)]


def rays_markdown(rows: list[RaysRow], command: str) -> str:
    return report_markdown("Rays through the trace API on the benchmark views", command,
                           [f"{r.backend}: {r.device}" for r in rows], rays_tables(rows))
