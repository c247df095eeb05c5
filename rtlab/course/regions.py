"""Student regions in the kernel sources: the lines between ``/* BEGIN SOLUTION */`` and
``/* END SOLUTION */`` inside a function body (signature and doc comment stay outside).

Templates are the reference with each region of a lab's functions replaced by a stub that compiles
and returns a miss (or zero), so there is one source of truth. The stub comes from the function's
return type (:data:`STUBS`); a region may name its own with a ``/* STUB: ... */`` line right after
BEGIN SOLUTION. The markers stay in the template: students write between them.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from ..errors import LabError
from ..paths import STUB_MARK as TODO_MARK   # one spelling: rtlab.paths reads it too


BEGIN_RE = re.compile(r"^([ \t]*)/\*\s*BEGIN SOLUTION\s*\*/[ \t]*$", re.M)
END_RE = re.compile(r"^[ \t]*/\*\s*END SOLUTION\s*\*/[ \t]*$", re.M)
STUB_RE = re.compile(r"^[ \t]*/\*\s*STUB:\s*(.*?)\s*\*/[ \t]*$")
# A function definition starts at the beginning of a line with a qualifier, the return type, the name
SIGNATURE_RE = re.compile(
    r"^(?:RT_FN|RT_KERNEL|__kernel|extern\s+\"C\"\s+__global__|__global__|static\s+inline|static)\s+"
    r"(?P<ret>[A-Za-z_][\w \t\*]*?)\s*\b(?P<name>[A-Za-z_]\w*)\s*\(", re.M)

# What a stubbed function returns: a miss, zero, an empty ray (tmax = 0: every pixel misses).
STUBS = {
    "void": "return;",
    "int": "return 0;",
    "unsigned int": "return 0u;",
    "uint": "return 0u;",
    "float": "return 0.0f;",
    "float3": "return f3(0.0f, 0.0f, 0.0f);",
    "float4": "return f4(0.0f, 0.0f, 0.0f, 0.0f);",
    "Ray": "return make_ray(f3(0.0f, 0.0f, 0.0f), f3(0.0f, 0.0f, 1.0f), 0.0f, 0.0f);",
    "Hit": "return make_miss(0.0f);",
}


@dataclass
class Region:
    function: str
    return_type: str
    begin: int          # character offset of the BEGIN line's start
    end: int            # character offset just past the END line (its newline excluded)
    body_start: int     # just past the BEGIN line's newline
    body_end: int       # start of the END line
    indent: str
    line: int           # 1-based line of the BEGIN marker
    stub: str | None    # a /* STUB: ... */ given in the region

    def body(self, text: str) -> str:
        return text[self.body_start:self.body_end]


def find_regions(text: str, where: str = "<source>") -> list[Region]:
    """Every marked region of a source, with the function it sits in."""
    regions = []
    ends = [m for m in END_RE.finditer(text)]
    begins = [m for m in BEGIN_RE.finditer(text)]
    if len(begins) != len(ends):
        raise LabError(f"{where}: {len(begins)} BEGIN SOLUTION but {len(ends)} END SOLUTION markers")
    for b, e in zip(begins, ends):
        if e.start() < b.end():
            raise LabError(f"{where}:{text.count(chr(10), 0, e.start()) + 1}: END SOLUTION before its BEGIN")
        sigs = list(SIGNATURE_RE.finditer(text, 0, b.start()))
        line = text.count("\n", 0, b.start()) + 1
        if not sigs:
            raise LabError(f"{where}:{line}: BEGIN SOLUTION outside a function")
        sig = sigs[-1]
        ret = " ".join(sig.group("ret").split())
        body_start = b.end() + 1
        first_end = text.find("\n", body_start)
        first = text[body_start:first_end]
        if TODO_MARK in first:       # an already stubbed region: its STUB line follows the TODO line
            first = text[first_end + 1:text.find("\n", first_end + 1)]
        stub_match = STUB_RE.match(first)
        regions.append(Region(function=sig.group("name"), return_type=ret, begin=b.start(), end=e.end(),
                              body_start=body_start, body_end=e.start(), indent=b.group(1), line=line,
                              stub=stub_match.group(1) if stub_match else None))
    return regions


def stub_for(region: Region, where: str) -> str:
    if region.stub:
        return region.stub
    ret = region.return_type.replace("static", "").replace("inline", "").replace("__device__", "")
    ret = " ".join(ret.replace("__forceinline__", "").split())
    if ret in STUBS:
        return STUBS[ret]
    raise LabError(f"{where}:{region.line}: no stub for {region.function} returning '{region.return_type}'; "
                   f"add a line /* STUB: return ...; */ right after BEGIN SOLUTION")


def todo_line(step: str, function: str) -> str:
    return f"/* {TODO_MARK}{step}): write {function} here; labs/{step}/README.md says what it must do. */"


def strip_regions(text: str, functions: list[str], step: str, where: str = "<source>") -> str:
    """``text`` with the regions of ``functions`` replaced by TODO + stub (markers kept)."""
    regions = find_regions(text, where)
    found = {r.function for r in regions}
    missing = [f for f in functions if f not in found]
    if missing:
        raise LabError(f"{where}: no BEGIN SOLUTION region in {', '.join(missing)} "
                       f"(regions found in: {', '.join(sorted(found)) or 'none'})")
    out, pos = [], 0
    for r in regions:
        if r.function not in functions:
            continue
        out.append(text[pos:r.body_start])
        stub = stub_for(r, where)
        out.append(f"{r.indent}{todo_line(step, r.function)}\n")
        if r.stub:
            out.append(f"{r.indent}/* STUB: {r.stub} */\n")
        out.append(f"{r.indent}{stub}\n")
        pos = r.body_end
    out.append(text[pos:])
    return "".join(out)


def code_tokens(text: str) -> tuple[str, ...]:
    """A piece of C as its tokens: comments, spaces and line breaks dropped (rtlab.course.ctokens)."""
    from .ctokens import tokenize
    return tuple(t.value for t in tokenize(text))


def template_stubs(text: str, where: str = "<source>") -> dict[str, str]:
    """function -> the statement its template region holds (stub_for): read from the reference file,
    or a template or release (whose regions name their stub); functions whose stub cannot be told
    (no STUB line, a return type STUBS does not know) are left out."""
    try:
        regions = find_regions(text, where)
    except LabError:
        return {}
    out = {}
    for r in regions:
        try:
            out[r.function] = stub_for(r, where)
        except LabError:
            continue
    return out


def stubbed_functions(text: str, stubs: dict[str, str] | None = None) -> list[str]:
    """Functions whose region still holds the template's stub: the same code tokens as the template's
    stub statement (comments, the TODO line among them, and spacing do not count: code written under a
    kept TODO line is code, and the grader's rules judge it). ``stubs``: the template's stubs by function
    (:func:`template_stubs` of the reference file, which knows a stub even where the submitted region
    dropped its STUB line); without it, the region's own."""
    try:
        regions = find_regions(text)
    except LabError:
        return []
    out = []
    for r in regions:
        body = r.body(text)
        stub = (stubs or {}).get(r.function)
        if stub is None:
            try:
                stub = stub_for(r, "<source>")
            except LabError:
                continue
        try:
            if code_tokens(body) == code_tokens(stub):
                out.append(r.function)
        except TimeoutError:
            continue
    return out


def splice_regions(reference: str, student: str, where: str = "<source>", functions=None) -> str:
    """The reference with each region's body taken from the same function's region in ``student``
    (regions the student file lacks, or functions not in ``functions`` when given, keep the
    reference body). Used to keep stored test submissions current when the code around the
    regions changes, and to take a student's earlier steps in a student release."""
    theirs = {r.function: r.body(student) for r in find_regions(student, where)
              if functions is None or r.function in functions}
    out, pos = [], 0
    for r in find_regions(reference, where):
        if r.function not in theirs:
            continue
        out.append(reference[pos:r.body_start])
        out.append(theirs[r.function])
        pos = r.body_end
    out.append(reference[pos:])
    return "".join(out)
