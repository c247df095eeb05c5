"""The autograder graded on real submissions (tests/submissions/): the reference gets full marks, the
template fails cleanly, broken submissions (compile error, crash, endless loop, off by one) get the
expected score and message, and adversarial ones (includes of the reference by relative, absolute or
computed path, symlinks, a #define around a stub, a later step's function, speed gaming, a
preprocessor bomb) score at most the compile points. Files are taken as written (a Latin-1 comment
compiles; UTF-16 and empty files get a message). The student release holds no solution and lab 00
can be done from it; the Gradescope bundle grades in a simulated /autograder layout.

Each stored submission holds the student's functions (signature and marked region); before grading,
its regions are spliced into the current reference files (rtlab.course.splice_regions), so these tests
follow changes to the code around the student's functions. Submissions whose point is outside the
regions (an #include, a symlink, an encoding) are made here from the reference files. To keep this
file fast on 2 cores, each submission is graded on the tests that tell its outcome apart;
RTLAB_GRADE_ALL=1 grades every stored submission on every test.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from rtlab.backends.nvcc import nvcc_available
from rtlab.course import LabError, grade, lab_names, load_config, splice_regions, strip_regions
from rtlab.course.checks import check_camera_rays, speed_score
from rtlab.course.fixtures import hidden_seed, spec_for_run
from rtlab.course.grader import compile_message
from rtlab.course.processes import default_jobs
from rtlab.course.regions import STUBS, find_regions, stubbed_functions
from rtlab.course.results import gradescope_dict
from rtlab.course.submission import check_source, tree_rules
from rtlab.course.kernel_sources import (build_student_tree, find_submitted_file, kernel_files, region_owners, template_text,
                              tree_stubs)
from rtlab.paths import PROJECT_DIR

STEP = "00_primary"
SUBMISSIONS = Path(__file__).parent / "submissions"
GRADE_ALL = os.environ.get("RTLAB_GRADE_ALL") == "1"
CONFIG = load_config(STEP)
ALL_TESTS = [t.name for t in CONFIG.tests]
TRAVERSAL_TESTS = ["trace_random_rays", "trace_split_plane_rays", "render_default", "render_bunny"]
SPEED_MSG = r"\d+ pairs in random order on the same device, every launch checked: [\d.]+x the reference"

# Per submission: the tests graded by default, and what each test must come out as:
# (status, message pattern). Scores follow from the status (passed: full points, else 0).
EXPECTED = {
    # Speed against itself: a ratio near 1; a busy shared machine may cost a few points
    "reference": (ALL_TESTS, {t: ("passed", r"") for t in ALL_TESTS}
                  | {"speed_bunny": ("passed|partial", SPEED_MSG)}),
    "template": (["compile", "camera_rays", "trace_random_rays", "render_default", "speed_bunny"], {
        "compile": ("passed", r"compiles"),
        "camera_rays": ("failed", r"100\.0 % of pixels get a wrong direction .* expected \(.*\), got \(0, 0, 1\)"
                                  r".*note: camera_ray in kernels/shared/rt_types\.h still holds the template's stub"),
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
    # Counts its rays in the scene's memory and returns early once the first check is done: the old
    # grader checked only the first launch and gave it 15 / 15 at 0.01x the reference's time
    "speed_gaming": (["render_default", "speed_bunny"], {
        **{t: ("passed", r"") for t in ALL_TESTS[:-1]},
        "speed_bunny": ("failed", r"timed launch \d+ of \d+ .* does not match the reference kernel's output on the "
                                  r"same rays:\n[\d.]+ % of pixels hit another triangle \(\d+ of \d+\); first at "
                                  r".*: expected triangle \d+ at t = [\d.]+, got a miss")}),
}
# Run-phase time limits are scaled down for the endless loop (the limit is what it costs)
TIME_SCALE = {"infinite_loop": 0.3}


def materialize(name: str, out: Path, step: str = STEP) -> Path:
    """The stored submission as a student hands it in: every lab file whole, the stored functions'
    regions spliced into the current reference files (same layout); a stored file without regions
    as it is; a lab file the folder leaves out is the reference's, under its repository path."""
    src = SUBMISSIONS / step / name
    config = load_config(step)
    stored = {f.name: f for f in src.rglob("*") if f.suffix in (".h", ".cu")}
    for lab_file in config.files:
        reference = (PROJECT_DIR / lab_file.path).read_text()
        f = stored.get(Path(lab_file.path).name)
        dst = out / (f.relative_to(src) if f else lab_file.path)
        dst.parent.mkdir(parents=True, exist_ok=True)
        if f is not None and "BEGIN SOLUTION" not in f.read_text():
            shutil.copyfile(f, dst)
            continue
        dst.write_text(splice_regions(reference, f.read_text(), str(f)) if f else reference)
    return out


def assert_refused(report, why: dict) -> None:
    """Each test named in ``why`` scored 0, refused (its kernels never ran), with the message given."""
    for name, message in why.items():
        t = report.test(name)
        assert t.score == 0 and t.status == "refused" and message in t.output, (name, t.status, t.output)


def reference_files(step: str, out: Path) -> Path:
    """A submission of the reference's files of a lab, in the repository layout."""
    for lf in load_config(step).files:
        dst = out / lf.path
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(PROJECT_DIR / lf.path, dst)
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


def test_failing_test_notes_only_the_unfinished_functions_it_uses(tmp_path_factory):
    """The template: the camera test's note names camera_ray only, the traversal tests' notes name
    traverse_kd_stack only (trace_rays takes its rays as given), the render names both."""
    report, _ = graded("template", tmp_path_factory)
    notes = {t.name: t.output.split("note: ", 1)[1] for t in report.tests if "note: " in t.output}
    assert "camera_ray" in notes["camera_rays"] and "traverse_kd_stack" not in notes["camera_rays"]
    assert "traverse_kd_stack" in notes["trace_random_rays"] and "camera_ray " not in notes["trace_random_rays"]
    assert "camera_ray" in notes["render_default"] and "traverse_kd_stack" in notes["render_default"]
    assert "compile" not in notes


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


def test_require_full_marks_fails_below_full_marks(tmp_path):
    """The bundle's self-check (`--require-full-marks`): exit status 1 when a point is missing."""
    from rtlab.cli import main
    sub = materialize("template", tmp_path / "sub")
    assert main(["grade", STEP, str(sub), "--tests", "camera_rays", "--require-full-marks",
                 "--out", str(tmp_path / "r.json")]) == 1
    assert main(["grade", STEP, str(PROJECT_DIR), "--tests", "compile", "--require-full-marks",
                 "--out", str(tmp_path / "r.json")]) == 0


# --------------------------------------------------------------------------------------------------
# the tree a submission compiles in, templates, the rule on submitted files
# --------------------------------------------------------------------------------------------------
def test_every_solution_region_belongs_to_a_lab_and_no_lab_needs_a_later_one():
    """Each marked region is some lab's, and the pipeline every lab runs on (the default variant:
    camera, stack traversal, the given Moller-Trumbore test) needs no later step's solution: the
    student tree of a lab stubs the later steps without breaking it."""
    from rtlab.device.kernels import SceneFeatures, Variant, build_defines
    from rtlab.course.cpp import Preprocessor
    owners = region_owners()
    root = PROJECT_DIR / "kernels"
    for rel in kernel_files(root):
        for r in find_regions((PROJECT_DIR / rel).read_text(), rel):
            assert (rel, r.function) in owners, f"{rel}: {r.function} is in no lab's grading.toml"
    step_of = {f: s for (_, f), s in owners.items()}
    for step in lab_names():
        pp = Preprocessor([root / "shared"], build_defines(Variant.paper(), SceneFeatures())).run(
            root / "opencl" / f"{step}.cl")
        later = sorted(f for f in pp.reachable(pp.kernels()) if step_of.get(f, "") > step)
        assert not later, f"lab {step}'s kernels call later steps' {later}"


@pytest.mark.parametrize("step", lab_names())
def test_student_tree_stubs_this_and_later_steps_only(step, tmp_path):
    """Lab 00's tree must not hold lab 03's solutions; a lab's tree keeps earlier steps' reference."""
    config = load_config(step)
    tree = build_student_tree(config, tmp_path / "empty", tmp_path / "work")
    stubbed = {f for fs in tree_stubs(tree.root).values() for f in fs}
    for (rel, function), owner in region_owners().items():
        assert (function in stubbed) == (owner >= step), (rel, function, owner)
    assert sorted(p.name for p in tree.root.iterdir()) == ["cuda", "opencl", "shared"]
    assert all("was not handed in" in n for n in tree.notes) and len(tree.notes) == len(config.files)


@pytest.mark.parametrize("step", lab_names())
def test_generated_template_matches_the_reference(step):
    """Templates are generated from the reference: the lab's (and later labs') functions stubbed,
    everything else as in the reference (splicing the reference's bodies back gives it)."""
    config = load_config(step)
    owners = region_owners()
    for lf in config.files:
        ref = (PROJECT_DIR / lf.path).read_bytes().decode("latin-1")    # templates keep the bytes as they are
        tmpl = template_text(config, lf.path)
        later = {f for (rel, f), s in owners.items() if rel == lf.path and s > step}
        assert set(stubbed_functions(tmpl)) == set(lf.functions) | later
        assert splice_regions(tmpl, ref) == ref
        assert f"TODO (lab {step})" in tmpl


def test_missing_file_is_graded_as_template(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "rt_types.h").write_text((PROJECT_DIR / "kernels/shared/rt_types.h").read_text())
    tree = build_student_tree(CONFIG, tmp_path / "sub", tmp_path / "work")
    assert any("rt_kdtree.h was not handed in" in n for n in tree.notes)
    assert stubbed_functions((tree.root / "shared" / "rt_kdtree.h").read_text()) == ["traverse_kd_stack"]
    assert (tree.root / "shared" / "rt_types.h").read_text() == (PROJECT_DIR / "kernels/shared/rt_types.h").read_text()
    assert tree.stubs == {"kernels/shared/rt_kdtree.h": ["traverse_kd_stack"]}


def test_earlier_steps_in_a_submitted_file_are_the_reference(tmp_path):
    """A lab 05 rt_whitted.h as a student of the release hands it in (lab 04's functions are theirs,
    here still stubs): lab 05 is graded on spawn_* alone, with the reference's lab 04 functions."""
    config = load_config("05_kernel_tree")
    rel = "kernels/shared/rt_whitted.h"
    student = template_text(load_config("04_shadows"), rel)            # lab 04 and 05 stubbed
    student = splice_regions(student, (PROJECT_DIR / rel).read_bytes().decode("latin-1"), rel,
                             functions=["spawn_reflection", "spawn_refraction"])
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "rt_whitted.h").write_bytes(student.encode("latin-1"))
    tree = build_student_tree(config, tmp_path / "sub", tmp_path / "work")
    assert tree_stubs(tree.root).get(rel) is None
    assert (tree.root / "shared" / "rt_whitted.h").read_bytes() == (PROJECT_DIR / rel).read_bytes()
    assert any("light_visible, shade_local in kernels/shared/rt_whitted.h" in n for n in tree.notes), tree.notes


def test_find_submitted_file_by_path_or_name(tmp_path):
    (tmp_path / "a" / "kernels" / "shared").mkdir(parents=True)
    (tmp_path / "a" / "kernels" / "shared" / "rt_types.h").write_text("x")
    (tmp_path / "b" / "deep" / "er").mkdir(parents=True)
    (tmp_path / "b" / "deep" / "er" / "rt_types.h").write_text("y")
    assert find_submitted_file(tmp_path / "a", "kernels/shared/rt_types.h")[0].read_text() == "x"
    assert find_submitted_file(tmp_path / "b", "kernels/shared/rt_types.h")[0].read_text() == "y"
    assert find_submitted_file(tmp_path / "b", "kernels/shared/rt_kdtree.h") == (None, None)
    # a linked folder is not entered
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "kernels").symlink_to(tmp_path / "a" / "kernels")
    assert find_submitted_file(tmp_path / "c", "kernels/shared/rt_types.h") == (None, None)


RULES = None


def _rules():
    global RULES
    if RULES is None:
        from rtlab.course.checks import HARNESS_DIR
        RULES = tree_rules(PROJECT_DIR / "kernels", sorted(HARNESS_DIR.glob("*")))
    return RULES


# (what a submitted rt_kdtree.h holds, a part of the refusal or None when it is allowed)
RULE_CASES = [
    ('#include "rt_port.h"\n', None),
    ('#include "rt_kd_restart.h"\n', None),                                  # a lab header: its later step is stubbed
    ('#pragma once\n#pragma unroll 4\n#pragma OPENCL EXTENSION cl_khr_fp64 : enable\n', None),
    ('#define MY_HELPER(x) ((x) + 1)\n#undef MY_HELPER\n', None),
    ('#define KD_LEAF 3\n', None),                                            # the reference rt_kdtree.h defines it
    ('// a comment: #include "/etc/passwd" and __asm__\n/* #include <stdio.h> */\n', None),
    ('const char *s = "#include \\"/x.h\\"";\n', None),
    ('/* caf\xe9 au lait (Latin-1) */\n', None),
    ('#if defined(RT_TRAVERSAL) && RT_TRAVERSAL == 0\n#error "x"\n#endif\n', None),
    ('#include "../../reference/kernels/shared/rt_kdtree.h"\n', "names a path"),
    ('#include "/autograder/source/kernels/shared/rt_kdtree.h"\n', "names a path"),
    ('#include "rt_kdtree.h" // ok\n#include "shared\\\\rt_port.h"\n', "names a path"),
    ('#include <stdio.h>\n', "#include <...>"),
    ('#define REF "rt_port.h"\n#include REF\n', "computed include"),
    ('#inc\\\nlude "/x/rt_port.h"\n', "names a path"),                           # a line splice
    ('#inc\\  \nlude "/x/rt_port.h"\n', "names a path"),                         # a splice with spaces
    ('# /* a comment */ include "/x/rt_port.h"\n', "names a path"),
    ('#\\\n  include\\\n "/x/rt_port.h"\n', "names a path"),
    ('%:include "/x/rt_port.h"\n', "names a path"),                             # a digraph
    ('??=include "/x/rt_port.h"\n', "trigraph"),
    ('/* ??/\n*/ int x;\n', "trigraph"),
    ('#include_next "rt_port.h"\n', "#include_next is not allowed"),
    ('#import "rt_port.h"\n', "#import is not allowed"),
    ('#embed "rt_port.h"\n', "#embed is not allowed"),
    ('#line 1 "rt_port.h"\n', "#line is not allowed"),
    ('# 1 "rt_port.h"\n', "line marker"),
    ('#if __has_include("/etc/passwd")\n#endif\n', "__has_include"),
    ('#pragma clang diagnostic ignored "-Wall"\n', "#pragma clang is not allowed"),
    ('_Pragma("once")\n', "_Pragma"),
    ('void f(void) { __asm__ volatile("syscall"); }\n', "inline assembly"),
    ('void f(void) { asm("nop"); }\n', "inline assembly"),
    ('#define RT_TRAVERSAL 0\n', "RT_TRAVERSAL is used by"),
    ('#undef RT_TRAVERSAL\n', "RT_TRAVERSAL is used by"),
    ('#define traverse_kd_restart traverse_kd_stack\n', "traverse_kd_restart is used by"),
    ('#define intersect_leaf my_leaf\n', "intersect_leaf is used by"),
    ('#define get_global_id(i) 0\n', "get_global_id is used by"),
    ('#define CAT(a, b) a ## b\n', "token pasting"),
    ('void f(void) { void *p = __builtin_return_address(0); }\n', "__builtin_return_address"),
    ('#define CAT(a, b) a %:%: b\n', "token pasting"),
    ('const char *s = R"x(\n#include "/x/rt_port.h"\n)x";\n', "raw string"),
    ('int n = 1\'000;\n', "digit separator"),
    ("int c = 'a;\n", "not closed on its line"),
    ('/* never closed\n#include "/x/rt_port.h"\n', "never closed"),
]


@pytest.mark.parametrize("text,why", RULE_CASES, ids=[f"case{i}" for i in range(len(RULE_CASES))])
def test_rule_on_submitted_files(text, why):
    problems = check_source(text, "kernels/shared/rt_kdtree.h", _rules())
    if why is None:
        assert problems == [], problems
    else:
        assert problems, f"not refused: {text!r}"
        assert any(why in p.reason for p in problems), [str(p) for p in problems]
        assert all(p.line and p.path == "kernels/shared/rt_kdtree.h" for p in problems)


def test_rule_allows_every_reference_file():
    """The reference's own files pass the rule they are graded by."""
    for step in lab_names():
        for lf in load_config(step).files:
            text = (PROJECT_DIR / lf.path).read_bytes().decode("latin-1")
            assert check_source(text, lf.path, _rules()) == [], lf.path


def test_refusals_name_file_and_line_and_unreadable_files(tmp_path):
    """Empty, UTF-16 and linked files are refused with a message; a refused file stands in the tree
    as an #error so that exactly the kernels including it fail."""
    sub = tmp_path / "sub" / "kernels" / "shared"
    sub.mkdir(parents=True)
    (sub / "rt_types.h").write_text("")
    (sub / "rt_kdtree.h").write_bytes((PROJECT_DIR / "kernels/shared/rt_kdtree.h").read_text().encode("utf-16"))
    tree = build_student_tree(CONFIG, tmp_path / "sub", tmp_path / "w1")
    assert [str(r) for r in tree.refused["kernels/shared/rt_types.h"]] == ["kernels/shared/rt_types.h: file is empty"]
    assert "UTF-16" in str(tree.refused["kernels/shared/rt_kdtree.h"][0])
    assert (tree.root / "shared" / "rt_types.h").read_text().startswith("#error")
    (sub / "rt_types.h").unlink()
    (sub / "rt_types.h").symlink_to(PROJECT_DIR / "kernels/shared/rt_types.h")
    (sub / "rt_kdtree.h").write_text('#include "rt_port.h"\n#include "../../../kernels/shared/rt_kdtree.h"\n')
    tree = build_student_tree(CONFIG, tmp_path / "sub", tmp_path / "w2")
    assert "symbolic link" in str(tree.refused["kernels/shared/rt_types.h"][0])
    [r] = tree.refused["kernels/shared/rt_kdtree.h"]
    assert (r.line, r.path) == (2, "kernels/shared/rt_kdtree.h") and "names a path" in r.reason
    (sub / "rt_types.h").unlink()
    os.link(sub / "rt_kdtree.h", sub / "rt_types.h")
    tree = build_student_tree(CONFIG, tmp_path / "sub", tmp_path / "w3")
    assert "hard link" in str(tree.refused["kernels/shared/rt_types.h"][0])


# --------------------------------------------------------------------------------------------------
# adversarial submissions, graded
# --------------------------------------------------------------------------------------------------
def _without_region_body(text: str, function: str, step: str, rel: str) -> str:
    return strip_regions(text, [function], step, rel)


def test_lab03_cheats_score_nothing(tmp_path):
    """Lab 03 with each header a different way to the reference (the old grader gave 100 / 100 to the
    first alone): a relative include, a #define of the traversal name to lab 00's stack traversal,
    a symlink, a computed include behind a line splice; and an empty file. Every test that compiles
    one of them scores 0 and names the file and line; the total is at most the compile points. (An
    absolute include: test_bundle_in_a_simulated_gradescope_layout.)"""
    step = "03_traversal"
    sub = tmp_path / "sub"
    materialize("cheats", sub, step)           # rt_kd_restart.h, rt_kd_shortstack.h, rt_packet.h stored
    ropes = sub / "kernels/shared/rt_kd_ropes.h"
    ropes.unlink()
    ropes.symlink_to(PROJECT_DIR / "kernels/shared/rt_kd_ropes.h")
    (sub / "kernels/shared/rt_bvh.h").write_text("")
    tests = ["compile", "trace_restart", "trace_shortstack", "trace_ropes", "trace_packet", "trace_bvh"]
    report = grade(step, sub, tests=tests)
    config = load_config(step)
    assert report.score <= config.test("compile").points
    why = {"trace_restart": r"rt_kd_restart\.h:\d+: #include \"\.\./\.\./reference/.*\" names a path",
           "trace_shortstack": r"rt_kd_shortstack\.h:\d+: #define traverse_kd_shortstack: .* is used by",
           "trace_ropes": r"rt_kd_ropes\.h: is a symbolic link",
           "trace_packet": r"rt_packet\.h:\d+: #include REF: a computed include",
           "trace_bvh": r"rt_bvh\.h: file is empty"}
    for t in report.tests:
        assert t.score == 0, (t.name, t.output)
        if t.name in why:
            assert t.status == "refused" and re.search(why[t.name], t.output), (t.name, t.output)
    assert report.test("compile").status == "refused"


def _calling_instead(text: str, function: str, step: str, rel: str, call: str, before: str = "") -> str:
    """``text`` with ``function``'s solution replaced by ``call`` (and ``before`` put ahead of the function)."""
    text = _without_region_body(text, function, step, rel)
    pattern = rf"(/\* TODO \(lab {step}\): write {function} here.*?\*/\n)\s*return;"
    out = re.sub(pattern, lambda m: m.group(1) + "    " + call, text, flags=re.S)
    assert call in out
    head = f"RT_FN void {function}("
    return out.replace(head, before + head, 1)


def test_lab03_traversals_that_call_other_lab_functions_score_nothing(tmp_path):
    """Lab 03's traversals that call lab 00's finished traverse_kd_stack (67 / 100 before the lab-call
    rule), directly, through a helper of their own with an attribute after its parameters, through a
    macro of their own, or one lab 03 traversal calling another: every test that compiles one scores 0
    and names the path of calls; bvh, written, passes."""
    step = "03_traversal"
    sub = reference_files(step, tmp_path / "sub")
    args = "RT_SCENE_ARGS, scene_min, scene_max, ray, hit, any_hit"
    forged = {
        "rt_kd_restart.h": ("traverse_kd_restart", f"traverse_kd_stack({args});", ""),
        "rt_kd_shortstack.h": ("traverse_kd_shortstack", f"walk_for_me({args});",
                               "RT_FN void walk_for_me(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, "
                               "const Ray *ray, Hit *hit, int any_hit) __attribute__((overloadable))\n"
                               f"{{ traverse_kd_stack({args}); }}\n\n"),
        "rt_kd_ropes.h": ("traverse_kd_ropes", f"MY_WALK({args});", "#define MY_WALK traverse_kd_stack\n"),
        "rt_packet.h": ("traverse_kd_packet", "if (valid) traverse_kd_restart(RT_SCENE_ARGS, scene_min, scene_max, "
                        "ray, hit, any_hit);", '#include "rt_kd_restart.h"\n'),
    }
    for name, (function, call, before) in forged.items():
        path = sub / "kernels/shared" / name
        path.write_text(_calling_instead(path.read_text(), function, step, f"kernels/shared/{name}", call, before))
    report = grade(step, sub, tests=["trace_restart", "trace_shortstack", "trace_ropes", "trace_packet", "trace_bvh"])
    why = {"trace_restart": "traverse_kd_restart calls traverse_kd_stack, the function lab 00_primary grades",
           "trace_shortstack": "traverse_kd_shortstack calls traverse_kd_stack (through walk_for_me)",
           "trace_ropes": "traverse_kd_ropes calls traverse_kd_stack, the function lab 00_primary grades",
           "trace_packet": "traverse_kd_packet calls traverse_kd_restart, the function lab 03_traversal grades"}
    assert_refused(report, why)
    assert report.test("trace_bvh").passed, report.test("trace_bvh").output


def test_lab_call_rule_reads_the_compilers_call_graph(tmp_path):
    """The rule's two halves on their own: the reference's allowance (what lab 03's traversals may call:
    the triangle tests, never another traversal), and the call graph clang builds for a program, which
    sees a call through a macro, a static helper and an attribute, names mangled or not."""
    from rtlab.course.deps import opencl_ir
    from rtlab.course.lab_calls import ir_call_graph, lab_call_problem, lab_call_rules, source_name
    rules = lab_call_rules("03_traversal")
    assert set(rules["allowed"]) == {"traverse_kd_restart", "traverse_kd_shortstack", "traverse_kd_ropes",
                                     "traverse_kd_packet", "traverse_bvh"}
    for allowed in rules["allowed"].values():
        assert "intersect_ray_tri_watertight" in allowed and not any(f.startswith("traverse") for f in allowed)
    assert source_name("_Z17traverse_kd_stackPU3AS1Dv4_f") == "traverse_kd_stack" and source_name("f.1") == "f"
    src = tmp_path / "k.cl"
    src.write_text("#define GO(x) lab_b(x)\n"
                   "static float lab_b(float x) { return x * 2.0f; }\n"
                   "static float hide(float x) __attribute__((overloadable)) { return GO(x); }\n"
                   "static float lab_a(float x) { return hide(x) + 1.0f; }\n"
                   "__kernel void k(__global float *o) { o[0] = lab_a(o[0]); }\n")
    graph = ir_call_graph(opencl_ir(src, [tmp_path], {}))
    assert graph["k"] >= {"lab_a"} and graph["lab_a"] >= {"hide"} and graph["hide"] >= {"lab_b"}
    owners = {"lab_a": "01", "lab_b": "00"}
    problem = lab_call_problem(graph, {"owners": owners, "allowed": {"lab_a": []}})
    assert problem and problem.startswith("lab_a calls lab_b (through hide), the function lab 00 grades")
    assert lab_call_problem(graph, {"owners": owners, "allowed": {"lab_a": ["lab_b"]}}) is None


BRUTE_FORCE_BVH = """int stack[4096];
    int sp = 0;
    stack[sp++] = 0;
    while (sp > 0) {
        int ref = stack[--sp];
        if (ref >= 0) {
            float4 c = NODE_ROW(BVH_NODE_STRIDE * ref + 3);
            stack[sp++] = rt_as_int(c.x);
            stack[sp++] = rt_as_int(c.y);
        } else {
            LEAF
        }
    }"""
LOADER_LEAF = "intersect_bvh_leaf(RT_SCENE_ARGS, ref, ray, hit, any_hit);"
RAW_LEAF = """int bits = ~ref, first = bits >> BVH_LEAF_BITS, count = bits & ((1 << BVH_LEAF_BITS) - 1);
            for (int i = 0; i < count; ++i) {
#if RT_BVH_LEAF_TRIS
                RT_GLOBAL const float4 *r = (RT_GLOBAL const float4 *)tri_data + 3 * (first + i);
                intersect_tri_vertices(ray, xyz(r[0]), xyz(r[1]), xyz(r[2]), rt_as_int(r[0].w), hit);
#else
                int tri = ((RT_GLOBAL const int *)objects)[first + i];
                RT_GLOBAL const float4 *v = (RT_GLOBAL const float4 *)tris + 3 * tri;
                intersect_tri_vertices(ray, xyz(v[0]), xyz(v[1]), xyz(v[2]), tri, hit);
#endif
            }"""


@pytest.mark.parametrize("form, status, message", [
    # the old grader passed all three (10 / 10): the budget read counters the kernel can reach
    ("zeroed", "refused", "rt_work is the work budget's counter"),
    ("probed", "ok", "on the rays it was checked on it reads"),
    ("raw", "ok", "read triangle data 0 times through the lab's loaders"),
])
def test_lab03_brute_force_that_hides_from_the_work_budget_scores_nothing(tmp_path, form, status, message):
    """A brute-force traverse_bvh (every node, every leaf) that hides its reads: by zeroing its own
    counters, by walking only when the launch is larger than the probe's, or by reading the scene
    through raw pointers past the counting loaders. Its hits are right; its trace test scores 0."""
    step, rel = "03_traversal", "kernels/shared/rt_bvh.h"
    sub = reference_files(step, tmp_path / "sub")
    walk = BRUTE_FORCE_BVH.replace("LEAF", RAW_LEAF if form == "raw" else LOADER_LEAF)
    row = "((RT_GLOBAL const float4 *)node_data)[{}]" if form == "raw" else "load_node_data(node_data, {})"
    walk = re.sub(r"NODE_ROW\((.*?)\);", lambda m: row.format(m.group(1)) + ";", walk)
    body = {"zeroed": walk + "\n#if RT_COUNT_WORK\n    rt_work[2 + 2 * rt_imin((int)rt_item_index(), "
                             "(int)rt_work[0] - 1)] = 0u;\n#endif\n",
            "probed": "if (get_global_size(0) * get_global_size(1) <= 1024)\n        return;\n    " + walk,
            "raw": walk}[form]
    path = sub / rel
    path.write_text(_calling_instead(path.read_text(), "traverse_bvh", step, rel, body))
    t = grade(step, sub, tests=["trace_bvh"]).test("trace_bvh")
    assert t.score == 0 and message in t.output, t.output
    if status == "ok":      # the hits themselves were right: only the budget failed it
        assert "every ray" in t.output or "but on" in t.output, t.output


def test_a_stub_that_returns_no_hit_is_not_taken_for_a_raw_reader(tmp_path):
    """The floor of one counted triangle read a hit counts the hits the kernel returned: the template's
    stub (every ray a miss) fails on its hits, not with "reads the scene some other way"."""
    t = grade(STEP, materialize("template", tmp_path / "sub"), tests=["trace_random_rays"]).test("trace_random_rays")
    assert t.score == 0 and "past the loaders" not in t.output and "got a miss" in t.output, t.output


def test_later_step_function_is_a_stub_in_lab00(tmp_path):
    """Lab 00 whose traverse_kd_stack calls lab 03's traverse_kd_restart (≈ 98 / 100 with the old
    grader): the lab-call rule refuses it (and lab 03's solution is not in lab 00's tree either)."""
    sub = reference_files(STEP, tmp_path / "sub")
    kd = sub / "kernels/shared/rt_kdtree.h"
    text = _without_region_body(kd.read_text(), "traverse_kd_stack", STEP, "kernels/shared/rt_kdtree.h")
    text = text.replace("/* Single ray with a per-thread stack", '#include "rt_kd_restart.h"\n\n/* Single ray with a per-thread stack')
    text = re.sub(r"(/\* TODO \(lab 00_primary\).*?\*/\n)\s*return;",
                  r"\1    traverse_kd_restart(RT_SCENE_ARGS, scene_min, scene_max, ray, hit, any_hit);", text)
    assert "traverse_kd_restart(RT_SCENE_ARGS" in text
    kd.write_text(text)
    report = grade(STEP, sub, tests=["compile", "trace_random_rays", "render_default"])
    for name in ("compile", "trace_random_rays", "render_default"):
        t = report.test(name)
        assert t.score == 0 and "traverse_kd_stack calls traverse_kd_restart" in t.output, t.output


def test_compile_test_stands_for_every_kernel_the_tests_build(tmp_path):
    """Lab 03's compile test builds the packet kernels; a syntax error in the ropes header shows in
    the ropes test, and the compile test fails with it (the old one passed)."""
    step = "03_traversal"
    sub = reference_files(step, tmp_path / "sub")
    ropes = sub / "kernels/shared/rt_kd_ropes.h"
    ropes.write_text(ropes.read_text().replace("/* BEGIN SOLUTION */", "/* BEGIN SOLUTION */\n    int oops = ;", 1))
    report = grade(step, sub, tests=["compile", "trace_restart", "trace_ropes"])
    assert report.test("trace_restart").passed
    assert report.test("trace_ropes").status == "compile_error"
    c = report.test("compile")
    assert (c.status, c.score) == ("compile_error", 0) and "the kernel of test trace_ropes does not build" in c.output
    assert re.search(r"kernels/shared/rt_kd_ropes\.h:\d+:\d+: error", c.output), c.output


def test_latin1_and_utf16_files(tmp_path):
    """A correct rt_types.h with a Latin-1 comment scores what its code earns; a UTF-16 rt_kdtree.h is
    refused with a message, and only the tests whose kernels include it lose their points."""
    sub = reference_files(STEP, tmp_path / "sub")
    types = sub / "kernels/shared/rt_types.h"
    types.write_bytes(types.read_bytes().replace(b"/* BEGIN SOLUTION */", b"/* BEGIN SOLUTION */ /* caf\xe9 */", 1))
    kd = sub / "kernels/shared/rt_kdtree.h"
    latin1 = kd.read_bytes().replace(b"/* BEGIN SOLUTION */", b"/* BEGIN SOLUTION */\n    /* r\xe9f\xe9rence */", 1)
    kd.write_bytes(latin1)
    report = grade(STEP, sub, tests=["camera_rays", "trace_random_rays"])
    assert all(t.passed for t in report.tests), [(t.name, t.output) for t in report.tests]
    kd.write_bytes(latin1.decode("latin-1").encode("utf-16"))
    report = grade(STEP, sub, tests=["camera_rays", "trace_random_rays"])
    assert report.test("camera_rays").passed
    t = report.test("trace_random_rays")
    assert (t.status, t.score) == ("refused", 0) and "rt_kdtree.h: is not an 8-bit text file (UTF-16" in t.output


BOMB = "".join(["#define RT_BOMB0 1,\n"] + [f"#define RT_BOMB{i} RT_BOMB{i - 1} RT_BOMB{i - 1}\n" for i in range(1, 40)]
               + ["__constant int rt_bomb[] = {RT_BOMB30 0};\n"])


def _custom_config(tmp_path: Path, **defaults) -> Path:
    """lab 00's grading.toml with other [defaults] limits, as a file `rtlab grade` takes."""
    text = CONFIG.path.read_text()
    for key, value in defaults.items():
        text = re.sub(rf"^{key} = .*$", f"{key} = {value}", text, flags=re.M)
    p = tmp_path / "lab" / "grading.toml"
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text)
    return p


@pytest.mark.parametrize("limit", ["time", "memory"])
def test_preprocessor_bomb_is_stopped_within_its_limits(limit, tmp_path):
    """A macro that expands to 2^30 tokens in rt_types.h (the old grader: 8.5 GB and 120 s a test):
    stopped by the setup limit or by the memory limit, whichever the config makes first, with a
    valid results.json written through the CLI."""
    from rtlab.cli import main
    sub = reference_files(STEP, tmp_path / "sub")
    types = sub / "kernels/shared/rt_types.h"
    types.write_text(types.read_text() + BOMB)
    config = _custom_config(tmp_path, setup_limit=6 if limit == "time" else 60,
                            memory_limit_mb=4096 if limit == "time" else 600)
    out = tmp_path / "results.json"
    t0 = time.monotonic()
    assert main(["grade", str(config), str(sub), "--tests", "compile,camera_rays", "--jobs", "2",
                 "--format", "gradescope", "--out", str(out)]) == 0
    seconds = time.monotonic() - t0
    data = json.loads(out.read_text())
    assert data["score"] == 0 and [t["name"] for t in data["tests"]] == ["compile", "camera_rays"]
    for t in data["tests"]:
        if limit == "time":
            assert "stopped after 6 s compiling a kernel" in t["output"], t["output"]
        else:
            assert "ran out of memory" in t["output"] and "600 MB" in t["output"], t["output"]
    assert seconds < (40 if limit == "time" else 90)


def test_run_deadline_scores_what_is_left_zero(tmp_path):
    """Past the run's deadline, tests not started score 0 with a message; the report is handed on
    after every test (results.json as the run goes)."""
    updates = []
    report = grade(STEP, PROJECT_DIR, tests=["compile", "camera_rays", "trace_random_rays"], jobs=1, deadline=0.5,
                   on_update=lambda r: updates.append([t.status for t in r.tests]))
    for t in report.tests:
        assert t.score == 0 and t.status == "timeout" and "deadline" in t.output, (t.name, t.output)
    assert updates[0] == ["pending"] * 3 and updates[-1] == ["timeout"] * 3 and len(updates) >= 4


def test_killed_run_leaves_valid_results(tmp_path):
    """results.json is replaced after every test: a run killed from outside (Gradescope's limit)
    still reports the tests it finished, the others at 0."""
    out = tmp_path / "results.json"
    env = dict(os.environ, PYTHONPATH=str(PROJECT_DIR))
    proc = subprocess.Popen([sys.executable, "-m", "rtlab", "grade", STEP, str(PROJECT_DIR), "--jobs", "1",
                             "--tests", "compile,camera_rays,trace_random_rays,render_default", "--out", str(out)],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if out.is_file() and json.loads(out.read_text())["score"] > 0:
                break
            time.sleep(0.2)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    data = json.loads(out.read_text())
    assert 0 < data["score"] < 65 and len(data["tests"]) == 4
    assert any("stopped before this test finished" in t["output"] for t in data["tests"])


def test_jobs_follow_the_cpus_and_memory_this_process_may_use(monkeypatch):
    from rtlab.course import processes
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3, 4, 5, 6, 7})
    files = {"/sys/fs/cgroup/cpu.max": "300000 100000", "/proc/meminfo": "MemTotal:       67108864 kB",
             "/sys/fs/cgroup/memory.max": "max"}
    monkeypatch.setattr(processes, "_read", lambda path: files.get(path, ""))
    assert processes.available_cpus() == 3
    assert default_jobs(2048) == 3
    files["/sys/fs/cgroup/memory.max"] = str(int(5.5 * 2 ** 30))   # two tests of 2 GB beside the grader and its reference
    assert default_jobs(2048) == 2
    files["/sys/fs/cgroup/cpu.max"] = "max 100000"
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    assert processes.available_cpus() == 1 and default_jobs(512) == 1


def test_hidden_tests_draw_their_rays_from_the_secret():
    """A hidden test's seed comes from the bundle's secret (another one without it); visible tests keep
    the config's."""
    from rtlab.course.checks import KINDS
    from rtlab.course.fixtures import grading_scene
    hidden = CONFIG.test("trace_split_plane_rays")
    visible = CONFIG.test("trace_random_rays")
    assert spec_for_run(visible, "a" * 32) == visible
    s1, s2 = spec_for_run(hidden, "a" * 32), spec_for_run(hidden, "b" * 32)
    assert s1.params["seed"] == hidden_seed("a" * 32, hidden.name) != s2.params["seed"] != hidden.params["seed"]
    scene = grading_scene(hidden.scene, hidden.size)
    rays = [KINDS["trace_rays"].prepare(s, scene).inputs["origins"] for s in (hidden, s1, s2)]
    assert not np.array_equal(rays[0], rays[1]) and not np.array_equal(rays[1], rays[2])


def test_sponza_flat_cells_catch_the_textbook_restart(tmp_path):
    """kd-restart taking the far child at ties steps over flat cells: the SPONZA 128x128 render
    catches it (8 wrong pixels with the kd-tree before flat cells, when it passed every other test;
    with flat cells in the builder, the random rays catch it too)."""
    from .conftest import require_scene_file
    require_scene_file("sponza/sponza.obj")
    sub = materialize("restart_far_at_ties", tmp_path / "sub", "03_traversal")
    report = grade("03_traversal", sub, tests=["render_sponza_restart"])
    t = report.test("render_sponza_restart")
    assert t.score == 0 and re.search(r"of pixels hit another triangle \(\d+ of 16384\)", t.output), t.output


# --------------------------------------------------------------------------------------------------
# the other lab steps: the reference passes, the template fails
# --------------------------------------------------------------------------------------------------
# One test of each student function family (RTLAB_GRADE_ALL=1: every test, and the reference must get
# full marks).
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
    from rtlab.course import write_template
    write_template(step, tmp_path)
    tmpl = grade(step, tmp_path, tests=tests)
    for t in tmpl.tests:
        if t.name == "compile":
            assert t.passed, t.output
        else:
            assert t.status in ("failed", "skipped") and t.score == 0, (t.name, t.status, t.output)
    assert any("template's stub" in t.output for t in tmpl.tests)


def test_nvcc_test_skips_without_nvcc(monkeypatch):
    """Lab 01's CUDA compile check on a grading machine without the CUDA toolkit: skipped, 0 points,
    and it says why (never a pass, never a grader error)."""
    path = os.environ.get("PATH", "").split(os.pathsep)
    monkeypatch.setenv("PATH", os.pathsep.join(d for d in path if not (Path(d) / "nvcc").exists()))
    [t] = grade("01_memory", PROJECT_DIR, tests=["cuda_shared_ray"]).tests
    assert (t.status, t.score) == ("skipped", 0.0) and "nvcc" in t.output and "not on PATH" in t.output, t


def test_template_stubs_each_student_function_and_keeps_the_rest():
    for lf in CONFIG.files:
        ref = (PROJECT_DIR / lf.path).read_bytes().decode("latin-1")
        tmpl = template_text(CONFIG, lf.path)
        assert sorted(stubbed_functions(tmpl)) == sorted(lf.functions)
        assert splice_regions(tmpl, ref) == ref
        assert f"TODO (lab {STEP})" in tmpl


# --------------------------------------------------------------------------------------------------
# the student release and the Gradescope bundle
# --------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def release(tmp_path_factory):
    from rtlab.course import write_release
    return write_release(tmp_path_factory.mktemp("release") / "rtlab-student")


def test_release_holds_no_solution(release):
    """Every BEGIN/END SOLUTION region in the release holds a stub; no hidden test, no hidden test's
    parameter, no speed test in its grading configs; no tests, submissions or secrets."""
    regions = 0
    for f in release.rglob("*"):
        if not f.is_file() or f.suffix not in (".h", ".cu", ".cl", ".py", ".md", ".toml"):
            continue
        text = f.read_bytes().decode("latin-1")
        if "BEGIN SOLUTION */" not in text or f.suffix not in (".h", ".cu", ".cl"):
            continue
        for r in find_regions(text, str(f)):
            regions += 1
            body = [ln.strip() for ln in r.body(text).splitlines() if ln.strip()]
            # the TODO line, then the stub: the region's own (/* STUB: X */ then X) or its type's
            assert body[0].startswith("/* TODO (lab "), (f, r.function, body)
            if body[1].startswith("/* STUB: "):
                assert body[1:] == [body[1], body[1][len("/* STUB: "):-len(" */")]], (f, r.function, body)
            else:
                assert len(body) == 2 and body[1] in STUBS.values(), (f, r.function, body)
    from rtlab.course.kernel_sources import COURSE_REGIONS
    assert regions == sum(len(lf.functions) for s in lab_names() for lf in load_config(s).files) + len(COURSE_REGIONS)
    assert not (release / "tests").exists() and not list(release.rglob("grading-secret"))
    for step in lab_names():
        text = (release / "labs" / step / "grading.toml").read_text()
        config = load_config(release / "labs" / step / "grading.toml")
        assert config.tests and all(t.visibility == "visible" and t.kind != "speed" for t in config.tests)
        for t in load_config(step).tests:
            if t.visibility != "visible":
                assert f'"{t.name}"' not in text
    assert (release / "pyproject.toml").is_file() and (release / "rtlab" / "course" / "grader.py").is_file()
    assert (release / "notebooks").is_dir() and "student release" in (release / "README.md").read_text()


def test_lab00_from_the_release_reaches_full_marks(release, tmp_path):
    """A student with the release writes lab 00 in a copy of its kernels (here: the reference's
    regions pasted in) and grades it with the release's own rtlab: full marks of its visible tests.
    Lab 03 then runs on the student's own lab 00 (the release has no reference for it). The release
    cannot make a Gradescope bundle; render says which tree it compiles and which stubs it runs."""
    mine = tmp_path / "mykernels"
    shutil.copytree(release / "kernels", mine)
    for lf in CONFIG.files:
        f = mine / Path(lf.path).relative_to("kernels")
        f.write_text(splice_regions(f.read_text(), (PROJECT_DIR / lf.path).read_text()))
    env = dict(os.environ, PYTHONPATH=str(release))
    env.pop("RTLAB_KERNEL_DIR", None)

    def rtlab(*args, **extra_env):      # wide enough that no path is wrapped
        return subprocess.run([sys.executable, "-m", "rtlab", *map(str, args)], env={**env, "COLUMNS": "400",
                                                                                     **extra_env},
                              capture_output=True, text=True, cwd=tmp_path)

    r = rtlab("grade", STEP, mine, "--out", tmp_path / "r00.json", "--require-full-marks")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    data = json.loads((tmp_path / "r00.json").read_text())
    assert data["score"] == data["max_score"] == load_config(release / "labs" / STEP / "grading.toml").max_score
    r = rtlab("grade", "--bundle", STEP, "--out", tmp_path / "ag")
    assert r.returncode == 2 and "student release" in r.stderr and "Traceback" not in r.stderr
    r = rtlab("render", "default", "--size", 16, "--out", tmp_path / "r.png", "--traversal", "restart",
              "--isect", "moller", RTLAB_KERNEL_DIR=str(mine))
    out = " ".join(r.stdout.split())
    assert r.returncode == 0 and f"kernel sources: {mine} (from $RTLAB_KERNEL_DIR)" in out, out
    assert "calls traverse_kd_restart, still a stub" in out and "camera_ray," not in out, out
    # The course's rtlab rendering the student's tree (--kernels)
    r = rtlab("render", "default", "--size", 16, "--out", tmp_path / "r.png", "--traversal", "ropes",
              "--kernels", mine, PYTHONPATH=str(PROJECT_DIR))
    out = " ".join(r.stdout.split())
    assert r.returncode == 0 and f"kernel sources: {mine} (from --kernels)" in out
    assert "calls traverse_kd_ropes, still a stub" in out, out
    # Lab 03 in the same tree runs on the student's camera (lab 00)
    f = mine / "shared/rt_packet.h"
    f.write_text(splice_regions(f.read_text(), (PROJECT_DIR / "kernels/shared/rt_packet.h").read_text()))
    rtlab("grade", "03_traversal", mine, "--tests", "render_packet", "--out", tmp_path / "r03.json", "--format", "json")
    data = json.loads((tmp_path / "r03.json").read_text())
    assert data["score"] == 10, data
    assert any(n.startswith("camera_ray, traverse_kd_stack (kernels/shared") or "camera_ray (kernels/shared/rt_types.h)"
               in n for n in data["notes"]), data["notes"]


def _bundle(tmp_path) -> Path:
    from rtlab.course.bundle import write_bundle
    from .conftest import require_scene_file
    require_scene_file("bunny.ply")
    return write_bundle(STEP, tmp_path / "ag")


def test_bundle_has_gradescope_scripts(tmp_path):
    zpath = _bundle(tmp_path)
    root = zpath.parent
    for script in ("setup.sh", "run_autograder"):
        p = root / script
        assert p.stat().st_mode & stat.S_IXUSR
        subprocess.run(["bash", "-n", str(p)], check=True)
    run = (root / "run_autograder").read_text()
    assert f"grade {STEP} \"$ROOT/submission\"" in run and "results/results.json" in run
    assert "--secret-file" in run
    setup = (root / "setup.sh").read_text()
    assert "pocl-opencl-icd" in setup and "--require-full-marks" in setup
    names = set(zipfile.ZipFile(zpath).namelist())
    assert {"setup.sh", "run_autograder", "pyproject.toml", f"labs/{STEP}/grading.toml", "grading-secret",
            "AUTOGRADER.md", "kernels/shared/rt_types.h", "scenes/bunny.ply", "rtlab/course/grader.py"} <= names
    assert not any("/template/" in n for n in names)
    readme = (root / "AUTOGRADER.md").read_text()
    assert "Memory:" in readme and "Time:" in readme and "MB" in readme
    other = _bundle(tmp_path / "again")
    assert (other.parent / "grading-secret").read_text() != (root / "grading-secret").read_text()


def test_bundle_in_a_simulated_gradescope_layout(tmp_path):
    """run_autograder with /autograder/{source,submission,results} under a temporary root: the
    reference gets full marks, a submission that includes the reference gets at most the compile
    points, and results.json is Gradescope's."""
    zpath = _bundle(tmp_path)
    root = tmp_path / "autograder"
    with zipfile.ZipFile(zpath) as z:
        z.extractall(root / "source")
    for script in ("run_autograder", "setup.sh"):
        (root / "source" / script).chmod(0o755)
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    rtlab_cmd = venv / "bin" / "rtlab"     # the bundle's own rtlab, as the venv of setup.sh would run it
    rtlab_cmd.write_text(f'#!/usr/bin/env bash\nPYTHONPATH="{root / "source"}" exec "{sys.executable}" -m rtlab "$@"\n')
    rtlab_cmd.chmod(0o755)
    env = dict(os.environ, AUTOGRADER_ROOT=str(root), RTLAB_VENV=str(venv))
    env.pop("RTLAB_KERNEL_DIR", None)

    def run(files: dict) -> dict:
        shutil.rmtree(root / "submission", ignore_errors=True)
        shutil.rmtree(root / "results", ignore_errors=True)
        (root / "submission").mkdir()
        for name, text in files.items():              # Gradescope delivers an upload flat
            (root / "submission" / name).write_bytes(text.encode("latin-1"))
        subprocess.run(["bash", str(root / "source" / "run_autograder")], env=env, check=True,
                       capture_output=True, cwd=tmp_path)
        return json.loads((root / "results" / "results.json").read_text())

    ref = run({Path(lf.path).name: (PROJECT_DIR / lf.path).read_text() for lf in CONFIG.files})
    speed = next(t for t in ref["tests"] if t["name"] == "speed_bunny")
    assert all(t["score"] == t["max_score"] for t in ref["tests"] if t["name"] != "speed_bunny"), ref
    assert speed["score"] >= 0.75 * speed["max_score"] and ref["max_score"] == 100
    cheat = run({"rt_types.h": '#include "../source/kernels/shared/rt_types.h"\n',
                 "rt_kdtree.h": f'#include "{root}/source/kernels/shared/rt_kdtree.h"\n'})
    assert cheat["score"] <= CONFIG.test("compile").points
    assert all("refused" in t["output"] for t in cheat["tests"] if t["score"] == 0 and t["name"] != "speed_bunny")
    # the sandbox's adversaries, each with the template's camera_ray: at most the compile points
    bom = b"\xef\xbb\xbf".decode("latin-1")
    adversaries = {"byte-order mark": {
        "rt_types.h": f'{bom}#include "{root}/source/kernels/shared/rt_types.h"\n',
        "rt_kdtree.h": f'{bom}#include "{root}/source/kernels/shared/rt_kdtree.h"\n'}}
    for name in ("exhaustive_walk", "wild_pointers"):
        stored = materialize(name, tmp_path / name)
        adversaries[name] = {"rt_types.h": template_text(CONFIG, "kernels/shared/rt_types.h"),
                             "rt_kdtree.h": next(stored.rglob("rt_kdtree.h")).read_text()}
    for name, files in adversaries.items():
        got = run(files)
        assert got["score"] <= CONFIG.test("compile").points, (name, got)


# --------------------------------------------------------------------------------------------------
# small parts
# --------------------------------------------------------------------------------------------------
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
             'kind = "render"\nrequires = ["b"]': "requires 'b', which is not an earlier test",
             'kind = "render"\n[defaults]\nmemory_limit_mb = -1': "memory_limit_mb must be a positive number"}
    for extra, message in cases.items():
        p = tmp_path / "grading.toml"
        p.write_text(base + extra + "\n")
        with pytest.raises(LabError, match=re.escape(message)):
            load_config(p)


def test_grade_arguments_that_select_nothing_are_errors(tmp_path):
    """`--tests ,` graded nothing and passed (0 / 0, even with --require-full-marks); `--deadline 0`
    became grading.toml's 480 s and -1 was taken; a file given as the submission was "a folder that
    does not exist"."""
    (tmp_path / "sub").mkdir()
    (tmp_path / "file.h").write_text("int x;\n")
    with pytest.raises(LabError, match="no test named: choose from compile"):
        grade(STEP, tmp_path / "sub", tests=[])
    for bad in (0, -1):
        with pytest.raises(LabError, match="deadline must be a positive number of seconds"):
            grade(STEP, tmp_path / "sub", deadline=bad)
    with pytest.raises(LabError, match="is not a folder"):
        grade(STEP, tmp_path / "file.h")
    from rtlab.cli import main
    assert main(["grade", STEP, str(tmp_path / "sub"), "--tests", ","]) != 0


def test_harness_paths_read_as_the_harness_in_a_checkout():
    """The harness lies inside the checkout, whose root reads as reference/: its own files read as
    rtlab/course/harness/..., not as reference/rtlab/course/harness/... (a path that does not exist)."""
    from rtlab.course.checks import HARNESS_DIR
    from rtlab.course.messages import _clean
    from rtlab.paths import PROJECT_DIR
    text = f"{HARNESS_DIR}/camera_rays.cl:3:1: error: x; {PROJECT_DIR}/kernels/shared/rt_types.h:5:1"
    cleaned = _clean(text, [(PROJECT_DIR, "reference/")])
    assert "rtlab/course/harness/camera_rays.cl:3:1" in cleaned and "reference/rtlab" not in cleaned
    assert "reference/kernels/shared/rt_types.h:5:1" in cleaned


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
    from rtlab.scene.model import camera_rays
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
