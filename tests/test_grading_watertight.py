"""Lab 02's watertightness test (trace_edges_watertight): rays aimed at shared edges and vertices of the
default scene's closed meshes, from far away and at grazing angles, each of which must hit one of the
triangles that meet there. Before it, Moller-Trumbore pasted into intersect_ray_tri_watertight got
100 / 100: the other tests compare hits by compare_hits, whose rule (b) takes a miss, or a triangle
behind, near an edge for a tie, and none aims at shared edges. Here the reference gets full marks,
the pasted Moller-Trumbore and the template's stub none, with a message that counts the leaks.
"""
from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np

from rtlab.course import grade, load_config, write_template
from rtlab.course.regions import find_regions
from rtlab.paths import PROJECT_DIR

STEP = "02_intersect"
TEST = "trace_edges_watertight"
INTERSECT_H = "kernels/shared/rt_intersect.h"
LEAK_MSG = (r"[\d.]+ % of rays aimed at shared edges and vertices of closed meshes leaked through the surface "
            r"\((?P<leaks>\d+) of (?P<rays>\d+): .*\); a watertight test hits one of the triangles that meet "
            r"where a ray crosses; first at ray \d+ from \(.*\) along \(.*\): expected one of triangles [\d, ]+ "
            r"\(the reference: triangle \d+ at t = [\d.]+\), got ")


def reference_submission(out: Path) -> Path:
    """The reference's files of lab 02, in the repository layout."""
    for lab_file in load_config(STEP).files:
        dst = out / lab_file.path
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(PROJECT_DIR / lab_file.path, dst)
    return out


def moller_as_watertight(text: str) -> str:
    """rt_intersect.h with the given Moller-Trumbore's body pasted into intersect_ray_tri_watertight's
    region: watertight on no mesh, right nearly everywhere else."""
    moller = re.search(r"^RT_FN int intersect_ray_tri_moller\([^)]*\)\n\{\n(.*?)^\}\n", text, re.S | re.M)
    assert moller, "intersect_ray_tri_moller not found in the reference"
    region = next(r for r in find_regions(text, INTERSECT_H) if r.function == "intersect_ray_tri_watertight")
    body = "    /* Moller-Trumbore, pasted: not the watertight test */\n" + moller.group(1)
    return text[:region.body_start] + body + text[region.body_end:]


def graded(sub: Path):
    report = grade(STEP, sub, tests=[TEST])
    assert [t.name for t in report.tests] == [TEST]
    return report.test(TEST)


def test_config_weighs_watertightness_and_totals_100():
    config = load_config(STEP)
    spec = config.test(TEST)
    assert spec.kind == "trace_rays" and spec.params["rays"] == "edges" and spec.params["intersection"] == "watertight"
    assert spec.visibility == "visible" and spec.points > 0
    assert config.max_score == 100


def test_edge_rays_keep_their_answers_in_the_grader():
    """The test process gets the scene and the rays; the triangles around each target (the answers)
    stay with the grader. Every ray's float64 reference hit is one of them, the rays come from far
    away (2..200 scene extents), some at grazing angles, half at vertices (fans of 5-6 triangles on
    the icospheres) and half at edges (two triangles)."""
    from rtlab.course.checks import KINDS
    from rtlab.course.fixtures import grading_scene
    spec = load_config(STEP).test(TEST)
    scene = grading_scene(spec.scene, spec.size)
    prepared = KINDS["trace_rays"].prepare(spec, scene)
    assert set(prepared.inputs) == {"scene", "origins", "directions"}
    o, d = prepared.inputs["origins"], prepared.inputs["directions"]
    fans, ref = prepared.expected["fans"], prepared.expected["ref"]
    n = int(spec.params["count"])
    assert o.shape == d.shape == (n, 3) and o.dtype == d.dtype == np.float32 and len(ref) == n
    assert ((fans == ref.tri[:, None]) & (fans >= 0)).any(axis=1).all()
    sizes = (fans >= 0).sum(axis=1)
    assert set(np.unique(sizes)) <= {2, 5, 6} and 0.4 < np.mean(sizes == 2) < 0.6
    lo, hi = scene.bounds().astype(np.float64)
    extent = float((hi - lo).max())
    assert ref.t.min() > 1.5 * extent and ref.t.max() > 20 * extent
    # the cosine between each ray and its triangle's normal: a good share below 0.1
    v = scene.vertices.astype(np.float64)[scene.faces[ref.tri]]
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    cos = np.abs(np.einsum("ij,ij->i", normal, d)) / np.linalg.norm(normal, axis=1)
    assert np.mean(cos < 0.1) > 0.25
    # same seed, same rays
    again = KINDS["trace_rays"].prepare(spec, scene)
    assert np.array_equal(again.inputs["origins"], o) and np.array_equal(again.expected["fans"], fans)


def test_closed_meshes_only():
    """Targets lie on closed meshes only: an icosphere's edges and vertices, not those of an open grid
    beside it (its border leaves the ray a way out)."""
    import trimesh
    from rtlab.course.checks.edges import closed_mesh_targets
    sphere = trimesh.creation.icosphere(subdivisions=1)
    xs = np.arange(4.0)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    grid_v = np.stack([gx.ravel() + 5.0, gy.ravel(), np.zeros(gx.size)], 1)
    idx = lambda i, j: i * 4 + j
    grid_f = np.array([t for i in range(3) for j in range(3)
                       for t in ([idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)], [idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)])])
    n_sv, n_sf = len(sphere.vertices), len(sphere.faces)
    v = np.concatenate([sphere.vertices, grid_v]).astype(np.float32)
    f = np.concatenate([sphere.faces, grid_f + n_sv])
    _, _, edges, edge_faces, verts, fan_start, fan_faces = closed_mesh_targets(v, f)
    assert len(edges) == len(sphere.edges_unique) and edge_faces.max() < n_sf and edges.max() < n_sv
    assert np.array_equal(verts, np.arange(n_sv))
    assert all(fan_start[i + 1] - fan_start[i] in (5, 6) for i in verts)


def test_reference_scores_full_marks(tmp_path):
    t = graded(reference_submission(tmp_path))
    assert t.status == "passed" and t.score == t.max_score, t.output
    assert t.data["leaks"] == 0 and t.data["mismatches"] == 0, t.output
    assert re.match(r"all 2000 rays aimed at shared edges and vertices hit the expected triangle", t.output), t.output


def test_pasted_moller_trumbore_scores_nothing(tmp_path):
    """Float32 Moller-Trumbore leaks on about a quarter of these rays (551 of 2000 on PoCL); the
    leaks go on to the far side of the sphere or torus, which compare_hits alone took for ties."""
    sub = reference_submission(tmp_path)
    path = sub / INTERSECT_H
    path.write_text(moller_as_watertight(path.read_text()))
    t = graded(sub)
    assert t.status == "failed" and t.score == 0, t.output
    m = re.match(LEAK_MSG, t.output)
    assert m, t.output
    assert int(m["leaks"]) == t.data["leaks"] >= 0.01 * int(m["rays"]), t.output


def test_template_scores_nothing(tmp_path):
    write_template(STEP, tmp_path)
    t = graded(tmp_path)
    assert t.status == "failed" and t.score == 0, t.output
    m = re.match(LEAK_MSG, t.output)
    assert m and m["leaks"] == m["rays"] and "2000 missed" in t.output, t.output
    assert "intersect_ray_tri_watertight" in t.output and "template's stub" in t.output, t.output

