"""Which private storage a program's LLVM IR reaches at a variable offset: the structure rule's reading
(rtlab.course.structure) of where a traversal keeps a stack. A stack is a variable index into memory,
whatever the type of the memory: an array, structs of structs, a union, a copy of the Ray. One pass
over the IR (before any optimisation: every local an ``alloca``) follows each local's address through
whatever derives a pointer from it, and each function's summary says which of its parameters it
indexes or returns (:func:`indexed_allocas`).
"""
from __future__ import annotations

import re

from .lab_calls import _DEFINE_RE, SYMBOL
from .llvm_types import TypeTable, size_of

_ALLOCA_RE = re.compile(r'^\s*(%"[^"]*"|%[\w.$-]+) = alloca (?:inalloca )?(.*)$', re.M)


def bodies(ir: str):
    """(symbol, text from the define's parameters to its closing brace) of each function defined."""
    starts = list(_DEFINE_RE.finditer(ir))
    for k, m in enumerate(starts):
        end = ir.find("\n}", m.end())
        yield m.group(2), ir[m.end():end if end >= 0 else (starts[k + 1].start() if k + 1 < len(starts) else len(ir))]


# --------------------------------------------------------------------------------------------------
# which private storage is indexed: a variable offset into an alloca, through whatever pointer
# --------------------------------------------------------------------------------------------------
_VALUE_RE = re.compile(r'%"[^"]*"|%[\w.$-]+')
_INSTR_RE = re.compile(r'^\s+(?:(%"[^"]*"|%[\w.$-]+) = )?(?:(?:tail|musttail|notail) )?([a-z]\w*)\b(.*)$')
_CALLEE_RE = re.compile(SYMBOL + r'\(')
_HARMLESS_INTRINSICS = ("llvm.lifetime.", "llvm.dbg.", "llvm.assume", "llvm.experimental.noalias",
                        "llvm.invariant.", "llvm.var.annotation")


def _split_top(text: str) -> list[str]:
    """``text`` split at the commas outside any (), [], {}, <>."""
    parts, depth, start = [], 0, 0
    for i, c in enumerate(text):
        if c in "([{<":
            depth += 1
        elif c in ")]}>":
            depth -= 1
        elif c == "," and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return parts


def _inside(text: str, open_at: int) -> str:
    """The text between the parenthesis at ``open_at`` and its match."""
    depth = 0
    for i in range(open_at, len(text)):
        depth += text[i] == "("
        depth -= text[i] == ")"
        if depth == 0:
            return text[open_at + 1:i]
    return text[open_at + 1:]


# A stack kept in fixed slots and reached by control flow is indexed too, whatever the spelling: a
# value that may point at SLOT_POINTERS places (a switch or a ?: chain returning &slots->e5), an object
# read or written at SLOT_FIELDS constant offsets (_Slots), or SLOT_POINTERS locals a switch's cases pick
# among (switch_slots): lab 00's walk over 64 named slots or 64 separate locals is a stack. The references
# stay well below: no value points at 2 places, no object has 8 offsets.
SLOT_POINTERS = 8
SLOT_FIELDS = 24


_SWITCH_RE = re.compile(r'^\s+switch \S+ [^,]+, label %[\w.$-]+ \[(.*?)\]', re.M | re.S)
_CASE_RE = re.compile(r'label %([\w.$-]+)')
_BLOCK_RE = re.compile(r'^([\w.$-]+):', re.M)


def switch_slots(body: str) -> set[str]:
    """The allocas a ``switch`` picks among: those its case blocks touch that not every case block
    touches, when they are SLOT_POINTERS or more (64 separate locals, or 8 structs of slots, one a case:
    a stack indexed by control flow, whatever the slots' spelling)."""
    allocas = {m.group(1) for m in _ALLOCA_RE.finditer(body)}
    if not allocas or "switch " not in body:
        return set()
    starts = list(_BLOCK_RE.finditer(body))
    blocks = {m.group(1): body[m.end():starts[k + 1].start() if k + 1 < len(starts) else len(body)]
              for k, m in enumerate(starts)}
    out: set[str] = set()
    for sw in _SWITCH_RE.finditer(body):
        labels = list(dict.fromkeys(_CASE_RE.findall(sw.group(1))))      # cases sharing a block count once
        touched = [set(_VALUE_RE.findall(blocks.get(label, ""))) & allocas for label in labels]
        if len(touched) >= SLOT_POINTERS:
            picked = set().union(*touched) - set.intersection(*touched)
            if len(picked) >= SLOT_POINTERS:
                out |= picked
    return out


def _variable_extent(types: TypeTable, parts: list[str]) -> int | None:
    """Bytes a getelementptr's first variable index ranges over: the array or vector it indexes inside
    the source type (a per-axis ``float o[3]`` of a larger state struct: 12 B, not the struct), or None
    (all of the object) where the variable index is the first one (pointer arithmetic) or the type
    cannot be read."""
    try:
        ty = types.parse(parts[0].replace("inbounds", "").strip())
        for k, index in enumerate(parts[2:]):
            if _VALUE_RE.search(index) and k > 0:
                return size_of(ty) if ty.kind in ("array", "vector") else None
            if _VALUE_RE.search(index):
                return None
            if k == 0:
                continue                       # the first index steps over whole objects
            n = int(index.strip().split()[-1])
            ty = ty.members[n] if ty.kind == "struct" else ty.elem
    except (IndexError, ValueError, AssertionError, AttributeError, TypeError):
        return None
    return None


class _Slots:
    """Where each address value of one function may point: (source, constant GEP indices) pairs, merged
    through phis, selects, casts, pointer locals and returned parameters, so that a slot picked by
    control flow (a switch, a chain of ?:, a case per field) shows as the many places it is."""

    def __init__(self, taint):
        self.taint = taint
        self.locs: dict = {}        # value -> {(source, key)}
        self.held: dict = {}        # source -> {(source, key)} of the addresses stored in it
        self.touched: dict = {}     # source -> keys it is read or written at

    def of(self, v):
        if not v:
            return set()
        return self.locs.get(v) or {(src, ()) for src in self.taint.get(v, ())}

    def grow(self, res, places) -> bool:
        if res and places and not places <= self.locs.setdefault(res, set()):
            self.locs[res] |= places
            return True
        return False

    def gep(self, res, base, indices) -> bool:
        return self.grow(res, {(src, key + indices) for src, key in self.of(base)})

    def store(self, value, addr) -> bool:
        self.touch(addr)
        places, grew = self.of(value) if value in self.locs or value in self.taint else set(), False
        for src in self.taint.get(addr, ()) if addr else ():
            if places and not places <= self.held.setdefault(src, set()):
                self.held[src] |= places
                grew = True
        return grew

    def load(self, res, addr) -> bool:
        self.touch(addr)
        return self.grow(res, set().union(*(self.held.get(src, set()) for src in self.taint.get(addr, ()))))

    def touch(self, addr):
        for src, key in self.of(addr):
            if key:
                self.touched.setdefault(src, set()).add(key)

    def indexed(self) -> set:
        """Sources reached as slots: any value that may point at SLOT_POINTERS places, or one source
        read or written at SLOT_FIELDS constant offsets."""
        out = {src for places in self.locs.values() if len(places) >= SLOT_POINTERS for src, _ in places}
        return out | {src for src, keys in self.touched.items() if len(keys) >= SLOT_FIELDS}


# Why long: one data-flow pass to a fixed point over every instruction kind that moves an address (GEP,
# casts, selects, phis, loads and stores through locals, calls with per-function summaries): split, each
# part would need the whole state.
def indexed_allocas(ir: str, types: TypeTable) -> dict[tuple[str, str], int | None]:
    """(function symbol, alloca) -> the bytes of it reached at a variable offset (None: all of it),
    for every private variable that the program reaches so: a ``getelementptr`` with a non-constant
    index or a ``memcpy``/``memset`` of variable length (all of it), a vector's lane by a variable
    (that vector's bytes), on a pointer derived from it however: constant GEPs, casts, selects, a
    pointer kept in another local and loaded again, a parameter of a function it is passed to (each
    function's summary says which of its parameters it indexes or returns). What the reading cannot
    follow counts as indexed: the address turned into an integer, stored anywhere but a local,
    passed to a function that is only declared (an OpenCL builtin), or kept in a local whose own
    address is passed on. Flow-insensitive, to a fixed point: a stack is a variable index into
    memory, whatever the type of that memory says."""
    names = set(types.text)
    funcs = []
    for symbol, body in bodies(ir):
        params = [next(iter([v for v in _VALUE_RE.findall(p) if v not in names][-1:]), None)
                  for p in _split_top(_inside("(" + body, 0))]
        code = []
        for line in body.split("\n")[1:]:
            m = _INSTR_RE.match(line)
            if m:
                code.append((m.group(1), m.group(2), m.group(3).split(", !")[0]))
        funcs.append((symbol, params, code))
    defined = {symbol for symbol, _, _ in funcs}
    switched = {symbol: switch_slots(body) for symbol, body in bodies(ir)}
    summary = {symbol: ({}, set()) for symbol in defined}    # ({parameter: bytes indexed}, parameters returned)
    marked: dict = {}

    def vals(text: str) -> list[str]:
        return [v for v in _VALUE_RE.findall(text) if v not in names]

    def state():
        return sorted(marked.items(), key=str), sorted(((k, sorted(a.items(), key=str), sorted(b))
                                                         for k, (a, b) in summary.items()), key=str)

    for _ in range(len(funcs) + 2):
        before = state()
        for symbol, params, code in funcs:
            taint = {p: {("p", i)} for i, p in enumerate(params) if p}     # value -> what it points into
            contents: dict = {}                 # source -> sources whose addresses it holds
            slots = _Slots(taint)               # where each address may point: slots picked by control flow
            vec_from: dict = {}                 # vector value -> the memory it was loaded from
            indexed_params, returned = summary[symbol]

            def t(v):
                return taint.get(v, set()) if v else set()

            def mark(srcs, extent=None):
                for src in list(srcs):
                    table, key = (marked, (symbol, src[1])) if src[0] == "a" else (indexed_params, src[1])
                    old = table.get(key, 0)
                    table[key] = None if extent is None or old is None else max(old, extent)

            def held(srcs):
                """What the memory of ``srcs`` holds, and what that holds, on down."""
                out, todo = set(), list(srcs)
                while todo:
                    for c in contents.get(todo.pop(), ()):
                        if c not in out:
                            out.add(c)
                            todo.append(c)
                return out

            def add(res, srcs, table=taint):
                if res and srcs and not srcs <= table.setdefault(res, set()):
                    table[res] |= srcs
                    return True
                return False

            changed = True
            while changed:
                changed = False
                for res, op, rest in code:
                    if op == "alloca":
                        changed |= add(res, {("a", res)})
                    elif op == "load":
                        v = vals(rest)
                        srcs = t(v[-1]) if v else set()
                        changed |= add(res, set().union(*(contents.get(s, set()) for s in srcs)))
                        changed |= add(res, set(srcs), vec_from)
                        changed |= slots.load(res, v[-1] if v else None)
                    elif op == "store":
                        parts = _split_top(rest)
                        value, addr = vals(parts[0]), vals(parts[1]) if len(parts) > 1 else []
                        tv, ta = t(value[-1] if value else None), t(addr[-1] if addr else None)
                        changed |= slots.store(value[-1] if value else None, addr[-1] if addr else None)
                        if tv:
                            if not ta or any(s[0] == "p" for s in ta):
                                mark(tv | held(tv))             # a local's address leaves the frame
                            for s in ta:
                                if not tv <= contents.setdefault(s, set()):
                                    contents[s] |= tv
                                    changed = True
                    elif op == "getelementptr":
                        parts = _split_top(rest)
                        base = vals(parts[1]) if len(parts) > 1 else []
                        tb = t(base[-1] if base else None)
                        changed |= add(res, set(tb))
                        if any(vals(p) for p in parts[2:]):
                            mark(tb, _variable_extent(types, parts))
                        elif res and tb:
                            changed |= slots.gep(res, base[-1], tuple(p.strip() for p in parts[2:]))
                    elif op in ("extractelement", "insertelement"):
                        parts = _split_top(rest)
                        lane = parts[1 if op == "extractelement" else 2] if len(parts) > 1 else ""
                        vec = vals(parts[0])
                        if vals(lane) and vec:
                            try:
                                extent = size_of(types.parse(parts[0].strip().rsplit(" ", 1)[0]))
                            except (IndexError, ValueError, AssertionError):
                                extent = None
                            mark(vec_from.get(vec[-1], set()), extent)
                        changed |= add(res, set().union(*(t(v) for v in vals(rest))))
                        if vec:
                            changed |= add(res, set(vec_from.get(vec[-1], set())), vec_from)
                    elif op == "ptrtoint":
                        srcs = set().union(*(t(v) for v in vals(rest)))
                        mark(srcs)
                        changed |= add(res, srcs)
                    elif op == "call":
                        m = _CALLEE_RE.search(rest)
                        if not m:
                            mark(set().union(*(t(v) for v in vals(rest))))
                            continue
                        callee = m.group(2)
                        args = [vals(a) for a in _split_top(_inside(rest, m.end() - 1))]
                        targs = [t(a[-1]) if a else set() for a in args]
                        if callee.startswith(_HARMLESS_INTRINSICS):
                            continue
                        if callee.startswith(("llvm.memcpy", "llvm.memmove", "llvm.memset")):
                            for a in args[:2]:
                                slots.touch(a[-1] if a else None)     # a struct copied into or out of a slot
                            if len(args) > 2 and args[2]:
                                mark(set().union(*targs[:2]))       # a variable length
                            elif callee.startswith(("llvm.memcpy", "llvm.memmove")) and len(targs) > 1:
                                moved = held(targs[1])
                                if moved and (not targs[0] or any(s[0] == "p" for s in targs[0])):
                                    mark(moved)
                                for s in targs[0]:
                                    if not moved <= contents.setdefault(s, set()):
                                        contents[s] |= moved
                                        changed = True
                            continue
                        for i, ta in enumerate(targs):
                            if not ta:
                                continue
                            mark(held(ta))                      # pointers kept in what it passes on
                            if callee not in summary:
                                mark(ta)
                            elif i in summary[callee][0]:
                                mark(ta, summary[callee][0][i])
                            if callee in summary and i in summary[callee][1]:
                                changed |= add(res, set(ta))
                                changed |= slots.grow(res, slots.of(args[i][-1]))
                    elif op == "ret":
                        for v in vals(rest):
                            returned |= {s[1] for s in t(v) if s[0] == "p"}
                    elif res:
                        changed |= add(res, set().union(*(t(v) for v in vals(rest))))
                        changed |= slots.grow(res, set().union(*(slots.of(v) for v in vals(rest)
                                                                 if v in slots.locs or v in taint)))
                        if op == "shufflevector":              # a float3 is loaded as 4 lanes, then shuffled
                            changed |= add(res, set().union(*(vec_from.get(v, set()) for v in vals(rest))),
                                           vec_from)
            mark(slots.indexed() | {("a", name) for name in switched[symbol]})
        if state() == before:
            break
    return marked
