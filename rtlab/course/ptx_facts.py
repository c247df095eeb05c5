"""What lab 01's CUDA functions do, read from nvcc's PTX (rtlab.course.ptx; the grader has no NVIDIA
GPU, so a CUDA function cannot be run):

* :func:`follow_fetch_scene` follows the harness's ``fetch_scene`` for each scene buffer (its
  ``which`` argument) and a few threads: what it stores into ``out``, with each texture fetch a
  symbol "texture k, element c, component x". Compared with the reference's PTX followed the same
  way (rtlab.course.checks.nvcc), a fetch of element 0, of i + 1 or of i & 1023, or a constant,
  stores other symbols than ``tex nodes[i]``; equivalent arithmetic (``3 * (i / 3) + i % 3``) stores
  the same.
* :func:`shared_stores` reads a kernel's ``st.shared`` instructions: for each, the byte offset in its
  slot and whether the stored value comes from the kernel's inputs (a load from global or constant
  memory, a texture: where the ray's origin and direction come from), or is a constant (the stub's
  empty ray) or only the thread's index.

Limits: the comparison is structural. The ray's fields stored into each other's places, or a value
from the inputs that is not the ray, are not seen; nvcc versions may change the PTX (the reference
goes through the same nvcc on the same machine, so both change together).
"""
from __future__ import annotations

import re

from .ptx import REG_RE, CannotFollow, Ins, entry_body, entry_params, follow, immediate, operands, parse, text_of, type_bits

# (block, thread) of 64-thread blocks: elements 0, 1, 5, 71, 1000, 262143 and about 2^29 of n = 2^30
FETCH_THREADS = ((0, 0), (0, 1), (0, 5), (1, 7), (15, 40), (4095, 63), (8388607, 33))
FETCH_BLOCK = 64
FETCH_N = 1 << 30


def follow_fetch_scene(ptx: str, buffers: int = 7) -> dict:
    """``{"stores": {which: [per thread: [per store: [address, [values]]]]}}`` (as text), or
    ``{"error": why}``: what fetch_scene stores for each buffer ``which`` < ``buffers`` and each of
    :data:`FETCH_THREADS`, with n = :data:`FETCH_N`. A texture fetch's value reads
    ``"i32 #k[c].x"``: component x of element c of the texture in parameter k, read as int (or f32)."""
    body = entry_body(ptx, "fetch_scene")
    if not body:
        return {"error": "no fetch_scene kernel in the PTX"}
    names = entry_params(body)
    if len(names) < buffers + 3:
        return {"error": f"fetch_scene has {len(names)} parameters, not {buffers + 3}"}
    out: dict[str, list] = {}
    try:
        for which in range(buffers):
            rows = []
            for block, thread in FETCH_THREADS:
                params = {n: ("param", k, 0) for k, n in enumerate(names)}
                params[names[buffers]] = which
                params[names[buffers + 1]] = FETCH_N
                special = {"%tid.x": thread, "%ntid.x": FETCH_BLOCK, "%ctaid.x": block, "%nctaid.x": 1 << 14,
                           "%tid.y": 0, "%ntid.y": 1, "%ctaid.y": 0, "%tid.z": 0, "%ntid.z": 1, "%ctaid.z": 0}
                stores = follow(body, params, special)
                rows.append([[f"{op} {text_of(addr)}", [text_of(v) for v in vals]] for op, addr, vals in stores])
            out[str(which)] = rows
    except CannotFollow as e:
        return {"error": str(e)}
    return {"stores": out}


def fetch_element(block: int, thread: int) -> int:
    return block * FETCH_BLOCK + thread


_INPUT_LOADS = ("ld.global", "ld.const", "ldu.global", "tex", "tld4", "ld.param")
_ELEM_BYTES = {8: 1, 16: 2, 32: 4, 64: 8}


def _input_registers(code: list[Ins]) -> set[str]:
    """The registers whose value comes from the kernel's inputs: loaded from global or constant memory
    or a texture (ld.param excluded: sizes and pointers), or computed from such a value; a value
    loaded back from local or shared memory counts once a value from the inputs is stored there.
    A worklist over the uses: linear in the PTX's size."""
    uses: dict[str, list[int]] = {}
    loads = {"local": [], "shared": []}
    dests: list[list[str]] = []
    for k, ins in enumerate(code):
        base = ins.op.split(".")[0]
        if base in ("st", "bra", "ret", "exit", "bar", "call") or not ins.args:
            dests.append([])
        else:
            dests.append(operands(ins.args[0].split("|")[0]))
        if base == "st":
            for r in REG_RE.findall(" ".join(ins.args[1:])):
                uses.setdefault(r, []).append(k)
        elif base == "ld":
            space = ins.op.split(".")[1] if "." in ins.op else ""
            if space in loads:
                loads[space].append(k)
        elif dests[-1]:
            for r in REG_RE.findall(" ".join(ins.args[1:])):
                uses.setdefault(r, []).append(k)
    tainted: set[str] = set()
    memory = {"local": False, "shared": False}
    work = [k for k, ins in enumerate(code)
            if ins.op.startswith(_INPUT_LOADS) and not ins.op.startswith("ld.param")]

    def mark(k: int) -> None:
        for d in dests[k]:
            if d not in tainted:
                tainted.add(d)
                work.extend(uses.get(d, ()))

    while work:
        k = work.pop()
        ins = code[k]
        if ins.op.startswith("st."):
            space = ins.op.split(".")[1]
            if space in memory and not memory[space]:
                memory[space] = True
                for j in loads[space]:
                    mark(j)
            continue
        mark(k)
    return tainted


def shared_stores(ptx: str, kernel: str) -> dict:
    """For ``kernel``'s st.shared: ``{"stores": n, "inputs": [offsets stored from the kernel's
    inputs], "distinct": distinct input-derived values stored}``. Offsets are bytes from the
    address's base register (followed through additions of constants)."""
    body = entry_body(ptx, kernel)
    code, _ = parse(body) if body else ([], {})
    defs: dict[str, list[Ins]] = {}
    for ins in code:
        if ins.op.split(".")[0] in ("st", "bra", "ret", "exit", "bar", "call") or not ins.args:
            continue
        for d in operands(ins.args[0].split("|")[0]):
            defs.setdefault(d, []).append(ins)
    tainted = _input_registers(code)
    inputs: set[int] = set()
    values: set[str] = set()
    count = 0
    for ins in code:
        if not ins.op.startswith("st.shared"):
            continue
        m = re.fullmatch(r"\[\s*([^\]+\-]+?)\s*(?:([+-])\s*(\d+))?\s*\]", ins.args[0].strip())
        if not m:
            continue
        base, off = _base_offset(defs, m.group(1).strip()) if m.group(1).strip().startswith("%") else (m.group(1), 0)
        off += int(m.group(3) or 0) * (-1 if m.group(2) == "-" else 1)
        size = _ELEM_BYTES.get(type_bits(ins.op), 4)
        for k, v in enumerate(operands(ins.args[1])):
            count += 1
            parts = _fields(defs, v.strip(), size)
            for j, part in enumerate(parts):
                if part.startswith("%") and part in tainted:
                    inputs.add(off + k * size + j * (size // len(parts)))
                    values.add(_origin(defs, part))
    return {"stores": count, "inputs": sorted(inputs), "distinct": len(values)}


def _fields(defs: dict, value: str, size: int) -> list[str]:
    """The values one stored element holds: itself, or the two 4-byte halves of a packed pair
    (``mov.b64 %rd, {%r1, %r2}`` then an 8-byte store)."""
    ds = defs.get(value, []) if value.startswith("%") else []
    if size == 8 and len(ds) == 1 and ds[0].op.split(".")[0] == "mov" and ds[0].args[1].strip().startswith("{"):
        return [x.strip() for x in operands(ds[0].args[1])]
    return [value]


def _origin(defs: dict, reg: str, seen=()) -> str:
    """A register through plain copies (mov of one register) to where its value is made."""
    ds = defs.get(reg, [])
    if len(ds) == 1 and ds[0].op.split(".")[0] == "mov" and len(ds[0].args) == 2 \
            and re.fullmatch(r"%[\w$]+", ds[0].args[1].strip()) and reg not in seen:
        return _origin(defs, ds[0].args[1].strip(), seen + (reg,))
    return reg


def _base_offset(defs: dict, reg: str, seen=()) -> tuple[str, int]:
    """An address register as (base register, byte offset), through additions of constants and copies."""
    ds = defs.get(reg, [])
    if len(ds) == 1 and reg not in seen:
        ins = ds[0]
        b = ins.op.split(".")[0]
        if b in ("add", "sub") and len(ins.args) == 3 and immediate(ins.args[2]) is not None:
            r, off = _base_offset(defs, ins.args[1].strip(), seen + (reg,))
            k = immediate(ins.args[2])
            return r, off + (k if b == "add" else -k)
        if b == "mov" and len(ins.args) == 2 and ins.args[1].strip().startswith("%"):
            return _base_offset(defs, ins.args[1].strip(), seen + (reg,))
    return reg, 0
