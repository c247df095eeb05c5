"""Kernel sources read the way the C preprocessor reads them: tokens and directives (rtlab.course.ctokens),
and the code a set of defines leaves active (here).

The grader uses this twice:

* :func:`tokenize` for the rule on submitted files (rtlab.course.submission): a directive is found
  wherever a compiler would find one, whatever the spelling (line splices ``\\`` + newline, comments
  between ``#`` and the directive name, the ``%:`` digraph).
* :class:`Preprocessor` to see which functions a kernel calls under its ``-D`` defines (a failing
  test's note names only the unfinished functions that test uses).

clang (PoCL's OpenCL C) and nvcc (CUDA C++) lex a few things differently: raw strings and digit
separators are C++ only, trigraphs depend on the language mode. Those spellings could hide a
directive from one reading and not the other, so :func:`tokenize` reports them (``Token.kind`` =
"ambiguous") and the submission rule refuses them rather than guessing which compiler is right.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..cexpr import ExprError, evaluate
from .ctokens import Token, directive_at, tokenize

# --------------------------------------------------------------------------------------------------
# a small preprocessor: which code a set of defines leaves active, and who calls whom
# --------------------------------------------------------------------------------------------------
@dataclass
class Macro:
    params: list[str] | None     # None: object-like
    body: list[Token]


@dataclass
class Function:
    name: str
    file: Path
    line: int
    calls: set[str] = field(default_factory=set)    # identifiers in the body
    is_kernel: bool = False


KERNEL_QUALIFIERS = {"__kernel", "kernel", "__global__"}


class Preprocessor:
    """Runs the conditionals and includes of a kernel source under a set of defines (quoted
    includes beside the including file, then in ``include_dirs``; anything else is skipped), and
    collects the function definitions of the active code with the identifiers their bodies name."""

    def __init__(self, include_dirs, defines: dict | None = None):
        self.include_dirs = [Path(d) for d in include_dirs]
        self.macros: dict[str, Macro] = {}
        for k, v in (defines or {}).items():
            self.macros[k] = Macro(None, tokenize(str(v)))
        self.functions: dict[str, Function] = {}
        self.files: list[Path] = []
        self._once: set[Path] = set()

    def resolve(self, name: str, current: Path) -> Path | None:
        for d in [current.parent, *self.include_dirs]:
            p = d / name
            if p.is_file():
                return p
        return None

    def run(self, path) -> "Preprocessor":
        self._file(Path(path), 0)
        return self

    def _expand_ids(self, toks: list[Token], seen=frozenset()) -> list[str]:
        out: list[str] = []
        i = 0
        while i < len(toks):
            t = toks[i]
            if t.kind == "ident" and t.text == "defined":
                j = i + 1
                paren = j < len(toks) and toks[j].value == "("
                j += paren
                name = toks[j].text if j < len(toks) else ""
                out.append("1" if name in self.macros else "0")
                i = j + 1 + paren
                continue
            if t.kind == "ident" and t.text in self.macros and t.text not in seen:
                m = self.macros[t.text]
                if m.params is None:
                    out += self._expand_ids(m.body, seen | {t.text})
                    i += 1
                    continue
            out.append(t.value)
            i += 1
        return out

    def _condition(self, args: list[Token]) -> bool:
        try:
            return bool(evaluate(self._expand_ids(args), unknown=0))
        except (ExprError, RecursionError):
            return False

    # Why long: the directive switch (#include, #define, the #if family, #pragma once), one case each, as C's
    # preprocessor reads them.
    def _file(self, path: Path, depth: int) -> None:
        if depth > 40 or path in self._once:
            return
        self.files.append(path)
        try:
            text = path.read_bytes().decode("latin-1")
        except OSError:
            return
        toks = tokenize(text)
        active: list[Token] = []
        stack: list[list[bool]] = []     # per #if: [this branch active, some branch taken, parent active]
        live = True
        i, n = 0, len(toks)
        while i < n:
            t = toks[i]
            found = directive_at(toks, i)
            if found:
                rest, i = found
                name = rest[0].text if rest and rest[0].kind == "ident" else ""
                args = rest[1:]
                if name in ("if", "ifdef", "ifndef"):
                    if not live:
                        stack.append([False, True, False])
                    else:
                        if name == "if":
                            c = self._condition(args)
                        else:
                            c = bool(args) and ((args[0].text in self.macros) == (name == "ifdef"))
                        stack.append([c, c, True])
                    live = stack[-1][0]
                elif name in ("elif", "elifdef", "elifndef") and stack:
                    top = stack[-1]
                    if top[2] and not top[1]:
                        if name == "elif":
                            c = self._condition(args)
                        else:
                            c = bool(args) and ((args[0].text in self.macros) == (name == "elifdef"))
                        top[0] = c
                        top[1] = c
                    else:
                        top[0] = False
                    live = top[0]
                elif name == "else" and stack:
                    top = stack[-1]
                    top[0] = top[2] and not top[1]
                    top[1] = True
                    live = top[0]
                elif name == "endif" and stack:
                    stack.pop()
                    live = stack[-1][0] if stack else True
                elif not live:
                    pass
                elif name == "define" and args and args[0].kind == "ident":
                    mname = args[0].text
                    body = args[1:]
                    params = None
                    # function-like: '(' right after the name (no space: same line and adjacent in source)
                    if body and body[0].value == "(" and body[0].pos == args[0].pos + len(args[0].text):
                        k = 1
                        params = []
                        while k < len(body) and body[k].value != ")":
                            if body[k].kind == "ident" or body[k].value == "...":
                                params.append(body[k].text)
                            k += 1
                        body = body[k + 1:]
                    self.macros[mname] = Macro(params, body)
                elif name == "undef" and args:
                    self.macros.pop(args[0].text, None)
                elif name == "include" and args and args[0].kind == "string":
                    target = self.resolve(args[0].text[1:-1], path)
                    if target is not None:
                        self._collect(active, path)
                        active = []
                        self._file(target, depth + 1)
                elif name == "pragma" and args and args[0].text == "once":
                    self._once.add(path)
                continue
            if live:
                active.append(t)
            i += 1
        self._collect(active, path)

    def _collect(self, toks: list[Token], path: Path) -> None:
        """Function definitions at file scope: NAME ( ... ) { ... }."""
        depth = 0
        i, n = 0, len(toks)
        while i < n:
            t = toks[i]
            v = t.value
            if v == "{" and depth == 0 and i > 0 and toks[i - 1].value == ")":
                # walk back to the '(' that matches, then the name before it
                k, level = i - 1, 0
                while k >= 0:
                    if toks[k].value == ")":
                        level += 1
                    elif toks[k].value == "(":
                        level -= 1
                        if level == 0:
                            break
                    k -= 1
                name_tok = toks[k - 1] if k > 0 else None
                # the body
                j, level = i, 0
                while j < n:
                    if toks[j].value == "{":
                        level += 1
                    elif toks[j].value == "}":
                        level -= 1
                        if level == 0:
                            break
                    j += 1
                if name_tok is not None and name_tok.kind == "ident":
                    start = k - 1
                    while start > 0 and toks[start - 1].value not in (";", "}", ")") and toks[start - 1].kind != "punct":
                        start -= 1
                    quals = {x.text for x in toks[start:k - 1]}
                    body_ids = {x.text for x in toks[i:j] if x.kind == "ident"}
                    self.functions[name_tok.text] = Function(name_tok.text, path, name_tok.line, body_ids,
                                                             bool(quals & KERNEL_QUALIFIERS))
                i = j + 1
                continue
            if v == "{":
                depth += 1
            elif v == "}":
                depth = max(0, depth - 1)
            i += 1

    def _macro_ids(self, name: str, seen: set[str]) -> set[str]:
        """Identifiers a macro expands to, macros inside expanded too."""
        out: set[str] = set()
        stack = [name]
        while stack:
            m = stack.pop()
            if m in seen:
                continue
            seen.add(m)
            for t in self.macros[m].body:
                if t.kind == "ident":
                    if t.text in self.macros:
                        stack.append(t.text)
                    else:
                        out.add(t.text)
        return out

    def reachable(self, roots) -> set[str]:
        """Functions called, directly or through macros, from the functions ``roots`` (names)."""
        seen: set[str] = set()
        stack = [r for r in roots if r in self.functions]
        while stack:
            f = stack.pop()
            if f in seen:
                continue
            seen.add(f)
            ids = set()
            for ident in self.functions[f].calls:
                if ident in self.macros:
                    ids |= self._macro_ids(ident, set())
                else:
                    ids.add(ident)
            stack += [x for x in ids if x in self.functions and x not in seen]
        return seen

    def kernels(self) -> list[str]:
        return [f.name for f in self.functions.values() if f.is_kernel]
