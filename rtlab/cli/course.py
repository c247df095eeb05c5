"""The course's commands (rtlab.course):

    rtlab lab list | template STEP [--out DIR] | release OUT
    rtlab grade STEP SUBMISSION_DIR [--format gradescope|json|table] [--backend B] [--out results.json]
                [--secret-file F] [--deadline S] [--jobs N] [--require-full-marks]
    rtlab grade --bundle STEP [--out DIR]

Imports are lazy: registering costs nothing until a command runs.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape

from ..errors import RtlabError
from .common import console
lab_app = typer.Typer(no_args_is_help=True, help="Lab steps: list them, write their templates, make the student release.")


@lab_app.command("list")
def lab_list():
    """Lab steps with a grading config: tests, points, visibility."""
    from rich.table import Table
    from ..course.config import lab_names, load_config
    table = Table(title="rtlab lab steps")
    for col in ("step", "title", "files (functions)", "tests", "points"):
        table.add_column(col)
    for step in lab_names():
        c = load_config(step)
        files = "\n".join(f"{f.path} ({', '.join(f.functions)})" for f in c.files)
        tests = "\n".join(f"{t.name} [{t.kind}]" + ("" if t.visibility == "visible" else f" ({t.visibility})")
                          for t in c.tests)
        table.add_row(step, escape(c.title), escape(files), escape(tests), f"{c.max_score:g}")
    console.print(table)


@lab_app.command("template")
def lab_template(step: str = typer.Argument(..., help="lab step, e.g. 00_primary"),
                 out: Optional[Path] = typer.Option(None, help="folder to write (default STEP-template)")):
    """Write the step's template: the kernels' files of the step with the student's regions stubbed."""
    from ..course.template import write_template
    for p in write_template(step, out or Path(f"{step}-template")):
        console.print(f"wrote {p}")


@lab_app.command("release")
def lab_release(out: Path = typer.Argument(..., help="folder to write (new or empty)"),
                force: bool = typer.Option(False, "--force", help="replace the folder if it exists"),
                wheel: bool = typer.Option(False, "--wheel", help="also build the student wheel (OUT/dist), checked "
                                                                 "to hold no solution: what a notebook server installs")):
    """Write the student release: the project with every solution stubbed and the visible tests only.
    (A wheel or `pip install .` of the course's repository ships every solution: give students this.)"""
    from ..course.release import build_wheel, write_release
    from ..course.kernel_sources import tree_stubs
    path = write_release(out, force=force)
    n = sum(len(v) for v in tree_stubs(path / "kernels").values())
    console.print(f"wrote {path}/ (pyproject.toml, README.md, rtlab/, kernels/ with {n} functions stubbed, "
                  f"labs/ with visible tests, notebooks/): students `pip install -e {path}`")
    if wheel:
        whl = build_wheel(path)
        console.print(f"wrote {whl} (no solution in it): `pip install {whl.name}` on a notebook server")


# Why long: the command's options and what each of them asks for; the grading itself is rtlab.course.grader.
def grade_command(step: Optional[str] = typer.Argument(None, help="lab step, e.g. 00_primary"),
                  submission: Optional[Path] = typer.Argument(None, help="folder with the student's files"),
                  bundle: bool = typer.Option(False, "--bundle", help="write a Gradescope autograder for STEP instead"),
                  fmt: str = typer.Option("table", "--format", help="gradescope, json or table"),
                  backend: str = typer.Option("opencl", help="opencl (PoCL by default) or cuda"),
                  device: Optional[str] = typer.Option(None, help="device name substring or index"),
                  out: Optional[Path] = typer.Option(None, help="results file (bundle: the folder to write)"),
                  tests: Optional[str] = typer.Option(None, help="comma-separated test names (default: all)"),
                  jobs: Optional[int] = typer.Option(None, min=1, help="tests run at once (default: the CPUs this process "
                                                                "may use, as many as memory allows)"),
                  keep: bool = typer.Option(False, help="keep the work folder (trees, logs) for debugging"),
                  secret_file: Optional[Path] = typer.Option(None, help="seed of the hidden tests' rays (the "
                                                             "bundle's grading-secret; default: drawn for this run)"),
                  deadline: Optional[float] = typer.Option(None, help="seconds for the whole run (default: "
                                                           "grading.toml's deadline, 480)"),
                  require_full_marks: bool = typer.Option(False, "--require-full-marks",
                                                          help="exit with status 1 unless every point is scored "
                                                               "(the bundle's self-check of the reference)")):
    """Grade a submission on a lab step: each test in its own process, on PoCL unless told otherwise."""
    from ..course.results import FORMATS, report_table, write_report
    if bundle:
        if step is None:
            raise RtlabError("--bundle needs the lab step: rtlab grade --bundle 00_primary")
        from ..course.bundle import write_bundle
        zpath = write_bundle(step, out)
        console.print(f"wrote {zpath.parent}/ (setup.sh, run_autograder, rtlab, scenes) and {zpath}")
        return
    if step is None or submission is None:
        raise RtlabError("usage: rtlab grade STEP SUBMISSION_DIR (or rtlab grade --bundle STEP)")
    if fmt not in FORMATS:
        raise RtlabError(f"--format must be one of {', '.join(FORMATS)}, got '{fmt}'")
    from ..course.grader import grade, grading_failure_report
    quiet = fmt != "table" and out is None     # JSON goes to stdout: keep it clean
    status = console if not quiet else Console(stderr=True)

    def progress(t):
        status.print(f"  {t.name}: {t.score:g} / {t.max_score:g} ({t.status}, {t.seconds:.1f} s)")

    out_fmt = "json" if fmt == "json" else "gradescope"

    def on_update(partial):   # results after every test: a run killed from outside still reports
        if out is not None:
            write_report(partial, out, out_fmt)

    try:
        from ..course.fixtures import read_secret
        cap_grader_memory(step)
        secret = read_secret(secret_file) if secret_file else None
        report = grade(step, submission, backend=backend, device=device,
                       tests=[t for t in tests.split(",") if t.strip()] if tests is not None else None, jobs=jobs, keep=keep,
                       progress=progress, secret=secret, deadline=deadline, on_update=on_update)
    except Exception as e:  # the grader always writes results, even when it cannot grade
        report = grading_failure_report(step, submission, backend, e)
        if out is not None:
            write_report(report, out, out_fmt)
        if isinstance(e, RtlabError):
            raise
        raise RtlabError(f"grading failed: {type(e).__name__}: {e}") from e
    if out is not None:
        write_report(report, out, out_fmt)
    if quiet:
        from ..course.results import full_dict, gradescope_dict
        data = full_dict(report) if fmt == "json" else gradescope_dict(report)
        sys.stdout.write(json.dumps(data, indent=2, default=str) + "\n")
    else:
        console.print(report_table(report))
        for note in report.notes:
            console.print(f"note: {escape(note)}")
        if out is not None:
            console.print(f"wrote {out}")
    if require_full_marks and report.score < report.max_score:
        short = [f"{t.name} ({t.status}: {t.score:g} / {t.max_score:g})" for t in report.tests if t.score < t.max_score]
        Console(stderr=True).print(f"rtlab: not full marks ({report.score:g} / {report.max_score:g}): "
                                   + escape(", ".join(short)))
        raise typer.Exit(1)


def cap_grader_memory(step: str) -> None:
    """The grading process's own memory cap (grading.toml grader_memory_mb, RLIMIT_DATA): what a
    submission makes the grader read (its files, its outputs) cannot take the machine."""
    import resource
    from ..course.config import load_config
    limit = load_config(step).grader_memory_mb * 2 ** 20
    soft, hard = resource.getrlimit(resource.RLIMIT_DATA)
    if soft == resource.RLIM_INFINITY or soft > limit:
        resource.setrlimit(resource.RLIMIT_DATA, (limit, hard))


def register(app: typer.Typer) -> None:
    """Add the course commands to the main app."""
    app.add_typer(lab_app, name="lab")
    app.command("grade")(grade_command)
