"""Lab templates: the reference kernels with the lab's marked regions stubbed.

``rtlab lab template STEP`` writes ``labs/STEP/template/<path>`` for every file a submission
provides (grading.toml ``[[files]]``). Templates are generated, never edited by hand; a test checks
that the committed ones are current.
"""
from __future__ import annotations

from pathlib import Path

from .config import LabConfig, load_config
from .grader import template_text

TEMPLATE_HEADER_NOTE = "template"


def template_files(config: LabConfig) -> dict[str, str]:
    """relpath -> template text for every file of the lab."""
    return {lf.path: template_text(config, lf.path, lf.functions) for lf in config.files}


def write_template(step: str, out: Path | None = None) -> list[Path]:
    config = load_config(step)
    out = Path(out) if out is not None else config.folder / "template"
    written = []
    for rel, text in template_files(config).items():
        p = out / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
        written.append(p)
    return written


def stale_template_files(step: str) -> list[str]:
    """Files of labs/STEP/template that differ from what the generator writes now."""
    config = load_config(step)
    stale = []
    for rel, text in template_files(config).items():
        p = config.folder / "template" / rel
        if not p.is_file() or p.read_text() != text:
            stale.append(rel)
    return stale
