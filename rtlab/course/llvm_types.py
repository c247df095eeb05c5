"""LLVM IR types as rtlab.course.structure reads them: named struct types, a parser of type text, and
sizes as the x86-64 / SPIR data layouts give them (natural alignment; a three-lane vector takes four
lanes' room), and the bytes of a local's storage a loop can index (arrays, wide vectors)."""
from __future__ import annotations

import re
from dataclasses import dataclass

TYPE_TOKEN_RE = re.compile(r'<\{|\}>|[{}\[\]<>,()]|%"[^"]*"|%[\w.$-]+|[\w.$]+')
_STRUCT_DEF_RE = re.compile(r'^(%"[^"]*"|%[\w.$-]+) = type (.*)$', re.M)


@dataclass(frozen=True)
class Ty:
    kind: str                    # int, float, ptr, vector, array, struct, opaque
    size: int = 0                # bytes of the scalar (int, float, ptr)
    count: int = 0               # vector lanes, array elements
    elem: "Ty | None" = None
    members: tuple = ()
    packed: bool = False
    name: str = ""


class TypeTable:
    """The module's named struct types and a parser of type text."""

    def __init__(self, ir: str):
        self.text = {m.group(1): m.group(2).strip() for m in _STRUCT_DEF_RE.finditer(ir)}
        self.parsed: dict[str, Ty] = {}

    def named(self, name: str) -> Ty:
        if name not in self.parsed:
            self.parsed[name] = Ty("opaque", name=name)          # a recursive reference stays opaque
            body = self.text.get(name, "opaque")
            if body.startswith("opaque"):
                ty = Ty("opaque", name=name)
            else:
                ty, _ = self.parse_tokens(TYPE_TOKEN_RE.findall(body), 0)
                ty = Ty(ty.kind, ty.size, ty.count, ty.elem, ty.members, ty.packed, name)
            self.parsed[name] = ty
        return self.parsed[name]

    def parse(self, text: str) -> Ty:
        """The type at the start of ``text``."""
        return self.parse_tokens(TYPE_TOKEN_RE.findall(text), 0)[0]

    def parse_tokens(self, tok: list[str], i: int) -> tuple[Ty, int]:
        t = tok[i]
        if t in ("{", "<{"):
            members, i = [], i + 1
            close = "}" if t == "{" else "}>"
            while tok[i] != close:
                m, i = self.parse_tokens(tok, i)
                members.append(m)
                if tok[i] == ",":
                    i += 1
            return Ty("struct", members=tuple(members), packed=t == "<{"), i + 1
        if t in ("[", "<"):
            n = int(tok[i + 1])
            assert tok[i + 2] == "x", tok[i:i + 4]
            elem, j = self.parse_tokens(tok, i + 3)
            return Ty("array" if t == "[" else "vector", count=n, elem=elem), j + 1
        if t.startswith("%"):
            return self.named(t), i + 1
        if t == "ptr":
            if i + 1 < len(tok) and tok[i + 1] == "addrspace":
                return Ty("ptr", size=8), i + 5
            return Ty("ptr", size=8), i + 1
        m = re.fullmatch(r"i(\d+)", t)
        if m:
            return Ty("int", size=max(1, (int(m.group(1)) + 7) // 8)), i + 1
        sizes = {"half": 2, "bfloat": 2, "float": 4, "double": 8, "x86_fp80": 16, "fp128": 16}
        if t in sizes:
            return Ty("float", size=sizes[t]), i + 1
        return Ty("opaque", name=t), i + 1


def _pow2(n: int) -> int:
    p = 1
    while p < n:
        p *= 2
    return p


def align_of(t: Ty) -> int:
    if t.kind in ("int", "float", "ptr"):
        return _pow2(t.size)
    if t.kind == "vector":
        return _pow2(t.count * size_of(t.elem))
    if t.kind == "array":
        return align_of(t.elem)
    if t.kind == "struct":
        return 1 if t.packed else max([align_of(m) for m in t.members] or [1])
    return 1


def size_of(t: Ty) -> int:
    """Allocation size in bytes."""
    if t.kind in ("int", "float", "ptr"):
        return _pow2(t.size)
    if t.kind == "vector":
        return _pow2(t.count * size_of(t.elem))
    if t.kind == "array":
        return t.count * size_of(t.elem)
    if t.kind == "struct":
        off = 0
        for m in t.members:
            a = 1 if t.packed else align_of(m)
            off = (off + a - 1) // a * a + size_of(m)
        a = align_of(t)
        return (off + a - 1) // a * a
    return 0


def _is_padding(t: Ty) -> bool:
    """clang's explicit padding in a struct: a short array of i8 (``[8 x i8]`` after Ray's floats)."""
    return t.kind == "array" and t.elem.kind == "int" and t.elem.size == 1 and t.count < 16


def array_bytes(t: Ty, top: bool = True) -> int:
    """Bytes of a local's storage a loop can index: arrays at any depth, vectors of more than 4 lanes."""
    if t.kind == "array":
        return 0 if (not top and _is_padding(t)) else size_of(t)
    if t.kind == "vector":
        return size_of(t) if t.count > 4 else 0
    if t.kind == "struct":
        return sum(array_bytes(m, top=False) for m in t.members)
    return 0


def type_text(t: Ty) -> str:
    if t.name:
        return t.name.lstrip("%").strip('"').removeprefix("struct.").removeprefix("union.")
    if t.kind == "array":
        return f"{t.count} x {type_text(t.elem)}"
    if t.kind == "vector":
        return f"<{t.count} x {type_text(t.elem)}>"
    if t.kind == "int":
        return f"i{8 * t.size}" if t.size > 1 else "i8"
    if t.kind == "float":
        return {2: "half", 4: "float", 8: "double"}.get(t.size, "float")
    if t.kind == "ptr":
        return "ptr"
    if t.kind == "struct":
        return "{" + ", ".join(type_text(m) for m in t.members) + "}"
    return t.name or t.kind


def describe(t: Ty) -> str:
    """A local's indexable storage as a student reads it: ``[20 x KdStackEntry]``, a struct by its
    largest array (``anon holding [20 x KdStackEntry]``), a wide vector ``<16 x i32>``."""
    if t.kind == "array":
        return f"[{t.count} x {type_text(t.elem)}]"
    if t.kind == "struct":
        inner = max((m for m in t.members if array_bytes(m, top=False)), key=lambda m: array_bytes(m, top=False),
                    default=None)
        if inner is not None:
            name = type_text(t) if t.name else "anon"
            return f"{'a struct' if name.split('.')[0] == 'anon' else name} holding {describe(inner)}"
    return type_text(t)
