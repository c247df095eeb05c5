"""What a submitted file may contain, and how it is read.

A submission is compiled in a tree where it can reach nothing but the lab's own headers, with every
solution of this step and the later ones stubbed (rtlab.course.kernel_sources). The rule below keeps a file
from reaching past that tree or around the stubs. It reads the file as the C preprocessor does
(rtlab.course.cpp: line splices, comments anywhere in a directive, the ``%:`` digraph) and allows:

* the directives ``#define #undef #if #ifdef #ifndef #elif #else #endif #error #warning``, ``#pragma``
  of a few harmless kinds, and ``#include "NAME.h"`` for NAME.h one of the lab's headers (the files
  of kernels/shared) and nothing else on the line;
* ``#define``/``#undef`` of names of the file's own (new names, or what its template defines): a name
  the rest of the kernel sources use (a function, a variant switch such as RT_TRAVERSAL, a type) cannot
  be redefined around a stub;
* no name a compiler or the OpenCL runtime provides that the lab's kernel sources do not use: reserved
  names (any that begins with ``_``: ``__AVX__``, ``__CLANG_ATOMIC_LLONG_LOCK_FREE``, PoCL's ``_cl_sin``,
  the name its own headers give the built-in ``sin``), the runtime's (``POCL_...``, extension and
  ``CLK_`` enumeration macros, ``HALF_...``, and every macro PoCL's kernel headers define that the
  rules' clang does not: ``LLVM_15_0``, ``CLANG_MAJOR``), and no ``#`` operator (stringizing) in a
  ``#define``. Their values differ between the clang that the rules
  below read the code with and PoCL's compile, and ``if (sizeof(STR(POCL_DEVICE_ADDRESS_BITS)) < 8)``
  is a constant clang folds away, with the call behind it, where PoCL runs it;
* conditionals (``#if``, ``#ifdef``...) that test only the lab's own macros (those the kernel sources
  define), those the file's reference tests, and the file's own: the rules that read the code as the
  compiler does (rtlab.course.lab_calls, rtlab.course.structure) run clang beside the compile, and a
  macro only the runtime's compiler defines (PoCL's ``POCL_DEVICE_ADDRESS_BITS``, ``__IMAGE_SUPPORT__``)
  would hide code from them that the kernel runs;
* no ``asm``, no builtins that reach the stack behind a function's back
  (``__builtin_return_address``...), no attributes that run code when the kernel's binary is loaded
  (``constructor``, ``ifunc``, ``section``...), no ``_Pragma``, ``__has_include``, token pasting ``##``
  (it builds names the rule could not see), and none of the spellings C and C++ read differently
  (raw strings, digit separators, trigraphs, unclosed quotes);
* none of the work budget's instruments (``rt_work``, ``RT_COUNT_WORK``, ``load_hit_vertex``... of
  rt_memory.h's counting build) outside the files whose reference uses them;
* ASCII outside comments and string literals: a UTF-8 byte-order mark that opens the file is
  skipped, as clang skips it; any other byte above 127 there is refused with its line.

This rule reads the text; it is not the boundary. On PoCL a kernel is native code in the process
that runs it, so what that process holds and may do is (rtlab.course.sandbox), and what the
preprocessor opens is checked by the preprocessor itself before each compile (rtlab.course.deps).
The lexer is linear in the file's size and stops at the grading run's deadline.

Files are taken as written, byte for byte: a Latin-1 comment compiles as it is; a file that is
empty, UTF-16 (NUL bytes), a link or not a regular file is refused with a message.
"""
from __future__ import annotations

import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path

from .ctokens import split_directives, tokenize

MAX_FILE_BYTES = 1 << 20
ALLOWED_DIRECTIVES = {"define", "undef", "if", "ifdef", "ifndef", "elif", "elifdef", "elifndef", "else",
                      "endif", "error", "warning", "pragma", "include", ""}
ALLOWED_PRAGMAS = {"once", "unroll", "nounroll", "OPENCL", "STDC"}
FORBIDDEN_IDENTIFIERS = {
    "asm": "inline assembly", "__asm": "inline assembly", "__asm__": "inline assembly",
    "_Pragma": "the _Pragma operator", "__pragma": "the __pragma operator",
    "__has_include": "__has_include", "__has_include_next": "__has_include_next", "__has_embed": "__has_embed",
    # the stack and control flow behind a function's back (a CPU kernel could reach the grader's code)
    **{name: f"the builtin {name}" for name in (
        "__builtin_frame_address", "__builtin_return_address", "__builtin_extract_return_addr",
        "__builtin_setjmp", "__builtin_longjmp", "__builtin_eh_return", "__builtin_unwind_init",
        "__builtin_dwarf_cfa", "__builtin_stack_save", "__builtin_stack_restore", "__builtin_alloca",
        "__builtin_alloca_with_align", "__builtin_call_with_static_chain", "__builtin___clear_cache")},
    # attributes that run code when the kernel's binary is loaded, before any launch (constructors,
    # destructors, ifunc resolvers, init sections) or rename symbols the runtime looks up
    **{name: f"the attribute {name.strip('_')} (code that runs when the kernel's binary is loaded)"
       for base in ("constructor", "destructor", "ifunc", "alias", "weakref", "section", "init_priority", "symver")
       for name in (base, f"__{base}__")},
}
# The work budget's instruments (rt_memory.h's counting build): a file that names them could write or
# skip its own counts. Only a file whose reference uses them (rt_memory.h; rt_intersect.h and
# rt_shade.h read a hit's vertices uncounted) may.
WORK_INSTRUMENTS = frozenset({"rt_work", "rt_counted", "RtNodeList", "RtFloat4List", "RtIntList", "RT_COUNT_WORK",
                              "load_hit_vertex"})
# Names a compiler or the OpenCL runtime provides (besides reserved ones): the runtime's own, extension
# macros and the enumerations and constants that depend on them
RUNTIME_NAME_RE = re.compile(r"(?:POCL_|CLK_|CL_|cl_|cles_|HALF_)\w*|M_\w+_H\Z")
MAX_REFUSALS = 40       # refusals listed for one file (a file of 10^5 trigraphs is refused in one message)


@dataclass(frozen=True)
class Refusal:
    path: str               # the lab's path of the file, e.g. kernels/shared/rt_kdtree.h
    line: int | None
    reason: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.reason}" if self.line else f"{self.path}: {self.reason}"


class Refused(Exception):
    def __init__(self, refusals: list[Refusal]):
        super().__init__("; ".join(str(r) for r in refusals))
        self.refusals = refusals


@dataclass(frozen=True)
class SourceRules:
    """What the rule needs to know about the lab's kernel sources."""
    headers: frozenset[str]          # names #include may name (basenames of kernels/shared)
    names_used: dict                 # identifier -> a file (relpath) of the tree that uses it
    defined_by_file: dict            # relpath -> frozenset of macro names the reference file defines
    tested_by_file: dict = None      # relpath -> frozenset of macro names the reference file's conditionals test
    runtime_macros: frozenset = frozenset()  # macros only the runtime's compiler defines (deps.runtime_only_macros)

    def testable(self, relpath: str) -> frozenset:
        """Macros a conditional of the submitted file ``relpath`` may test (besides the file's own)."""
        return self.defined_anywhere | (self.tested_by_file or {}).get(relpath, frozenset())

    @property
    def defined_anywhere(self) -> frozenset:
        return frozenset().union(*self.defined_by_file.values())


def tree_rules(root: Path, extra_files=()) -> SourceRules:
    """The rules for submissions compiled in the kernel sources at ``root`` (shared, cuda, opencl):
    ``extra_files`` (the grader's harness kernels) count as users of names too."""
    root = Path(root)
    headers = frozenset(p.name for p in (root / "shared").glob("*.h"))
    names: dict[str, dict[str, None]] = {}
    defined: dict[str, frozenset] = {}
    tested: dict[str, frozenset] = {}
    files = [(f"kernels/{p.relative_to(root).as_posix()}", p) for sub in ("shared", "cuda", "opencl")
             for p in sorted((root / sub).glob("*")) if p.is_file()]
    files += [(f"rtlab/course/harness/{Path(p).name}", Path(p)) for p in extra_files]
    for rel, p in files:
        toks = tokenize(p.read_bytes().decode("latin-1"))
        directives, _ = split_directives(toks)
        defined[rel] = frozenset(d.args[0].text for d in directives
                                 if d.name == "define" and d.args and d.args[0].kind == "ident")
        tested[rel] = frozenset(n for d in directives if d.name in CONDITIONALS for n in _macros_tested(d))
        for t in toks:
            if t.kind == "ident":
                names.setdefault(t.text, {})[rel] = None
    from .deps import runtime_only_macros
    return SourceRules(headers, {k: tuple(v) for k, v in names.items()}, defined, tested, runtime_only_macros())


CONDITIONALS = {"if", "ifdef", "ifndef", "elif", "elifdef", "elifndef"}


def _macros_tested(d) -> list[str]:
    """The names a conditional directive tests (``defined`` itself aside)."""
    return [t.text for t in d.args if t.kind == "ident" and t.text != "defined"]


def _include_problem(args, headers) -> str | None:
    if not args:
        return "#include without a file name"
    first = args[0]
    if first.kind == "string" and first.text.startswith('"'):
        name = first.text[1:-1]
        if "/" in name or "\\" in name or ".." in name:
            return f'#include "{name}" names a path: include the lab\'s headers by name only, e.g. #include "rt_port.h"'
        if name not in headers:
            return (f'#include "{name}": not one of the lab\'s headers ({", ".join(sorted(headers))})')
        if len(args) > 1:
            return f'#include "{name}" is followed by more on its line'
        return None
    if first.value == "<":
        return "#include <...>: only the lab's own headers may be included, as #include \"rt_....h\""
    if first.kind == "ident":
        return f"#include {first.text}: a computed include (a macro for the file name) is not allowed"
    return f"#include {first.text}: only #include \"NAME.h\" with one of the lab's headers is allowed"


# Reserved names that are the languages' own keywords, the same in every compiler (OpenCL C's address
# spaces and access qualifiers, GNU spellings of C's keywords)
LANGUAGE_KEYWORDS = frozenset({
    "__kernel", "__global", "__local", "__constant", "__private", "__generic", "__read_only", "__write_only",
    "__read_write", "__attribute__", "__attribute", "__restrict", "__restrict__", "__inline", "__inline__",
    "__const", "__const__", "__signed", "__signed__", "__volatile", "__volatile__", "__alignof", "__alignof__",
    "__typeof", "__typeof__", "__extension__", "__func__"})


def _provided_name(name: str) -> bool:
    """Whether a name is one a compiler or the runtime provides: reserved (any name that begins with
    ``_``, as C reserves them at file scope: PoCL renames OpenCL's built-ins to ``_cl_sin`` and the like
    in its own headers only, so a function of that name is the built-in's overload there and nothing
    here; the languages' keywords aside: LANGUAGE_KEYWORDS) or the runtime's (RUNTIME_NAME_RE)."""
    if name in LANGUAGE_KEYWORDS:
        return False
    return name[:1] == "_" or bool(RUNTIME_NAME_RE.match(name))


def _directive_problems(directives, relpath: str, rules: SourceRules) -> list[Refusal]:
    """What the file's directives break of the rule (see the module docstring)."""
    problems: list[Refusal] = []

    def refuse(line, why):
        problems.append(Refusal(relpath, line, why))

    own = rules.defined_by_file.get(relpath, frozenset())
    testable = rules.testable(relpath) | {d.args[0].text for d in directives
                                           if d.name == "define" and d.args and d.args[0].kind == "ident"}
    for d in directives:
        if d.name.startswith("#"):
            refuse(d.line, f"a line marker (# {d.name[1:]} ...) is not allowed")
        elif d.name not in ALLOWED_DIRECTIVES:
            refuse(d.line, f"#{d.name} is not allowed in submitted kernels (allowed: #include \"rt_....h\", "
                           f"#define, #undef, #if/#ifdef/#ifndef/#elif/#else/#endif, #error, #pragma once/unroll)")
        elif d.name == "include":
            why = _include_problem(d.args, rules.headers)
            if why:
                refuse(d.line, why)
        elif d.name == "pragma":
            what = d.args[0].text if d.args else ""
            if what not in ALLOWED_PRAGMAS:
                refuse(d.line, f"#pragma {what} is not allowed (allowed: once, unroll, nounroll, OPENCL, STDC)")
        elif d.name in CONDITIONALS and rules.tested_by_file is not None:
            unknown = [n for n in _macros_tested(d) if n not in testable]
            if unknown:
                refuse(d.line, f"#{d.name} tests {unknown[0]}, not one of the lab's macros (RT_... and those this "
                               f"file's template tests): the grader reads your code as the compiler does under the "
                               f"lab's own macros, and code behind the runtime's (PoCL's) would escape it")
        elif d.name == "define" and any(t.kind == "punct" and t.value == "#" for t in d.args[1:]):
            refuse(d.line, "the # operator (a macro argument made a string) is not allowed in submitted kernels: "
                           "a name spelled out as text can mean one thing to the compiler that reads your code for "
                           "the grader and another to the one that runs it")
        elif d.name in ("define", "undef") and d.args and d.args[0].kind == "ident":
            name = d.args[0].text
            users = [f for f in rules.names_used.get(name, ()) if f != relpath]
            if users and name not in own:
                refuse(d.line, f"#{d.name} {name}: {name} is used by {users[0]}; a submitted file may define only "
                               f"new names of its own (rename yours)")
    return problems


def check_source(text: str, relpath: str, rules: SourceRules, deadline_at: float | None = None) -> list[Refusal]:
    """Everything in a submitted file (decoded as Latin-1) that breaks the rule, in line order (at
    most MAX_REFUSALS, then a count of the rest)."""
    try:
        toks = tokenize(text, deadline_at)
    except TimeoutError as e:
        return [Refusal(relpath, None, f"not read: {e}")]
    problems: list[Refusal] = []

    def refuse(line, why):
        problems.append(Refusal(relpath, line, why))

    for t in toks:
        if t.kind == "ambiguous":
            refuse(t.line, f"{t.why}: compilers read this differently, so it is not allowed")
        elif t.kind == "nonascii":
            refuse(t.line, "a byte outside ASCII outside a comment or a string (a byte-order mark, an accented "
                           "letter, a Unicode quote or space?): kernel code is ASCII; save the file as ASCII or UTF-8 "
                           "without a byte-order mark, with non-ASCII text only in comments")
        elif t.kind == "punct" and t.value == "\\":
            refuse(t.line, "a backslash outside a string or a comment (a universal character name such as \\u00e9 "
                           "in a name?): kernel code names things in plain ASCII letters, digits and _")
        elif t.kind == "ident" and t.text in FORBIDDEN_IDENTIFIERS:
            refuse(t.line, f"{FORBIDDEN_IDENTIFIERS[t.text]} ({t.text}) is not allowed in submitted kernels")
        elif t.kind == "ident" and (_provided_name(t.text) or t.text in rules.runtime_macros) \
                and t.text not in rules.names_used:
            refuse(t.line, f"{t.text} is a name the compiler or the OpenCL runtime provides, which the lab's kernels "
                           f"do not use: its value differs between the compiler that reads your code for the grader "
                           f"and the one that runs it, so submitted kernels may not depend on it")
        elif t.kind == "ident" and t.text in WORK_INSTRUMENTS and relpath not in rules.names_used.get(t.text, ()):
            refuse(t.line, f"{t.text} is the work budget's counter (rt_memory.h): submitted kernels read the scene "
                           f"through the lab's loaders and leave the counting to them")
        elif t.kind == "punct" and t.value == "##":
            refuse(t.line, "token pasting (##) is not allowed in submitted kernels")
        if len(problems) > 4 * MAX_REFUSALS:
            break
    directives, _ = split_directives(toks)
    problems += _directive_problems(directives, relpath, rules)
    problems.sort(key=lambda r: r.line or 0)
    if len(problems) > MAX_REFUSALS:
        rest = len(problems) - MAX_REFUSALS
        problems = problems[:MAX_REFUSALS] + [Refusal(relpath, None, f"... and {rest}{'+' if rest >= 3 * MAX_REFUSALS else ''} "
                                                                     f"more problems")]
    return problems


def read_submitted(path: Path, relpath: str) -> bytes:
    """The file's bytes, as written; :class:`Refused` when it is not a plain, non-empty text file."""
    try:
        st = os.lstat(path)
    except OSError as e:
        raise Refused([Refusal(relpath, None, f"cannot be read ({e.strerror})")]) from None
    if stat.S_ISLNK(st.st_mode):
        raise Refused([Refusal(relpath, None, "is a symbolic link: hand in the file itself")])
    if not stat.S_ISREG(st.st_mode):
        raise Refused([Refusal(relpath, None, "is not a regular file")])
    if st.st_nlink > 1:
        raise Refused([Refusal(relpath, None, "is a hard link to another file: hand in a copy of your own")])
    if st.st_size > MAX_FILE_BYTES:
        raise Refused([Refusal(relpath, None, f"is {st.st_size:,} bytes, more than the {MAX_FILE_BYTES:,} "
                                              f"a kernel source may have")])
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | getattr(os, "O_NONBLOCK", 0))
    except OSError as e:
        raise Refused([Refusal(relpath, None, f"cannot be read ({e.strerror})")]) from None
    try:
        if os.fstat(fd).st_ino != st.st_ino:
            raise Refused([Refusal(relpath, None, "changed while it was read")])
        data = os.read(fd, MAX_FILE_BYTES + 1)
    finally:
        os.close(fd)
    if not data.strip():
        raise Refused([Refusal(relpath, None, "file is empty")])
    if data[:2] in (b"\xff\xfe", b"\xfe\xff") or b"\0" in data:
        raise Refused([Refusal(relpath, None, "is not an 8-bit text file (UTF-16 or NUL bytes): compilers read "
                                              "bytes, so save it as UTF-8 or ASCII")])
    return data


def refused_placeholder(refusals: list[Refusal]) -> bytes:
    """What stands in the compile tree for a refused file: an #error, so exactly the kernels that
    include it fail (with the refusal as their message) and the others still run."""
    first = str(refusals[0]).replace("\\", "/").replace('"', "'")
    return (f'#error "{REFUSED_MARK}{first}"\n').encode("latin-1", "replace")


REFUSED_MARK = "rtlab refused this file: "
