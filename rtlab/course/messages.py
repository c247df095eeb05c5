"""How the grader words what it found: paths of its own folders read as the student's, compiler
errors with file and line first, the unfinished functions a failing test uses, bounded notes."""
from __future__ import annotations

import os
import re
from pathlib import Path

MAX_NOTE = 2000          # characters of one note in the report


def _clean(text: str, roots: list[tuple[Path, str]]) -> str:
    """Paths of the grader's folders read as the student's: kernels/shared/rt_types.h:57:5."""
    from .checks import HARNESS_DIR
    # the longest first: the harness lies inside the checkout, whose own root reads as reference/
    for root, to in sorted([*roots, (HARNESS_DIR, "rtlab/course/harness/")], key=lambda r: -len(str(r[0]))):
        text = text.replace(str(root) + os.sep, to)
    return text


BUILD_RE = re.compile(r"^kernel (?P<file>\S+) failed to compile \(defines: (?P<defines>[^)]*)\):\s*$")
PLACE_RE = re.compile(r"^\s*(?P<sev>error|warning|fatal error):\s*(?P<place>\S+:\d+:\d+):\s*(?P<msg>.*)$")


def compile_message(text: str) -> str:
    """A KernelBuildError as a student reads it: file:line:col: error: message first, then what was built."""
    lines = text.splitlines()
    head = BUILD_RE.match(lines[0]) if lines else None
    body = []
    for ln in lines[1:] if head else lines:
        m = PLACE_RE.match(ln)
        body.append(f"  {m['place']}: {m['sev']}: {m['msg']}" if m else ln)
    out = ["does not compile:", *body]
    if head:
        out.append(f"(while building {head['file']} with {head['defines'] or 'no defines'})")
    return "\n".join(out)


def used_functions(programs: list[dict], tree: Path) -> set[str] | None:
    """Functions the kernels of ``programs`` call (through the tree's headers and macros under each
    program's defines); None when the process recorded no program."""
    from .cpp import Preprocessor
    if not programs:
        return None
    used: set[str] = set()
    for p in programs:
        try:
            pp = Preprocessor([Path(tree) / "shared"], p["defines"]).run(p["path"])
        except (OSError, RecursionError, ValueError):
            return None
        roots = p["kernels"] or pp.kernels()
        used |= pp.reachable(roots)
    return used


def note_text(note: str) -> str:
    return note if len(note) <= MAX_NOTE else note[:MAX_NOTE - 60] + f" ... ({len(note) - MAX_NOTE + 60:,} more characters cut)"


