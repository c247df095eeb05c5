"""Writing a grading report: Gradescope's results.json, a fuller JSON, and a table for people.

Gradescope's format (https://gradescope-autograders.readthedocs.io/en/latest/specs/): top-level
score, execution_time, output, visibility, tests[] with name, score, max_score, status, output,
visibility. ``max_score`` is added at the top level for other readers.
"""
from __future__ import annotations

import json
from pathlib import Path

from .grader import GradeReport

FORMATS = ("gradescope", "json", "table")


def gradescope_dict(report: GradeReport) -> dict:
    header = (f"rtlab lab {report.step}: {report.score:g} / {report.max_score:g} points "
              f"on {report.backend} ({report.device or 'no device'}), {report.execution_time:.1f} s")
    out = {
        "score": round(report.score, 3),
        "max_score": round(report.max_score, 3),
        "execution_time": round(report.execution_time, 2),
        "output": "\n".join([header, *report.notes]),
        "visibility": "visible",
        "stdout_visibility": "hidden",
        "tests": [],
    }
    for i, t in enumerate(report.tests, 1):
        out["tests"].append({
            "name": t.name,
            "number": str(i),
            "score": round(t.score, 3),
            "max_score": round(t.max_score, 3),
            "status": "passed" if t.passed else "failed",
            "output": t.output,
            "visibility": t.visibility,
        })
    return out


def full_dict(report: GradeReport) -> dict:
    d = gradescope_dict(report)
    d.update({"step": report.step, "submission": report.submission, "backend": report.backend,
              "device": report.device, "notes": report.notes})
    for entry, t in zip(d["tests"], report.tests):
        entry.update({"result": t.status, "seconds": t.seconds, "data": t.data})
    return d


MAX_RESULTS_BYTES = 1 << 20      # results.json stays under 1 MB whatever a submission makes the grader say


def bounded_json(data: dict, limit: int = MAX_RESULTS_BYTES) -> str:
    """``data`` as JSON of at most ``limit`` bytes: outputs and notes cut shorter until it fits."""
    text = json.dumps(data, indent=2, default=_jsonable) + "\n"
    for keep in (4000, 1000, 200):
        if len(text.encode()) <= limit:
            return text
        for t in data.get("tests", []):
            if len(t.get("output", "")) > keep:
                t["output"] = t["output"][:keep] + " ... (cut)"
            t.pop("data", None)
        data["output"] = data.get("output", "")[:keep * 4]
        data.pop("notes", None)
        text = json.dumps(data, indent=2, default=_jsonable) + "\n"
    return text


def write_report(report: GradeReport, path, fmt: str = "gradescope") -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = gradescope_dict(report) if fmt == "gradescope" else full_dict(report)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(bounded_json(data))
    tmp.replace(path)
    return path


def _jsonable(x):
    try:
        return float(x)
    except (TypeError, ValueError):
        return str(x)


STATUS_STYLE = {"passed": "green", "partial": "yellow", "failed": "red", "compile_error": "red", "refused": "red",
                "crashed": "red", "timeout": "red", "memory": "red", "error": "magenta", "skipped": "dim",
                "pending": "dim"}


def report_table(report: GradeReport):
    from rich.markup import escape
    from rich.table import Table
    table = Table(title=f"lab {report.step}: {report.score:g} / {report.max_score:g} "
                        f"({report.backend}, {report.device or '-'}, {report.execution_time:.1f} s)",
                  show_lines=True)
    for col, kw in (("test", {}), ("points", {"justify": "right"}), ("result", {}), ("s", {"justify": "right"}),
                    ("output", {"overflow": "fold"})):
        table.add_column(col, **kw)
    for t in report.tests:
        style = STATUS_STYLE.get(t.status, "")
        vis = "" if t.visibility == "visible" else f"\n[dim]({t.visibility})[/]"
        table.add_row(f"{escape(t.name)}{vis}", f"{t.score:g} / {t.max_score:g}", f"[{style}]{t.status}[/]",
                      f"{t.seconds:.1f}", escape(t.output))
    return table
