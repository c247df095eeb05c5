"""nvcc's PTX as a program the grader can read (it has no NVIDIA GPU: a CUDA function cannot be run,
but its PTX can be parsed and, for a kernel as small as the lab 01 harness's ``fetch_scene``,
followed): :func:`parse` (instructions and labels of an ``.entry``) and :func:`follow`, which runs an
entry with concrete parameters and thread indices. Branches are followed where their predicate is
concrete (the thread's index, a parameter), integer arithmetic is computed, and everything else
(a texture fetch, a load, floating point) stands for a symbol naming what it is: "component x of
element c of the texture in parameter k". The stores the kernel makes come back, as values or
symbols. Where the PTX branches on a symbol, calls a function or runs past :data:`MAX_STEPS`, it
cannot be followed (:class:`CannotFollow`, saying why).

What the grader reads with it: rtlab.course.ptx_facts.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

MAX_STEPS = 20000
_COMMENT_RE = re.compile(r"//[^\n]*|/\*.*?\*/", re.S)
_LABEL_RE = re.compile(r"^\s*([$\w.]+):\s*")
REG_RE = re.compile(r"%[A-Za-z_$][\w$]*(?:\.[xyzw])?")


def entry_body(ptx: str, kernel: str) -> str:
    """The text of ``.entry kernel`` (empty when it is not in the PTX)."""
    m = re.search(rf"\.entry {re.escape(kernel)}\s*\(.*?\n}}", ptx, re.S)
    return m.group(0) if m else ""


def entry_params(body: str) -> list[str]:
    head = body[:body.find(")")] if ")" in body else ""
    return re.findall(r"\.param\s+\.\w+\s+(?:\.ptr\s+(?:\.\w+\s+)*)?(?:\.align\s+\d+\s+)?([\w$]+)", head)


@dataclass
class Ins:
    guard: str | None       # "%p1", "!%p1" or None
    op: str                 # "add.s32"
    args: list[str]


def parse(body: str) -> tuple[list[Ins], dict[str, int]]:
    """Instructions of an entry's body and its labels (label -> index of the next instruction)."""
    start = body.find("{")
    text = _COMMENT_RE.sub(" ", body[start + 1:body.rfind("}")] if start >= 0 else body)
    out: list[Ins] = []
    labels: dict[str, int] = {}
    for stmt in text.split(";"):
        s = stmt.strip()
        while True:
            m = _LABEL_RE.match(s)
            if not m:
                break
            labels[m.group(1)] = len(out)
            s = s[m.end():]
        s = s.strip()
        if not s or s.startswith("."):           # declarations (.reg, .shared, .local)
            continue
        guard = None
        if s.startswith("@"):
            g, _, s = s.partition(" ")
            guard = g[1:]
            s = s.strip()
        op, _, rest = s.partition(" ")
        if op.startswith("{") or op.startswith("}"):
            continue
        out.append(Ins(guard, op.strip(), _split_args(rest)))
    return out, labels


def _split_args(text: str) -> list[str]:
    args, depth, cur = [], 0, ""
    for c in text:
        if c in "[{":
            depth += 1
        elif c in "]}":
            depth -= 1
        if c == "," and depth == 0:
            args.append(cur.strip())
            cur = ""
        else:
            cur += c
    if cur.strip():
        args.append(cur.strip())
    return args


def operands(arg: str) -> list[str]:
    """``{%r1, %r2}`` -> [%r1, %r2]; a plain operand -> [it]."""
    arg = arg.strip()
    if arg.startswith("{") and arg.endswith("}"):
        return [a.strip() for a in arg[1:-1].split(",") if a.strip()]
    return [arg]


def type_bits(op: str) -> int:
    for part in reversed(op.split(".")):
        m = re.fullmatch(r"[subf](\d+)", part)
        if m:
            return int(m.group(1))
    return 64


def _signed(v: int, bits: int) -> int:
    v &= (1 << bits) - 1
    return v - (1 << bits) if v >> (bits - 1) else v


def immediate(text: str):
    t = text.strip()
    if re.fullmatch(r"0[fF][0-9A-Fa-f]{8}", t) or re.fullmatch(r"0[dD][0-9A-Fa-f]{16}", t):
        return int(t[2:], 16)
    if re.fullmatch(r"-?0[xX][0-9A-Fa-f]+U?", t):
        return int(t.rstrip("U"), 16)
    if re.fullmatch(r"-?\d+U?", t):
        return int(t.rstrip("U"))
    return None


class CannotFollow(Exception):
    pass


def _tex_class(op: str) -> str:
    parts = op.split(".")
    dtype = parts[-2] if len(parts) >= 2 else "?"
    return "f32" if dtype.startswith("f") else "i32"


def follow(body: str, params: dict, special: dict) -> list[tuple]:
    """Run an entry's PTX with concrete ``params`` (name -> value; a pointer param as ("param", k, 0))
    and special registers (``%tid.x``...): the stores it makes, in order, as (op, address, values)."""
    return _Run(body, params, special).run()


class _Run:
    """One run of an entry: its registers, the stores made so far."""

    def __init__(self, body: str, params: dict, special: dict):
        self.code, self.labels = parse(body)
        self.params, self.special = params, special
        self.regs: dict[str, object] = {}
        self.stores: list[tuple] = []

    def value(self, a: str):
        a = a.strip()
        imm = immediate(a)
        if imm is not None:
            return imm
        if a in self.special:
            return self.special[a]
        if a in self.regs:
            return self.regs[a]
        return ("undef", a) if a.startswith("%") else ("sym", a)   # a global's address (a __shared__ array)

    def address(self, a: str):
        inner = a.strip()[1:-1].strip()
        m = re.fullmatch(r"([^+\-]+?)\s*([+-]\s*-?\d+)?", inner)
        base, off = (m.group(1).strip(), int(m.group(2).replace(" ", "")) if m.group(2) else 0) if m else (inner, 0)
        return _add(self.params[base] if base in self.params else self.value(base), off)

    def set(self, dest: str, vals: list) -> None:
        for d, v in zip(operands(dest), vals):
            self.regs[d] = v

    def run(self) -> list[tuple]:
        pc, steps = 0, 0
        while pc < len(self.code):
            steps += 1
            if steps > MAX_STEPS:
                raise CannotFollow(f"it runs more than {MAX_STEPS} instructions")
            ins = self.code[pc]
            pc += 1
            if ins.guard:
                p = self.value(ins.guard.lstrip("!"))
                if not isinstance(p, bool):
                    raise CannotFollow(f"'{ins.op}' depends on a value it read (@{ins.guard})")
                if p == ins.guard.startswith("!"):
                    continue
            base = ins.op.split(".")[0]
            if base in ("ret", "exit"):
                break
            if base == "bra":
                if ins.args[0] not in self.labels:
                    raise CannotFollow(f"it jumps to {ins.args[0]}, not a label of the kernel")
                pc = self.labels[ins.args[0]]
                continue
            if base in ("call", "brx"):
                raise CannotFollow(f"it calls a function ({ins.op} {' '.join(ins.args)[:60]})")
            self.step(ins, base)
        return self.stores

    def step(self, ins: Ins, base: str) -> None:
        """One instruction that is not a jump: a store, a load, a texture fetch, arithmetic."""
        a = ins.args
        if base == "st":
            self.stores.append((ins.op, self.address(a[0]), tuple(self.value(v) for v in operands(a[1]))))
        elif base == "ld":
            n = len(operands(a[0]))
            self.set(a[0], [self.address(a[1])] if ".param" in ins.op else
                     [("load", ins.op, self.address(a[1]), k) for k in range(n)])
        elif base in ("tex", "tld4"):
            parts = _split_args(a[1].strip()[1:-1])
            handle = self.params[parts[0]] if parts[0] in self.params else self.value(parts[0])
            coords = tuple(_norm(self.value(c), 32) for c in operands(parts[1])) if len(parts) > 1 else ()
            for k, d in enumerate(operands(a[0])):
                self.regs[d] = ("tex", ins.op.split(".")[1], _tex_class(ins.op), _handle(handle), coords, "xyzw"[k % 4])
        elif base == "mov" and a[1].strip().startswith("{"):         # mov.b64 %rd1, {%r1, %r2}: pack
            parts = [self.value(x) for x in operands(a[1])]
            self.regs[a[0].strip()] = sum((x & 0xFFFFFFFF) << (32 * k) for k, x in enumerate(parts)) \
                if all(isinstance(x, int) for x in parts) else ("pack",) + tuple(parts)
        elif base == "mov" and a[0].strip().startswith("{"):         # mov.b64 {%r1, %r2}, %rd1: unpack
            src = self.value(a[1])
            for k, d in enumerate(operands(a[0])):
                self.regs[d] = (src >> (32 * k)) & 0xFFFFFFFF if isinstance(src, int) else ("part", src, k)
        else:
            result = _compute(ins.op, [self.value(x) for x in a[1:]])
            if base == "setp" and "|" in a[0]:
                p, q = a[0].split("|")
                self.regs[p.strip()] = result
                self.regs[q.strip()] = (not result) if isinstance(result, bool) else ("not", result)
            else:
                self.regs[operands(a[0])[0]] = result


def _handle(h):
    if isinstance(h, tuple) and h[:1] == ("param",):
        return h[1]
    return h


def _norm(v, bits: int):
    return _signed(v, bits) if isinstance(v, int) and not isinstance(v, bool) else v


def _add(base, off: int):
    if off == 0:
        return base
    if isinstance(base, int) and not isinstance(base, bool):
        return base + off
    if isinstance(base, tuple) and base[:1] == ("param",):
        return ("param", base[1], base[2] + off)
    return ("add", base, off)


_CMP = {"eq": lambda x, y: x == y, "ne": lambda x, y: x != y, "lt": lambda x, y: x < y, "le": lambda x, y: x <= y,
        "gt": lambda x, y: x > y, "ge": lambda x, y: x >= y, "lo": lambda x, y: x < y, "ls": lambda x, y: x <= y,
        "hi": lambda x, y: x > y, "hs": lambda x, y: x >= y}


def _is_float(parts: list[str]) -> bool:
    return any(re.fullmatch(r"f\d+", p) for p in parts[1:])


def _compute(op: str, srcs: list):
    """One instruction's result from its sources: an int or bool where they are concrete integers,
    else a symbol naming the operation (pointer arithmetic on a parameter kept as an offset)."""
    parts = op.split(".")
    base = parts[0]
    concrete = all(isinstance(s, (int, bool)) for s in srcs)
    if base in ("mov", "cvta"):
        return srcs[0]
    if base == "add" and len(srcs) == 2 and not _is_float(parts):
        x, y = srcs
        if isinstance(x, tuple) and isinstance(y, int):
            return _add(x, y)
        if isinstance(y, tuple) and isinstance(x, int):
            return _add(y, x)
    if base == "selp" and len(srcs) == 3 and isinstance(srcs[2], bool):
        return srcs[0] if srcs[2] else srcs[1]
    if not concrete or _is_float(parts):
        return (op,) + tuple(srcs)          # floating point, or a value read: a symbol
    if any(isinstance(x, bool) for x in srcs):
        return _PRED.get(base, lambda xs: (op,) + tuple(xs))(srcs)
    bits = type_bits(op)
    signed = any(p.startswith("s") and p[1:].isdigit() for p in parts)
    mask = (1 << bits) - 1
    if base == "cvt":                   # cvt.u64.u32: the destination's type first, the source's last
        src_bits = type_bits(parts[-1])
        x = _signed(srcs[0], src_bits) if parts[-1].startswith("s") else srcs[0] & ((1 << src_bits) - 1)
        return x & ((1 << type_bits(parts[1])) - 1)
    wide = [2 * bits if "wide" in parts and k == 2 else bits for k in range(len(srcs))]   # mad.wide's addend
    xs = [_signed(int(x), w) if signed else int(x) & ((1 << w) - 1) for x, w in zip(srcs, wide)]
    if base == "setp":
        return _CMP[parts[1]](xs[0], xs[1]) if parts[1] in _CMP else (op,) + tuple(srcs)
    fn = _INTEGER.get(base)
    try:
        out = fn(xs, bits, parts) if fn else None
    except (IndexError, ValueError, ZeroDivisionError):
        out = None
    if out is None:
        return (op,) + tuple(srcs)
    return out & ((1 << (2 * bits)) - 1 if "wide" in parts else mask)


def _divide(x: int, y: int) -> int:
    """C's division: toward zero."""
    return abs(x) // abs(y) * (1 if (x >= 0) == (y >= 0) else -1)


def _mul(xs, bits, parts):
    prod = xs[0] * xs[1]
    return prod >> bits if "hi" in parts else prod


# integer instructions on their sources (signed or masked to the type's width as its type says)
_INTEGER = {
    "add": lambda xs, bits, parts: xs[0] + xs[1],
    "sub": lambda xs, bits, parts: xs[0] - xs[1],
    "mul": _mul,
    "mad": lambda xs, bits, parts: _mul(xs, bits, parts) + xs[2],
    "div": lambda xs, bits, parts: _divide(xs[0], xs[1]),
    "rem": lambda xs, bits, parts: xs[0] - _divide(xs[0], xs[1]) * xs[1],
    "and": lambda xs, bits, parts: xs[0] & xs[1],
    "or": lambda xs, bits, parts: xs[0] | xs[1],
    "xor": lambda xs, bits, parts: xs[0] ^ xs[1],
    "not": lambda xs, bits, parts: ~xs[0],
    "neg": lambda xs, bits, parts: -xs[0],
    "shl": lambda xs, bits, parts: xs[0] << xs[1] if xs[1] < bits else 0,
    "shr": lambda xs, bits, parts: xs[0] >> min(xs[1], bits),
    "min": lambda xs, bits, parts: min(xs[0], xs[1]),
    "max": lambda xs, bits, parts: max(xs[0], xs[1]),
    "abs": lambda xs, bits, parts: abs(xs[0]),
}
_PRED = {"and": lambda xs: bool(xs[0] and xs[1]), "or": lambda xs: bool(xs[0] or xs[1]),
         "xor": lambda xs: bool(xs[0]) != bool(xs[1]), "not": lambda xs: not xs[0]}


def text_of(v) -> str:
    """A followed value as a message shows it."""
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, int):
        return str(_signed(v, 64) if v >> 63 else v)
    if isinstance(v, tuple) and v[:1] == ("tex",):
        coords = ",".join(text_of(c) for c in v[4])
        return f"{v[2]} #{text_of(v[3])}[{coords}].{v[5]}" + ("" if v[1] == "1d" else f" ({v[1]})")
    if isinstance(v, tuple) and v[:1] == ("param",):
        return f"param{v[1]}" + (f"+{v[2]}" if v[2] else "")
    if isinstance(v, tuple):
        return f"{v[0]}(" + ", ".join(text_of(x) for x in v[1:]) + ")"
    return str(v)
