"""The lab-call rule: a step's function calls only the lab functions its reference calls.

A submission compiles in a tree where the earlier steps' functions hold the reference's bodies
(rtlab.course.kernel_sources), so without this rule a lab 03 ``traverse_kd_restart`` could call lab
00's finished ``traverse_kd_stack`` and pass every test of the restart traversal without walking
anything itself; or one of a step's traversals could call another (the student's own shortstack
for the restart). Tests see only outputs, so the rule reads who calls whom instead:

* **Allowed** (the grader, from the reference tree): for each function the step grades, the lab
  functions (those with a solution region, of any step) its reference body reaches, directly or
  through helpers and macros, every ``#if`` branch at once: a generous reading of the reference.
* **Called** (the test process, before each compile): the call graph the compiler itself builds.
  clang turns the program, under the compile's own defines, into LLVM IR before any optimisation
  (``-disable-llvm-passes``: nothing inlined away), and each function's IR names every function it
  calls or takes the address of. No spelling of a call (a macro, an attribute, a helper, an
  ``#if`` branch) hides it there.

A graded function that reaches a lab function outside its allowance refuses the compile, naming
the path of calls. CUDA runs read the program's OpenCL twin (the same shared code under the
OpenCL branch of ``rt_port.h``). In a student release the reference bodies are stubs, so the rule
has nothing to compare with and checks nothing (a student grading their own work; the course's
grader holds the reference).
"""
from __future__ import annotations

import functools
import re
from pathlib import Path

# An IR symbol, group 2: plain (@name) or quoted with LLVM's hex escapes (@"r\C3\A9start", a name spelled
# with a universal character name): read both, so no function escapes the graph
SYMBOL = r'@(")?((?(1)(?:[^"\\]|\\[0-9A-Fa-f]{2}|\\\\)+|[\w.$-]+))(?(1)")'
_DEFINE_RE = re.compile(r'^define\b[^@]*' + SYMBOL + r'\(', re.M)
_NAME_RE = re.compile(SYMBOL)


def unread_definitions(ir: str) -> int:
    """How many of the IR's function definitions :data:`_DEFINE_RE` does not read (0: the rules see
    every function; more: they would judge a program with functions missing, so they refuse it)."""
    return len(re.findall(r'^define\b', ir, re.M)) - len(_DEFINE_RE.findall(ir))


@functools.lru_cache(maxsize=None)
def lab_call_rules(step: str) -> dict:
    """``{"owners": {function: its step}, "allowed": {function: [lab functions]}}`` for the functions
    ``step`` grades whose reference body is written (JSON-ready: it travels in the test's job)."""
    from .config import load_config
    from .cpp import Macro, Preprocessor
    from .ctokens import split_directives, tokenize
    from .kernel_sources import read_text, reference_kernels, region_owners
    from .regions import stubbed_functions
    owners = {f: s for (_, f), s in region_owners().items()}
    ref = reference_kernels()
    index = Preprocessor([])
    stubs: set[str] = set()
    for path in sorted((ref / "shared").glob("*.h")):
        text = read_text(path)
        stubs |= set(stubbed_functions(text))
        directives, code = split_directives(tokenize(text))
        for d in directives:
            if d.name == "define" and d.args and d.args[0].kind == "ident":
                body = index.macros.get(d.args[0].text)        # every #if branch's definition at once
                index.macros[d.args[0].text] = Macro(None, (body.body if body else []) + d.args[1:])
        for name, fn in _functions_of(index, code, path).items():
            if name in index.functions:                         # defined in two #if branches: both bodies
                index.functions[name].calls |= fn.calls
            else:
                index.functions[name] = fn
    allowed = {}
    for lf in load_config(step).files:
        for f in lf.functions:
            if f in index.functions and f not in stubs:
                allowed[f] = sorted((index.reachable([f]) & set(owners)) - {f})
    return {"owners": owners, "allowed": allowed}


def _functions_of(index, code, path: Path) -> dict:
    from .cpp import Preprocessor
    one = Preprocessor([])
    one._collect(code, path)
    return one.functions


def ir_call_graph(ir: str) -> dict[str, set[str]]:
    """function -> the functions its LLVM IR body names (calls, addresses taken), by source name."""
    graph: dict[str, set[str]] = {}
    starts = list(_DEFINE_RE.finditer(ir))
    for k, m in enumerate(starts):
        end = ir.find("\n}", m.end())
        body = ir[m.end():end if end >= 0 else (starts[k + 1].start() if k + 1 < len(starts) else len(ir))]
        graph.setdefault(source_name(m.group(2)), set()).update(source_name(n.group(2)) for n in _NAME_RE.finditer(body))
    return graph


def source_name(symbol: str) -> str:
    """A C function's name from its IR symbol: plain, or Itanium-mangled (``_Z17traverse_kd_stack...``,
    OpenCL's overloadable functions, C++)."""
    m = re.match(r"_Z(?:L)?(\d+)", symbol)
    if m:
        n = int(m.group(1))
        return symbol[m.end():m.end() + n]
    return symbol.split(".")[0]          # clang's suffixes for local copies (name.1)


def _path(graph: dict[str, set[str]], start: str, goal: str) -> list[str]:
    parent = {start: None}
    queue = [start]
    for f in queue:
        if f == goal:
            break
        for g in sorted(graph.get(f, ())):
            if g not in parent:
                parent[g] = f
                queue.append(g)
    out, f = [], goal
    while f is not None:
        out.append(f)
        f = parent.get(f)
    return out[::-1]


def overloaded_lab_function(ir: str, owners) -> str | None:
    """Why the program breaks "a lab function is one function", or None: a lab function (one with a
    solution region) that the IR defines under a mangled symbol, an ``overloadable`` definition beside
    the lab's own. The call graph reads functions by source name, so such an overload would merge with
    the lab function there, and the rules would take code of the student's own for the reference's
    (a copied stack walk behind an overload of an allowed lab function)."""
    for m in _DEFINE_RE.finditer(ir):
        symbol = m.group(2)
        if symbol.startswith("_Z") and source_name(symbol) in owners:
            name = source_name(symbol)
            return (f"{name} is defined as an overload (__attribute__((overloadable))): {name} is the lab's "
                    f"function (lab {owners[name]}); a lab function is one function, so give functions of your "
                    f"own names of their own")
    return None


def lab_call_problem(graph: dict[str, set[str]], rules: dict) -> str | None:
    """Why the program's graded functions break the rule (the first one found), or None."""
    owners, allowed = rules["owners"], rules["allowed"]
    for f in sorted(allowed):
        if f not in graph:
            continue                        # not in this program
        seen, stack = {f}, [f]
        while stack:
            for g in graph.get(stack.pop(), ()):
                if g not in seen:
                    seen.add(g)
                    stack.append(g)
        beyond = sorted(g for g in seen if g in owners and g != f and g not in allowed[f])
        if beyond:
            g = beyond[0]
            via = _path(graph, f, g)
            how = f" (through {' -> '.join(via[1:-1])})" if len(via) > 2 else ""
            return (f"{f} calls {g}{how}, the function lab {owners[g]} grades, which the reference {f} does "
                    f"not call: each lab function does its own work, so write {f} without {g}")
    return None
