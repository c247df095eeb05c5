"""Tables of benchmark results, written once and shown two ways: a bench module gives each of its
tables as columns and text cells (:class:`Table`); the command line prints them as rich tables
(rtlab.cli.common.print_tables) and ``--md`` appends them as markdown (:func:`report_markdown`), with
the command, date, host and devices above them: the blocks of docs/results/ (scripts/results_page.py
makes docs/results.md of them).
"""
from __future__ import annotations

import datetime
import math
import platform
import re
from dataclasses import dataclass, field

# A cell that reads as a number ("1,234.5", "12 %", "1.2×", "1024²", "-") is right-aligned in markdown
_NUMERIC = re.compile(r"^[-+]?[\d,.]+(?:e[-+]?\d+)?\s*(?:%|×|²|x|ms|s|B)?$|^-$")


@dataclass
class Table:
    columns: tuple[str, ...]
    rows: list[tuple[str, ...]] = field(default_factory=list)
    title: str = ""
    note: str = ""               # what the table shows, printed above it

    def markdown(self) -> str:
        align = ["---:" if self.rows and all(_NUMERIC.match(r[i].strip()) for r in self.rows) else "---"
                 for i in range(len(self.columns))]
        out = [self.note, ""] if self.note else []
        out += ["| " + " | ".join(self.columns) + " |", "|" + "|".join(align) + "|"]
        out += ["| " + " | ".join(cells) + " |" for cells in self.rows]
        return "\n".join(out) + "\n"


def fmt(value, spec: str, missing: str = "-") -> str:
    """``value`` formatted by ``spec``; ``missing`` for None and NaN (a cell nothing measured), "inf"
    for an infinity, text as it is (a value read back from JSON)."""
    if isinstance(value, str):
        return value
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return missing
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return format(value, spec)


def report_markdown(title: str, command: str, devices, tables: list[Table], intro: str = "") -> str:
    """A markdown block for a fragment of docs/results/: title, the command, date, host and
    devices, then the tables (each with its note above it)."""
    out = [f"### {title}", "", f"Command: `{command}`  ",
           f"Date: {datetime.date.today().isoformat()}; host: {platform.node()}; devices: {'; '.join(sorted(set(devices)))}",
           ""]
    if intro:
        out += [intro, ""]
    for table in tables:
        out += [table.markdown()]
    return "\n".join(out).rstrip("\n") + "\n"
