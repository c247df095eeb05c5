"""C source as the preprocessor's lexer sees it: spliced lines, tokens (with the spellings that clang
and nvcc read differently marked "ambiguous") and directives. rtlab.course.cpp evaluates directives;
rtlab.course.submission applies the rule on submitted files to these tokens."""
from __future__ import annotations

import bisect
import re
import time
from dataclasses import dataclass

TRIGRAPH_RE = re.compile(r"\?\?[=/'()!<>\-]")
IDENT_RE = re.compile(r"[A-Za-z_$][A-Za-z0-9_$]*")
BOM = "\xef\xbb\xbf"           # UTF-8's byte-order mark, as Latin-1 text: clang skips it at a file's start
NON_ASCII_RE = re.compile(r"[\x80-\xff]+")
DEADLINE_CHECK = 1 << 12        # tokens between two looks at the clock
NUMBER_RE = re.compile(r"\.?[0-9](?:[eEpP][+-]|[A-Za-z0-9_.])*")
PUNCTUATORS = sorted(["%:%:", "...", "<<=", ">>=", "->", "++", "--", "<<", ">>", "<=", ">=", "==", "!=", "&&", "||",
                      "*=", "/=", "%=", "+=", "-=", "&=", "^=", "|=", "##", "<:", ":>", "<%", "%>", "%:", "::"],
                     key=len, reverse=True)
PUNCT_RE = re.compile("|".join(re.escape(p) for p in PUNCTUATORS))     # longest first
LITERAL_PREFIXES = ("L", "u", "U", "u8")
RAW_PREFIXES = ("R", "LR", "uR", "UR", "u8R")
DIGRAPHS = {"%:": "#", "%:%:": "##", "<:": "[", ":>": "]", "<%": "{", "%>": "}"}


@dataclass
class Token:
    kind: str        # ident, number, string, char, punct, other, ambiguous, nonascii
    text: str        # as written (digraphs spelled out: see .value)
    line: int        # physical line (1-based) where the token starts
    bol: bool        # first token of its logical line (a directive starts with such a '#')
    why: str = ""    # for kind "ambiguous": what it is
    pos: int = -1    # offset in the spliced text (adjacency: a function-like macro's '(')

    @property
    def value(self) -> str:
        """The token's meaning: digraphs as the punctuator they stand for."""
        return DIGRAPHS.get(self.text, self.text) if self.kind == "punct" else self.text


def splice_lines(text: str) -> tuple[str, list[int]]:
    """Translation phases 1-2 without trigraphs: newlines as \\n (\\r\\n and a lone \\r too),
    backslash-newline splices removed (also with spaces between, which clang and gcc accept with a
    warning). Returns the text and each character's physical line."""
    out: list[str] = []
    lines: list[int] = []
    i, n, line = 0, len(text), 1
    while i < n:
        c = text[i]
        if c == "\\":
            j = i + 1
            while j < n and text[j] in " \t\f\v":
                j += 1
            if j < n and text[j] in "\r\n":
                j += 2 if text.startswith("\r\n", j) else 1
                line += 1
                i = j
                continue
        if c == "\r":
            i += 2 if text.startswith("\r\n", i) else 1
            c = "\n"
        else:
            i += 1
        out.append(c)
        lines.append(line)
        if c == "\n":
            line += 1
    return "".join(out), lines


def _literal_end(s: str, i: int, quote: str) -> int:
    """Index just past the literal opening at s[i] (the quote), or -1 if the line ends first."""
    j = i + 1
    n = len(s)
    while j < n:
        c = s[j]
        if c == "\\" and j + 1 < n and s[j + 1] != "\n":
            j += 2
            continue
        if c == quote:
            return j + 1
        if c == "\n":
            return -1
        j += 1
    return -1


# Why long: one hand-written scanner loop, a case per token kind: linear time is its point, and the cases read
# as one table.
def tokenize(text: str, deadline_at: float | None = None) -> list[Token]:
    """Preprocessing tokens of a source (comments dropped). ``text`` is the file decoded as Latin-1
    (one character a byte, so any file decodes). A byte-order mark that opens the file is skipped,
    as clang skips it; any other byte outside ASCII outside comments and string literals is a token
    of kind "nonascii". Linear in the file's size; past ``deadline_at`` (time.monotonic()) it raises
    TimeoutError."""
    if text.startswith(BOM):
        text = text[len(BOM):]
    toks: list[Token] = []
    starts = [m.start() for m in re.finditer("\n", text)]
    for m in TRIGRAPH_RE.finditer(text):
        toks.append(Token("ambiguous", m.group(), bisect.bisect_right(starts, m.start() - 1) + 1, False,
                          f"the trigraph {m.group()} (compilers disagree on trigraphs: C++17 ignores them)"))
    s, lines = splice_lines(text)
    i, n, bol = 0, len(s), True

    def add(kind, tok_text, at, why=""):
        nonlocal bol
        toks.append(Token(kind, tok_text, lines[at], bol, why, at))
        bol = False

    steps = 0
    while i < n:
        steps += 1
        if deadline_at is not None and steps % DEADLINE_CHECK == 0 and time.monotonic() > deadline_at:
            raise TimeoutError("the grader's time for reading the submission ran out")
        c = s[i]
        if c == "\n":
            bol = True
            i += 1
            continue
        if c in " \t\f\v":
            i += 1
            continue
        if s.startswith("//", i):
            j = s.find("\n", i)
            i = n if j < 0 else j
            continue
        if s.startswith("/*", i):
            j = s.find("*/", i + 2)
            if j < 0:
                add("ambiguous", "/*", i, "a comment that is never closed")
                break
            i = j + 2
            continue
        m = NON_ASCII_RE.match(s, i)
        if m:
            add("nonascii", m.group(), i, "a byte outside ASCII outside a comment or a string")
            i = m.end()
            continue
        m = IDENT_RE.match(s, i)
        if m:
            word, end = m.group(), m.end()
            if end < n and s[end] == '"' and word in RAW_PREFIXES:
                add("ambiguous", word + '"', i, "a raw string literal (C++ only: C reads it otherwise)")
                i = end + 1
                continue
            if end < n and s[end] in "\"'" and word in LITERAL_PREFIXES:
                close = _literal_end(s, end, s[end])
                if close < 0:
                    add("ambiguous", s[i:end + 1], i, f"a {s[end]} that is not closed on its line")
                    i = end + 1
                    continue
                add("string" if s[end] == '"' else "char", s[i:close], i)
                i = close
                continue
            add("ident", word, i)
            i = end
            continue
        if c.isdigit() or (c == "." and i + 1 < n and s[i + 1].isdigit()):
            m = NUMBER_RE.match(s, i)
            end = m.end()
            if end < n and s[end] == "'" and end + 1 < n and (s[end + 1].isalnum() or s[end + 1] == "_"):
                add("ambiguous", s[i:end + 2], i, "a digit separator ' (C++ only: C reads a character literal)")
                i = end + 2
                continue
            add("number", s[i:end], i)
            i = end
            continue
        if c in "\"'":
            close = _literal_end(s, i, c)
            if close < 0:
                add("ambiguous", c, i, f"a {c} that is not closed on its line")
                i += 1
                continue
            add("string" if c == '"' else "char", s[i:close], i)
            i = close
            continue
        m = PUNCT_RE.match(s, i)
        if m:
            add("punct", m.group(), i)
            i = m.end()
        else:
            add("punct" if c in "#[](){}.&*+-~!/%<>^|?:;=,\\" else "other", c, i)
            i += 1
    toks.sort(key=lambda t: t.line)   # trigraph reports in line order (the sort is stable)
    return toks


@dataclass
class Directive:
    name: str              # "include", "define", ...; "" for a null directive; "#<number>" for a line marker
    line: int
    args: list[Token]      # the tokens after the name, to the end of the logical line
    hash: Token = None     # the '#' (or '%:')


def directive_at(toks: list[Token], i: int) -> tuple[list[Token], int] | None:
    """At a '#' that begins a line: (the directive's tokens after it, the index past its line); None
    for any other token."""
    t = toks[i]
    if not (t.bol and t.kind == "punct" and t.value == "#"):
        return None
    j = i + 1
    while j < len(toks) and not toks[j].bol:
        j += 1
    return toks[i + 1:j], j


def split_directives(toks: list[Token]) -> tuple[list[Directive], list[Token]]:
    """(directives, the other tokens) of a token list, in order within each."""
    directives, code = [], []
    i, n = 0, len(toks)
    while i < n:
        t = toks[i]
        found = directive_at(toks, i)
        if found:
            rest, j = found
            if not rest:
                directives.append(Directive("", t.line, [], t))
            elif rest[0].kind == "ident":
                directives.append(Directive(rest[0].text, t.line, rest[1:], t))
            else:
                directives.append(Directive("#" + rest[0].text, t.line, rest[1:], t))
            i = j
            continue
        code.append(t)
        i += 1
    return directives, code
