"""C constant expressions, evaluated as C does: the one evaluator for the kernels' ``#define``
constants the host reads (rtlab.kernel_constants) and the lab preprocessor's ``#if`` conditions
(rtlab.course.cpp).

    evaluate(tokens("(16.0f * 5.9604645e-8f)"))        # 9.5367432e-07
    evaluate(tokens("RT_LANES * 2"), {"RT_LANES": 8})   # 16
    evaluate(tokens("defined_later > 1"), unknown=0)    # 0: #if reads an unknown name as 0

Integers keep C's semantics (division and remainder truncate toward zero, comparisons and logic give
0 or 1); a floating literal (a point, an exponent) makes its operation floating. Imports nothing from
rtlab, so every layer may use it.
"""
from __future__ import annotations

import re

_TOKEN_RE = re.compile(r"""
    (?:\d+\.\d*|\.\d+)(?:[eE][+-]?\d+)?[fFlL]? | \d+[eE][+-]?\d+[fFlL]?     # floating literals
  | 0[xX][0-9a-fA-F]+[uUlL]* | 0[bB][01]+[uUlL]* | \d+[uUlL]*               # integer literals
  | '(?:\\.|[^'\\])'                                                        # character literals
  | [A-Za-z_]\w*
  | <<|>>|<=|>=|==|!=|&&|\|\| | \S""", re.X)
BINARY = [("||",), ("&&",), ("|",), ("^",), ("&",), ("==", "!="), ("<", "<=", ">", ">="), ("<<", ">>"),
          ("+", "-"), ("*", "/", "%")]


class ExprError(ValueError):
    """Not a constant expression C could evaluate (a name without a value, a cast, a call...)."""


def tokens(text: str) -> list[str]:
    """The tokens of an expression's text."""
    return _TOKEN_RE.findall(text)


def literal(text: str) -> int | float:
    """A C number or character literal's value."""
    if text.startswith("'"):
        body = text[1:-1]
        return ord(body[-1]) if body else 0
    t = text.rstrip("uUlL")
    low = t.lower()
    try:
        if low.startswith("0x"):
            return int(t, 16)
        if low.startswith("0b"):
            return int(t, 2)
        if "." in t or ("e" in low and not low.startswith("0x")):
            return float(t.rstrip("fF"))
        if len(t) > 1 and t.startswith("0") and t.isdigit():
            return int(t, 8)
        return int(t)
    except ValueError:
        raise ExprError(f"not a number: {text}") from None


def _apply(op: str, a, b):
    if op == "||":
        return int(bool(a) or bool(b))
    if op == "&&":
        return int(bool(a) and bool(b))
    if op in ("/", "%"):
        if b == 0:
            raise ExprError("division by zero")
        if isinstance(a, float) or isinstance(b, float):
            if op == "%":
                raise ExprError("% of a floating value")
            return a / b
        q = abs(a) // abs(b) * (1 if (a >= 0) == (b >= 0) else -1)      # C truncates toward zero
        return q if op == "/" else a - q * b
    if op in ("|", "^", "&", "<<", ">>") and (isinstance(a, float) or isinstance(b, float)):
        raise ExprError(f"{op} of a floating value")
    return {"|": lambda: a | b, "^": lambda: a ^ b, "&": lambda: a & b, "==": lambda: int(a == b),
            "!=": lambda: int(a != b), "<": lambda: int(a < b), "<=": lambda: int(a <= b),
            ">": lambda: int(a > b), ">=": lambda: int(a >= b), "<<": lambda: a << b, ">>": lambda: a >> b,
            "+": lambda: a + b, "-": lambda: a - b, "*": lambda: a * b}[op]()


# Why long: a recursive-descent parser as nested functions, one per C precedence level, sharing the token
# position.
def evaluate(toks: list[str], names: dict | None = None, unknown: int | None = None) -> int | float:
    """The value of the expression ``toks``. A name takes its value from ``names``; any other name is
    ``unknown`` (C's #if reads it as 0), or an ExprError when ``unknown`` is None."""
    names = names or {}
    pos = 0

    def peek():
        return toks[pos] if pos < len(toks) else None

    def take():
        nonlocal pos
        if pos >= len(toks):
            raise ExprError("expression ends early")
        pos += 1
        return toks[pos - 1]

    def primary():
        t = take()
        if t == "(":
            v = ternary()
            if take() != ")":
                raise ExprError("missing )")
            return v
        if t in ("!", "~", "-", "+"):
            v = primary()
            if t == "~" and isinstance(v, float):
                raise ExprError("~ of a floating value")
            return {"!": lambda: int(not v), "~": lambda: ~v, "-": lambda: -v, "+": lambda: v}[t]()
        if t[0].isdigit() or t[0] == "." or t.startswith("'"):
            return literal(t)
        if re.fullmatch(r"[A-Za-z_]\w*", t):
            if t in names:
                return names[t]
            if unknown is None:
                raise ExprError(f"{t} has no value")
            return unknown
        raise ExprError(f"unexpected {t}")

    def binary(level):
        if level == len(BINARY):
            return primary()
        v = binary(level + 1)
        while peek() in BINARY[level]:
            op = take()
            v = _apply(op, v, binary(level + 1))
        return v

    def ternary():
        c = binary(0)
        if peek() == "?":
            take()
            a = ternary()
            if take() != ":":
                raise ExprError("missing : in ?:")
            b = ternary()
            return a if c else b
        return c

    v = ternary()
    if pos != len(toks):
        raise ExprError(f"unexpected {toks[pos]}")
    return v
