"""The autograder graded on real submissions (tests/submissions/00_primary/): the reference gets full
marks, the template fails cleanly, and a submission that does not compile, one that crashes, one that
loops forever and one with an off-by-one in its traversal each get the expected score and message.

Each stored submission is a student's whole header files; before grading, its marked regions are
spliced into the current reference headers (rtlab.labs.splice_regions), so these tests follow
changes to the code around the student's functions. To keep this file fast on 2 cores, the broken
submissions are graded on the tests that tell their failure apart; RTLAB_GRADE_ALL=1 grades every
submission on every test.
"""
from __future__ import annotations

import json
import os
import re
import stat
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest

from rtlab.labs import LabError, grade, lab_names, load_config, splice_regions, stale_template_files, strip_regions
from rtlab.labs.checks import check_camera_rays, speed_score
from rtlab.labs.grader import build_trees, compile_message, find_submitted_file, template_text
from rtlab.labs.regions import find_regions, stubbed_functions
from rtlab.labs.results import gradescope_dict
from rtlab.nvcc import nvcc_available
from rtlab.paths import PROJECT_DIR

STEP = "00_primary"
SUBMISSIONS = Path(__file__).parent / "submissions" / STEP
GRADE_ALL = os.environ.get("RTLAB_GRADE_ALL") == "1"
CONFIG = load_config(STEP)
ALL_TESTS = [t.name for t in CONFIG.tests]
TRAVERSAL_TESTS = ["trace_random_rays", "trace_split_plane_rays", "render_default", "render_bunny"]

# Per submission: the tests graded by default, and what each test must come out as:
# (status, message pattern). Scores follow from the status (passed: full points, else 0).
EXPECTED = {
    # Speed against itself: a ratio near 1; a busy shared machine may cost a few points
    "reference": (ALL_TESTS, {t: ("passed", r"") for t in ALL_TESTS}
                  | {"speed_bunny": ("passed|partial", r"alternating on the same device: [\d.]+x the reference")}),
    "template": (["compile", "camera_rays", "trace_random_rays", "render_default", "speed_bunny"], {
        "compile": ("passed", r"compiles"),
        "camera_rays": ("failed", r"100\.0 % of pixels get a wrong direction .* expected \(.*\), got \(0, 0, 1\)"),
        **{t: ("failed", r"hit another triangle .*expected triangle \d+ at t = [\d.]+, got a miss") for t in TRAVERSAL_TESTS},
        "speed_bunny": ("skipped", r"needs render_default to pass first"),
    }),
    "compile_error": (["compile", "camera_rays"], {
        t: ("compile_error", r"does not compile:\n  kernels/shared/rt_types\.h:{line}:\d+: error: .*'dir'")
        for t in ALL_TESTS[:-1]} | {"speed_bunny": ("skipped", r"needs render_default")}),
    "crash": (["camera_rays", "trace_random_rays"], {
        "compile": ("passed", r""), "camera_rays": ("passed", r""),
        **{t: ("crashed", r"crashed while running its kernel: SIGSEGV") for t in TRAVERSAL_TESTS},
        "speed_bunny": ("skipped", r"needs render_default")}),
    "infinite_loop": (["trace_random_rays"], {
        "compile": ("passed", r""), "camera_rays": ("passed", r""),
        **{t: ("timeout", r"timed out: still running after [\d.]+ s .* killed") for t in TRAVERSAL_TESTS},
        "speed_bunny": ("skipped", r"needs render_default")}),
    "off_by_one": (["camera_rays", "trace_random_rays", "render_bunny"], {
        "compile": ("passed", r""), "camera_rays": ("passed", r""),
        **{t: ("failed", r"[\d.]+ % of (rays|pixels) hit another triangle \(\d+ of \d+\); first at .*: "
                         r"expected triangle \d+ at t = [\d.]+, got ") for t in TRAVERSAL_TESTS},
        "speed_bunny": ("skipped", r"needs render_default")}),
}
# Run-phase time limits are scaled down for the endless loop (the limit is what it costs)
TIME_SCALE = {"infinite_loop": 0.3}


def materialize(name: str, out: Path) -> Path:
    """The stored submission as a student hands it in: every lab file whole, the stored functions'
    regions spliced into the current reference files (same layout); a lab file the folder leaves
    out is the reference's, under its repository path."""
    src = SUBMISSIONS / name
    stored = {f.name: f for f in src.rglob("*.h")}
    for lab_file in CONFIG.files:
        reference = (PROJECT_DIR / lab_file.path).read_text()
        f = stored.get(Path(lab_file.path).name)
        dst = out / (f.relative_to(src) if f else lab_file.path)
        dst.parent.mkdir(parents=True, exist_ok=True)
        dst.write_text(splice_regions(reference, f.read_text(), str(f)) if f else reference)
    return out


_reports: dict = {}


def graded(name: str, tmp_path_factory):
    if name not in _reports:
        sub = materialize(name, tmp_path_factory.mktemp(name))
        tests = None if GRADE_ALL else EXPECTED[name][0]
        _reports[name] = (grade(STEP, sub, tests=tests, time_scale=TIME_SCALE.get(name, 1.0)), sub)
    return _reports[name]


@pytest.mark.parametrize("name", list(EXPECTED))
def test_submission_gets_expected_score_and_messages(name, tmp_path_factory):
    report, sub = graded(name, tmp_path_factory)
    expected = EXPECTED[name][1]
    assert report.tests, "no test ran"
    error_line = None
    if name == "compile_error":
        lines = (sub / "kernels/shared/rt_types.h").read_text().splitlines()
        error_line = next(i + 1 for i, ln in enumerate(lines) if "normalize3(dir)" in ln)
    for t in report.tests:
        status, pattern = expected[t.name]
        assert re.fullmatch(status, t.status), f"{name}/{t.name}: {t.status}, expected {status}: {t.output}"
        if t.status == "partial":
            assert t.score >= 0.75 * t.max_score, f"{name}/{t.name}: {t.output}"
        else:
            assert t.score == (t.max_score if t.status == "passed" else 0.0), f"{name}/{t.name}: {t.score}"
        pattern = pattern.replace("{line}", str(error_line))
        assert re.search(pattern, t.output, re.S), f"{name}/{t.name}: {t.output!r} !~ {pattern!r}"
    want = sum(t.max_score for t in report.tests if t.status == "passed")
    assert report.score >= want and report.score == sum(t.score for t in report.tests)
    if name == "reference" and (GRADE_ALL or "speed_bunny" in EXPECTED[name][0]):
        speed = report.test("speed_bunny")
        assert speed.data["reference_ms"] > 0 and speed.data["best_ms"] > 0
    if name == "template":
        assert any("camera_ray" in n and "stub" in n for n in report.notes)
        assert any("traverse_kd_stack" in n and "stub" in n for n in report.notes)


def test_reference_results_json_has_gradescope_fields(tmp_path_factory):
    report, _ = graded("reference", tmp_path_factory)
    data = json.loads(json.dumps(gradescope_dict(report)))
    assert data["max_score"] == CONFIG.max_score
    assert data["score"] >= CONFIG.max_score - 0.25 * CONFIG.test("speed_bunny").points
    assert isinstance(data["execution_time"], (int, float)) and data["execution_time"] > 0
    assert isinstance(data["output"], str)
    assert len(data["tests"]) == len(CONFIG.tests)
    for entry, spec in zip(data["tests"], CONFIG.tests):
        assert set(entry) >= {"name", "score", "max_score", "output", "visibility"}
        assert entry["name"] == spec.name and entry["max_score"] == spec.points
        assert entry["visibility"] in ("visible", "hidden", "after_due_date", "after_published")
        assert entry["visibility"] == spec.visibility
    assert abs(sum(e["score"] for e in data["tests"]) - data["score"]) < 1e-9
    assert {e["visibility"] for e in data["tests"]} >= {"visible", "after_due_date"}


def test_cli_grade_writes_gradescope_results(tmp_path):
    """`rtlab grade` as Gradescope's run_autograder calls it, on the submission that does not compile."""
    from rtlab.cli import main
    sub = materialize("compile_error", tmp_path / "sub")
    out = tmp_path / "results" / "results.json"
    rc = main(["grade", STEP, str(sub), "--tests", "compile", "--format", "gradescope", "--out", str(out)])
    assert rc == 0
    data = json.loads(out.read_text())
    assert data["score"] == 0 and data["max_score"] == 5
    [entry] = data["tests"]
    assert entry["name"] == "compile" and "kernels/shared/rt_types.h:" in entry["output"]


def test_cli_writes_results_when_it_cannot_grade(tmp_path):
    from rtlab.cli import main
    out = tmp_path / "results.json"
    rc = main(["grade", STEP, str(tmp_path / "no-such-folder"), "--out", str(out)])
    assert rc == 2
    data = json.loads(out.read_text())
    assert data["score"] == 0 and len(data["tests"]) == len(CONFIG.tests)
    assert all("not graded" in t["output"] for t in data["tests"])


@pytest.mark.parametrize("step", lab_names())
def test_committed_template_is_current(step):
    assert stale_template_files(step) == [], f"run `rtlab lab template {step}`"


# The other lab steps: the reference passes and the template fails one test of each student
# function family (RTLAB_GRADE_ALL=1: every test, and the reference must get full marks).
OTHER_LABS = {"01_memory": ["fetch_images", "cuda_textures", "cuda_shared_ray"], "02_intersect": ["loop_plucker"],
              "03_traversal": ["trace_restart"], "04_shadows": ["one_pass"], "05_kernel_tree": ["two_bounces"]}


@pytest.mark.parametrize("step", sorted(OTHER_LABS))
def test_other_lab_reference_passes_and_template_fails(step, tmp_path):
    if step not in lab_names():
        pytest.skip(f"lab {step} has no grading config")
    config = load_config(step)
    tests = None if GRADE_ALL else OTHER_LABS[step]
    if not nvcc_available():   # the CUDA compile checks (lab 01) skip: test_nvcc_test_skips_without_nvcc
        tests = [t.name for t in config.tests if t.kind != "nvcc" and (tests is None or t.name in tests)]
    ref = grade(step, PROJECT_DIR, tests=tests)
    assert ref.score == ref.max_score, [(t.name, t.status, t.output) for t in ref.tests if not t.passed]
    if GRADE_ALL and nvcc_available():
        assert ref.max_score == config.max_score
    from rtlab.labs import write_template
    write_template(step, tmp_path)         # as generated now (the committed one is checked above)
    tmpl = grade(step, tmp_path, tests=tests)
    for t in tmpl.tests:
        if t.name == "compile":
            assert t.passed, t.output
        else:
            assert t.status in ("failed", "skipped") and t.score == 0, (t.name, t.status, t.output)
    assert any("template's stub" in n for n in tmpl.notes)


def test_nvcc_test_skips_without_nvcc(monkeypatch):
    """Lab 01's CUDA compile check on a grading machine without the CUDA toolkit: skipped, 0 points,
    and it says why (never a pass, never a grader error)."""
    path = os.environ.get("PATH", "").split(os.pathsep)
    monkeypatch.setenv("PATH", os.pathsep.join(d for d in path if not (Path(d) / "nvcc").exists()))
    [t] = grade("01_memory", PROJECT_DIR, tests=["cuda_shared_ray"]).tests
    assert (t.status, t.score) == ("skipped", 0.0) and "nvcc" in t.output and "not on PATH" in t.output, t


def test_template_stubs_each_student_function_and_keeps_the_rest():
    for lf in CONFIG.files:
        ref = (PROJECT_DIR / lf.path).read_text()
        tmpl = template_text(CONFIG, lf.path, lf.functions)
        assert sorted(stubbed_functions(tmpl)) == sorted(lf.functions)
        # Outside the regions nothing changed: splicing the reference's bodies back gives the reference
        assert splice_regions(tmpl, ref) == ref
        assert f"TODO (lab {STEP})" in tmpl


def test_missing_file_is_graded_as_template(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "rt_types.h").write_text((PROJECT_DIR / "kernels/shared/rt_types.h").read_text())
    ref, sub, notes = build_trees(CONFIG, tmp_path / "sub", tmp_path / "work")
    assert any("rt_kdtree.h was not handed in" in n for n in notes)
    kd = (sub / "shared" / "rt_kdtree.h").read_text()
    assert stubbed_functions(kd) == ["traverse_kd_stack"]
    assert (sub / "shared" / "rt_types.h").read_text() == (PROJECT_DIR / "kernels/shared/rt_types.h").read_text()
    # the reference copy includes its own headers by absolute path (for the speed test's process)
    assert f'"{ref / "shared"}' in (ref / "opencl" / f"{STEP}.cl").read_text()


def test_find_submitted_file_by_path_or_name(tmp_path):
    (tmp_path / "a" / "kernels" / "shared").mkdir(parents=True)
    (tmp_path / "a" / "kernels" / "shared" / "rt_types.h").write_text("x")
    (tmp_path / "b" / "deep" / "er").mkdir(parents=True)
    (tmp_path / "b" / "deep" / "er" / "rt_types.h").write_text("y")
    assert find_submitted_file(tmp_path / "a", "kernels/shared/rt_types.h")[0].read_text() == "x"
    assert find_submitted_file(tmp_path / "b", "kernels/shared/rt_types.h")[0].read_text() == "y"
    assert find_submitted_file(tmp_path / "b", "kernels/shared/rt_kdtree.h") == (None, None)


def test_regions_errors_are_clear():
    good = "RT_FN int f(int a)\n{\n    /* BEGIN SOLUTION */\n    return a;\n    /* END SOLUTION */\n}\n"
    [r] = find_regions(good)
    assert (r.function, r.return_type, r.line) == ("f", "int", 3)
    assert "return 0;" in strip_regions(good, ["f"], "00_x")
    with pytest.raises(LabError, match="1 BEGIN SOLUTION but 0 END"):
        find_regions(good.replace("    /* END SOLUTION */\n", ""))
    with pytest.raises(LabError, match="no BEGIN SOLUTION region in g"):
        strip_regions(good, ["g"], "00_x")
    odd = good.replace("RT_FN int", "RT_FN Widget")
    with pytest.raises(LabError, match="STUB"):
        strip_regions(odd, ["f"], "00_x")
    own = odd.replace("/* BEGIN SOLUTION */\n", "/* BEGIN SOLUTION */\n    /* STUB: return make_widget(); */\n")
    assert "    return make_widget();\n" in strip_regions(own, ["f"], "00_x")


def test_config_errors_name_the_problem(tmp_path):
    base = ('step = "x"\n[[files]]\npath = "kernels/shared/rt_types.h"\nfunctions = ["camera_ray"]\n'
            '[[tests]]\nname = "a"\npoints = 1\n')
    cases = {'kind = "nope"': "unknown kind 'nope'",
             'kind = "render"\nrays = "random"': "kind 'render' takes no rays",
             'kind = "render"\nvisibility = "later"': "visibility must be one of",
             'kind = "render"\ntolerance = { psnr = 3 }': "unknown tolerance psnr",
             'kind = "render"\nrequires = ["b"]': "requires 'b', which is not an earlier test"}
    for extra, message in cases.items():
        p = tmp_path / "grading.toml"
        p.write_text(base + extra + "\n")
        with pytest.raises(LabError, match=re.escape(message)):
            load_config(p)


def test_compile_message_puts_file_and_line_first():
    raw = ("kernel kernels/opencl/00_primary.cl failed to compile (defines: -DRT_ISECT=0):\n"
           "  error: kernels/shared/rt_types.h:68:45: use of undeclared identifier 'dir'")
    assert compile_message(raw).splitlines() == [
        "does not compile:", "  kernels/shared/rt_types.h:68:45: error: use of undeclared identifier 'dir'",
        "(while building kernels/opencl/00_primary.cl with -DRT_ISECT=0)"]


def test_speed_score_is_relative():
    tol = {"full_ratio": 1.25, "zero_ratio": 3.0}
    assert speed_score(1.0, tol)[0] == 1.0
    assert speed_score(1.25, tol)[0] == 1.0
    assert speed_score(3.0, tol)[0] == 0.0
    assert speed_score(2.125, tol)[0] == pytest.approx(0.5)
    assert speed_score(float("nan"), tol)[0] == 0.0


def test_camera_check_names_the_mistake():
    """The camera test's hints, on host-made rays with a known mistake (no kernel needed)."""
    from rtlab.scene.model import Camera
    from rtlab.tracing import camera_rays
    cam = Camera(eye=(0.0, 1.0, 5.0), target=(0.0, 0.0, 0.0), width=40, height=24)
    o, d = camera_rays(cam)
    tol = {"direction_abs": 1e-5, "origin_rel": 1e-6}

    def as4(o, d):
        o4 = np.concatenate([o, np.zeros((len(o), 1), np.float32)], 1)
        d4 = np.concatenate([d, np.full((len(d), 1), np.inf, np.float32)], 1)
        with np.errstate(divide="ignore"):
            inv = np.concatenate([1 / d, np.zeros((len(d), 1), np.float32)], 1)
        return o4, d4, inv

    assert check_camera_rays(cam, *as4(o, d), (o, d), tol).fraction == 1.0
    flipped = d.reshape(24, 40, 3)[::-1].reshape(-1, 3)
    out = check_camera_rays(cam, *as4(o, flipped), (o, d), tol)
    assert out.fraction == 0.0 and "upside down" in out.output


def test_bundle_has_gradescope_scripts(tmp_path):
    from rtlab.labs.bundle import write_bundle
    from .conftest import require_scene_file
    require_scene_file("bunny.ply")
    zpath = write_bundle(STEP, tmp_path / "ag")
    root = zpath.parent
    for script in ("setup.sh", "run_autograder"):
        p = root / script
        assert p.stat().st_mode & stat.S_IXUSR
        subprocess.run(["bash", "-n", str(p)], check=True)
    run = (root / "run_autograder").read_text()
    assert f"rtlab grade {STEP} /autograder/submission" in run and "/autograder/results/results.json" in run
    assert "pocl-opencl-icd" in (root / "setup.sh").read_text()
    names = set(zipfile.ZipFile(zpath).namelist())
    assert {"setup.sh", "run_autograder", "pyproject.toml", f"labs/{STEP}/grading.toml",
            "kernels/shared/rt_types.h", "scenes/bunny.ply", "rtlab/labs/grader.py"} <= names
