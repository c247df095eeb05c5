"""Constants the kernels and the host share, read from the kernels' own headers: one source.

The variant codes (``RT_TRAVERSAL_BVH``...), the ray-tree sentinels (``RT_NO_RAY``), the layout
constants of the host-built structures (``BVH_LEAF_BITS``, ``WBVH_NODE_VECTORS``...) and the packet width
(``RT_LANES``: the default the headers list) are ``#define``s in
``kernels/shared/*.h``. This module reads every object-like ``#define`` of :data:`HEADERS` whose value is
a constant expression (numbers, other such names, arithmetic) once, on first use, so that a code
changed in a header changes on the host too: no table to keep in sync by hand.

    from rtlab.kernel_constants import kernel_constant
    kernel_constant("RT_TRAVERSAL_BVH")      # 5

Read from the reference kernels (``rtlab.paths.REFERENCE_KERNEL_DIR``), not kernel sources swapped in
for a submission: these headers hold no student code, and the host's meaning of a code must not
depend on a student's copy. Imports nothing from rtlab but ``paths``, so every layer may use it.
"""
from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

from . import settings
from .cexpr import ExprError, evaluate, tokens
from .errors import RtlabError
from .paths import REFERENCE_KERNEL_DIR

# The headers whose #defines the host reads (kernels/shared/)
HEADERS = ("rt_port.h", "rt_intersect.h", "rt_kdtree.h", "rt_kd_ropes.h", "rt_bvh.h", "rt_bvh8.h", "rt_bvh4.h",
           "rt_bvh_packet.h", "rt_bvh_wide.h", "rt_lanes.h", "rt_shade.h", "rt_whitted.h", "rt_light_buffer.h")

_DIRECTIVE_RE = re.compile(r"^[ \t]*#[ \t]*(\w+)[ \t]*(.*?)[ \t]*$")
_COMMENT_RE = re.compile(r"/\*.*?\*/|//[^\n]*", re.S)


def _evaluate(expression: str, known: dict[str, int | float]) -> int | float | None:
    """The value of a C constant expression over numbers and ``known`` names, or None when it is
    anything else (a qualifier, a call, a cast...)."""
    try:
        return evaluate(tokens(expression.strip()), known)
    except ExprError:
        return None


def parse_defines(text: str, known: dict[str, int | float] | None = None) -> dict[str, int | float]:
    """Object-like ``#define NAME value`` lines of a C source whose value is a constant expression:
    those outside any conditional but an include guard or their own ``#ifndef NAME`` default (one
    under ``#if`` is a variant's, not the constant's). A later one may use an earlier one."""
    out: dict[str, int | float] = dict(known or {})
    lines = _COMMENT_RE.sub(lambda m: "\n" * m.group(0).count("\n") or " ", text).splitlines()
    open_ifs: list[str | None] = []     # per open conditional: the name of an #ifndef, else None
    for line in lines:
        m = _DIRECTIVE_RE.match(line)
        if not m:
            continue
        word, rest = m.groups()
        if word in ("if", "ifdef"):
            open_ifs.append(None)
        elif word == "ifndef":
            open_ifs.append(rest.split()[0] if rest else None)
        elif word in ("elif", "else") and open_ifs:
            open_ifs[-1] = None
        elif word == "endif" and open_ifs:
            open_ifs.pop()
        elif word == "define":
            name, _, body = rest.partition(" ")
            if not re.fullmatch(r"[A-Za-z_]\w*", name) or name in out:
                continue                     # a function-like macro, or defined already
            guards = [g for g in open_ifs if g != name]
            if any(g is None or not g.endswith("_H") for g in guards):
                continue
            v = _evaluate(body, out)
            if v is not None:
                out[name] = v
    return out


# A grading test process reads no reference file (they hold the solutions): the grader hands it the
# table as JSON in this file instead (rtlab.course.grader).
CONSTANTS_FILE_ENV = "RTLAB_KERNEL_CONSTANTS"


@lru_cache(maxsize=1)
def kernel_constants(shared_dir: Path = REFERENCE_KERNEL_DIR / "shared") -> dict[str, int | float]:
    """Every constant #define of :data:`HEADERS`, by name."""
    import json
    given = settings.get(CONSTANTS_FILE_ENV)
    if given:
        table = json.loads(Path(given).read_text())
        return {str(k): v for k, v in table.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
    known: dict[str, int | float] = {}
    for header in HEADERS:
        path = Path(shared_dir) / header
        try:
            text = path.read_text()
        except OSError as e:
            raise RtlabError(f"cannot read {path} ({e.strerror}): rtlab reads the kernels' constants from it") from None
        known = parse_defines(text, known)
    return known


def kernel_constant(name: str) -> int | float:
    """The value of ``#define name`` in the kernels' headers (a RtlabError naming the headers if none)."""
    table = kernel_constants()
    if name not in table:
        raise RtlabError(f"no constant #define {name} in kernels/shared/{{{','.join(HEADERS)}}}")
    return table[name]
