"""The structure rule: a stackless traversal holds no per-ray stack, a short stack no more than its
short stack, a packet traversal keeps its stack in the packet's local memory.

The lab-call rule (rtlab.course.lab_calls) sees calls only: lab 00's ``traverse_kd_stack`` *copied*
into lab 03's ``traverse_kd_restart`` calls nothing new, walks every leaf the stack walk does and
passes every hit test and the work budget (an upper bound: a full stack reads fewer nodes than a
restart). What makes a traversal stackless is where it keeps its state, and that the compiler can
say. From the same LLVM IR (before any optimisation, ``rtlab.course.deps.opencl_ir``: every local
variable is an ``alloca`` of its declared type, nothing promoted to registers or inlined away):

* **indexed private storage** (the grader, from the reference): for each function of :data:`RULES`
  whose reference body is written, the bytes of per-ray private storage a loop can index, held by
  the function and what it reaches, every path of calls down to the lab functions of other steps
  (reference code, which the lab-call rule already polices). Counted by what the code does with the
  bytes, not by their type's kind: a local whose type holds an array or a vector of more than four
  lanes (its arrays' bytes), and any local, whatever its type (structs of structs of KdStackEntry, a
  union, a copy of the Ray), that the program reaches at a variable offset (all its bytes; a vector
  lane picked by a variable: that vector's), through whatever pointer derived from it
  (:func:`indexed_allocas`). A stack is a variable index into memory. Measured on the reference
  program under probe defines, with and without the work count, and fitted as ``a + b *
  RT_STACK_SIZE + c * RT_SHORT_STACK_SIZE``: kd-restart's, ropes' and the packet's hold nothing, the
  short stack's its ``RT_SHORT_STACK_SIZE`` entries.
* **local memory** (packet traversals): whether the reference's walk writes the block's local
  (OpenCL ``__local``, CUDA ``__shared__``: LLVM address space 3) memory, and the size of the
  largest ``__local`` variable of its program (the packet's shared state, KdPacketShared).
* **the check** (the test process, before each compile, on the IR the lab-call rule reads): the
  submitted function's indexed private storage may hold at most the reference's bytes at the
  compile's own RT_STACK_SIZE and RT_SHORT_STACK_SIZE, plus :data:`SLACK_BYTES`, and it may not
  recurse where its reference does not (PoCL runs recursion: the frames are a stack); a packet
  traversal must write local memory where its reference does, and its program's local variable may
  be at most :data:`LOCAL_FACTOR` times the reference's (a stack for each of the block's rays in
  local memory is RT_TRACE_THREADS times one). A break refuses the compile with one line naming the
  function, its largest such local with its bytes, and the reference's bytes.

Why indexed storage and not the whole private frame: at -O0 every parameter and scalar has its
``alloca``, and the frames do not separate a copied stack from a restart written otherwise. The
reference kd-restart's deepest frame (its own 228 B, then intersect_leaf down to Moller-Trumbore)
is 712 B, ropes' 840 B, the short stack's 884 B; lab 00's walk copied in at the grading scenes'
RT_STACK_SIZE of 29 is 1,128 B (at 21: 1,000 B), only 244 to 416 B above them (116 B above the
short stack at 21), while a helper of one's own on the leaf path adds its whole frame (intersect_leaf's
parameters alone take 104 B) and each scalar 4 to 16 B: a restart written with its own helper and a
few dozen more scalars moves by as much. The indexed bytes of the same programs: 0 for the
references (160 B of short stack), 464 B for the copy at 29, 1,024 B for a 64-entry stack in structs of structs,
0 to 40 B for the legitimate variants measured (see :data:`SLACK_BYTES`).

What it cannot see (the README's "limits"): state kept in scalars (a 64-bit trail of bits is a
legitimate stackless walk, Laine 2010, and so is a restart: the rule does not judge algorithms),
and so a stack indexed by control flow spread over many small locals (slots in one local, through a
pointer given SLOT_POINTERS of its fields or written at SLOT_FIELDS offsets, count as indexed:
rtlab.course.ir_indexing); a stack written through raw
pointer casts into global memory; a stack squeezed into the allowance (the short stack's 160 B hold
40 node indices: a full stack of node indices that re-clips its cells fits). It reads the OpenCL
twin of a CUDA program, as the lab-call rule does, and the reference at the paper's variant (the
lab's tests). In a student release the reference bodies are stubs, so there is nothing to compare
with and the rule checks nothing.
"""
from __future__ import annotations

import functools
import re
from dataclasses import dataclass

from .ir_indexing import _ALLOCA_RE, _DEFINE_RE, bodies, indexed_allocas
from .lab_calls import source_name
from .llvm_types import TYPE_TOKEN_RE, Ty, TypeTable, array_bytes, describe, size_of, type_text

# function -> what its structure is; the allowance comes from the reference, the words from here
RULES = {
    "traverse_kd_restart": "stackless",
    "traverse_kd_ropes": "stackless",
    "traverse_kd_shortstack": "short stack",
    "traverse_kd_packet": "packet",
}
WHY = {
    "traverse_kd_restart": "kd-restart is stackless: after each leaf it restarts from the root, so it keeps no "
                           "per-ray stack",
    "traverse_kd_ropes": "the ropes traversal is stackless: after each leaf it follows the exit face's rope, so it "
                         "keeps no per-ray stack",
    "traverse_kd_shortstack": "a short stack holds at most RT_SHORT_STACK_SIZE = {k} entries and restarts from the "
                              "root when it runs empty",
    "traverse_kd_packet": "a packet keeps ONE stack for all its rays in the block's local memory (the "
                          "KdPacketShared *sh it is given), not a stack for each ray",
}
# Indexed bytes beyond the reference's that a legitimate traversal may need: the per-axis arrays of a
# slab clip (origin, direction, inverse, the box's corners, entry and exit distances: up to 7 x
# float[3], 84 B), or a copy of the Ray and a float4
# read by a variable lane (16 B each). A full stack at the grading scenes' depth (RT_STACK_SIZE 29)
# does not fit: 116 B as bare node indices, 464 B as lab 00's entries.
SLACK_BYTES = 96
LOCAL_FACTOR = 2        # the packet's local state: twice the reference's leaves room for more fields per entry
PROBE_STACK = (24, 40)  # RT_STACK_SIZE values the reference is measured at (the stackless ones stop above 64)


# --------------------------------------------------------------------------------------------------
# what a program's IR holds
# --------------------------------------------------------------------------------------------------
_LOCAL_STORE_RE = re.compile(r'^\s*(?:store\b.*,\s*ptr addrspace\(3\)|(?:%\S+ = )?(?:atomicrmw|cmpxchg)\b'
                             r'(?: volatile)?(?: \w+)? ptr addrspace\(3\))', re.M)
_LOCAL_GLOBAL_RE = re.compile(r'^(@"[^"]*"|@[\w.$-]+) = (?:[\w]+ )*addrspace\(3\) global (.*)$', re.M)


@dataclass
class Local:
    function: str
    name: str
    ty: Ty
    bytes: int                 # what counts: its arrays' bytes (array_bytes), or what a variable index reaches
    indexed: bool = False      # reached at a variable offset (a GEP's variable index, through any pointer)


@dataclass
class Program:
    functions: dict            # source name -> {"locals": [Local], "local_stores": int}
    local_vars: list           # (name, bytes) of the program's __local variables


def read_program(ir: str) -> Program:
    """Each function's locals (its allocas: every local variable and parameter at -O0), each with
    the bytes the rule counts, its writes to local memory; the program's ``__local`` variables."""
    types = TypeTable(ir)
    indexed = indexed_allocas(ir, types)
    functions: dict[str, dict] = {}
    for symbol, body in bodies(ir):
        name = source_name(symbol)
        entry = functions.setdefault(name, {"locals": [], "local_stores": 0})
        for a in _ALLOCA_RE.finditer(body):
            tok = TYPE_TOKEN_RE.findall(a.group(2))
            try:
                ty, i = types.parse_tokens(tok, 0)
            except (IndexError, ValueError, AssertionError):
                continue
            if tok[i:i + 1] == [","] and re.fullmatch(r"i\d+", tok[i + 1] if i + 1 < len(tok) else "") \
                    and i + 2 < len(tok) and tok[i + 2].isdigit():
                ty = Ty("array", count=int(tok[i + 2]), elem=ty)      # alloca T, i32 N: an array of N
            hit = (symbol, a.group(1)) in indexed
            reached = size_of(ty) if not hit or indexed[(symbol, a.group(1))] is None else \
                min(size_of(ty), indexed[(symbol, a.group(1))])
            entry["locals"].append(Local(name, a.group(1).lstrip("%").strip('"'), ty,
                                         max(reached, array_bytes(ty)) if hit else array_bytes(ty), hit))
        entry["local_stores"] += len(_LOCAL_STORE_RE.findall(body))
    local_vars = []
    for g in _LOCAL_GLOBAL_RE.finditer(ir):
        try:
            ty = types.parse(g.group(2))
        except (IndexError, ValueError, AssertionError):
            continue
        local_vars.append((g.group(1).lstrip("@").strip('"'), size_of(ty)))
    return Program(functions, local_vars)


def describe_local(loc: Local) -> str:
    """A counted local as a student reads it: its array (``[20 x KdStackEntry]``, ``a struct holding
    [...]``, ``<16 x i32>``), or its type and how it is indexed (``Nested64 indexed by a variable``,
    ``Ray, a vector lane indexed by a variable``)."""
    if not loc.indexed or loc.bytes <= array_bytes(loc.ty):
        return describe(loc.ty)
    name = type_text(loc.ty)
    if loc.ty.kind == "struct" and (not loc.ty.name or name.split(".")[0] == "anon"):
        name = "a union" if loc.ty.name.lstrip("%").startswith("union.") else "a struct"
    return f"{name}{', a vector lane' if loc.bytes < size_of(loc.ty) else ''} indexed by a variable"


def reach(graph: dict[str, set[str]], start: str, stop: set[str]) -> list[str]:
    """``start`` and the functions it reaches, not entering those in ``stop``."""
    seen, order = {start}, [start]
    for f in order:
        for g in sorted(graph.get(f, ())):
            if g not in seen and g not in stop:
                seen.add(g)
                order.append(g)
    return order


def recursion(graph: dict[str, set[str]], funcs: list[str]) -> list[str] | None:
    """A path of calls among ``funcs`` that comes back to where it started (``[a, b, a]``), or None."""
    inside, state = set(funcs), {}

    def visit(f: str, path: list[str]) -> list[str] | None:
        state[f] = 1
        for g in sorted(graph.get(f, ())):
            if g not in inside:
                continue
            if state.get(g) == 1:
                return path[path.index(g):] + [g]
            if g not in state:
                found = visit(g, path + [g])
                if found:
                    return found
        state[f] = 2
        return None

    for f in funcs:
        if f not in state:
            found = visit(f, [f])
            if found:
                return found
    return None


@dataclass
class Measure:
    private_bytes: int
    largest: Local | None
    local_stores: int
    local_bytes: int
    recursion: list | None = None      # calls that come back to themselves: a stack of call frames


def measure(program: Program, graph: dict[str, set[str]], function: str, stop: set[str]) -> Measure:
    funcs = [f for f in reach(graph, function, stop) if f in program.functions]
    arrays = [loc for f in funcs for loc in program.functions[f]["locals"] if loc.bytes > 0]
    largest = max(arrays, key=lambda loc: loc.bytes, default=None)
    return Measure(sum(loc.bytes for loc in arrays), largest,
                   sum(program.functions[f]["local_stores"] for f in funcs),
                   max((b for _, b in program.local_vars), default=0), recursion(graph, funcs))


# --------------------------------------------------------------------------------------------------
# the grader: allowances from the reference
# --------------------------------------------------------------------------------------------------
def _fit(base: float, dstack: float, dshort: float, s0: int, k0: int, s1: int, k1: int) -> list[float]:
    b = (dstack - base) / (s1 - s0)
    c = (dshort - base) / (k1 - k0)
    return [base - b * s0 - c * k0, b, c]


def short_stack_default() -> int:
    """RT_SHORT_STACK_SIZE as the reference's rt_kd_shortstack.h defaults it (its #ifndef)."""
    from ..kernel_constants import parse_defines
    from .kernel_sources import read_text, reference_kernels
    try:
        return int(parse_defines(read_text(reference_kernels() / "shared" / "rt_kd_shortstack.h"))
                   .get("RT_SHORT_STACK_SIZE", 4))
    except OSError:
        return 4


@functools.lru_cache(maxsize=None)
def structure_rules(step: str) -> dict:
    """``{"stop": [...], "functions": {function: allowance}}`` for the functions of :data:`RULES` that
    ``step`` grades and whose reference is written (JSON-ready: it travels in the test's job). ``stop``:
    the lab functions of other steps (reference code: the measure does not enter them). An allowance
    holds the kind, the fitted indexed private bytes ``[a, b, c]`` (a + b RT_STACK_SIZE + c
    RT_SHORT_STACK_SIZE), the reference's largest such local as probed, and the local-memory facts."""
    from ..device.kernels import SceneFeatures, build_defines
    from ..device.variants import TRAVERSAL_SPECS, Variant
    from .config import load_config
    from .deps import opencl_ir
    from .kernel_sources import read_text, reference_kernels, region_owners
    from .lab_calls import ir_call_graph
    from .regions import stubbed_functions
    graded = [f for lf in load_config(step).files for f in lf.functions if f in RULES]
    if not graded:
        return {"stop": [], "functions": {}}
    owners = {f: s for (_, f), s in region_owners().items()}
    stop = {f for f, s in owners.items() if s != step}
    ref = reference_kernels()
    source = ref / "opencl" / f"{step}.cl"
    stubs = {f for p in sorted((ref / "shared").glob("*.h")) for f in stubbed_functions(read_text(p))}
    k0 = short_stack_default()
    s0, s1 = PROBE_STACK
    k1 = 2 * k0
    out = {}
    for f in graded:
        spec = next((t for t in TRAVERSAL_SPECS.values() if t.function == f), None)
        if f in stubs or spec is None or not source.is_file():
            continue

        def probe(s, k, counted):
            variant = Variant.paper(traversal=spec.name, count_work=counted)
            ir = opencl_ir(source, [ref / "shared", source.parent], {**build_defines(variant, SceneFeatures()),
                                                                      "RT_STACK_SIZE": s, "RT_SHORT_STACK_SIZE": k})
            return measure(read_program(ir), ir_call_graph(ir), f, stop)

        def larger(a: Measure, b: Measure) -> Measure:
            return a if (a.private_bytes, a.local_bytes) >= (b.private_bytes, b.local_bytes) else b

        # the tests compile with and without the work count (its counters are locals too): the larger
        m0 = larger(probe(s0, k0, False), probe(s0, k0, True))
        if m0.private_bytes or m0.local_bytes:
            ms = larger(probe(s1, k0, False), probe(s1, k0, True))
            mk = larger(probe(s0, k1, False), probe(s0, k1, True))
        else:
            ms = mk = m0
        out[f] = {"kind": RULES[f],
                  "private": _fit(m0.private_bytes, ms.private_bytes, mk.private_bytes, s0, k0, s1, k1),
                  "largest": [m0.largest.name, describe_local(m0.largest), m0.largest.bytes] if m0.largest else None,
                  "probe": [s0, k0],
                  "recursive": bool(m0.recursion),
                  "local_stores": m0.local_stores > 0,
                  "local": _fit(m0.local_bytes, ms.local_bytes, mk.local_bytes, s0, k0, s1, k1)}
    return {"stop": sorted(stop), "functions": out}


# --------------------------------------------------------------------------------------------------
# the test process: the check
# --------------------------------------------------------------------------------------------------
def _at(fit: list[float], s: int, k: int) -> int:
    return int(round(fit[0] + fit[1] * s + fit[2] * k))


def straight_line(ir: str, function: str) -> bool:
    """Whether ``function``'s IR body is straight-line code that calls nothing: a stub's (``return;``), which
    walks nothing, so the packet's stub may leave local memory alone and still compile. Read from the
    very IR the rule judges, not from the text's markers (a decoy region in a comment or under ``#if 0``
    said "stub" for a function that held a copied walk)."""
    body = next((b for sym, b in bodies(ir) if sym == function), None)
    return body is not None and not re.search(r'^\s+(?:%\S+ = )?(?:tail |musttail |notail )?(?:call|invoke|br|switch|'
                                              r'indirectbr|callbr)\b', body, re.M)


def structure_problem(ir: str, graph: dict[str, set[str]], rules: dict, defines: dict) -> str | None:
    """Why a graded function of the program (LLVM IR ``ir``, its call graph ``graph``, compiled with
    ``defines``) breaks the structure rule (the first found), or None. ``rules``: structure_rules'."""
    functions = (rules or {}).get("functions") or {}
    if not functions:
        return None
    program = read_program(ir)
    stop = set(rules.get("stop", ()))
    s = int(defines.get("RT_STACK_SIZE", PROBE_STACK[0]))
    k = int(defines.get("RT_SHORT_STACK_SIZE", 4))
    for f in sorted(functions):
        if f not in graph or f not in program.functions:
            continue
        rule = functions[f]
        kind = rule["kind"]
        got = measure(program, graph, f, stop)
        allowed = _at(rule["private"], s, k)
        why = WHY.get(f, f"{f} keeps no more indexed private storage than its reference").format(k=k)
        if got.private_bytes > allowed + SLACK_BYTES:
            big = got.largest
            where = "" if big.function == f else f" (in {big.function}, which {f} calls)"
            more = f"; {got.private_bytes} B in all" if got.private_bytes != big.bytes else ""
            if allowed > 0:
                theirs = f"the reference {f} keeps {allowed} B"
                ref_big = rule.get("largest")
                if ref_big and ref_big[2] == allowed:
                    theirs += f" (its {ref_big[0]}, {ref_big[1]})"
            else:
                theirs = f"the reference {f} keeps none (0 B)"
            return (f"{f} keeps a per-ray private array {big.name}, {describe_local(big)} = {big.bytes} B{where}"
                    f"{more}, where {theirs}: {why}")
        if got.recursion and not rule.get("recursive"):
            where = "" if got.recursion[0] == f else f", in {got.recursion[0]}, which {f} calls"
            return (f"{f} keeps a per-ray stack of call frames: {' calls '.join(got.recursion)} (recursion{where}), "
                    f"where the reference {f} calls nothing recursively: {why}")
        if kind == "packet":
            if rule.get("local_stores") and not got.local_stores and not straight_line(ir, f):
                return (f"{f} writes nothing to the block's local memory, where the reference {f} keeps the "
                        f"packet's stack: {why}")
            limit = LOCAL_FACTOR * _at(rule["local"], s, k)
            if limit and got.local_bytes > limit:
                name = max(program.local_vars, key=lambda v: v[1])[0]
                return (f"{f}'s program holds {got.local_bytes} B of local memory in {name}, more than "
                        f"{LOCAL_FACTOR}x the reference's {_at(rule['local'], s, k)} B (a stack for each ray "
                        f"of the block, not one for the packet?): {why}")
    return None
