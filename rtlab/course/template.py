"""Lab templates: the reference kernels with the lab's marked regions (and later labs') stubbed.

``rtlab lab template STEP --out DIR`` writes ``DIR/<path>`` for every file a submission provides
(grading.toml ``[[files]]``). Templates are generated on demand from the kernels (one source of
truth), never committed.
"""
from __future__ import annotations

from pathlib import Path

from .config import LabConfig, load_config
from .kernel_sources import template_text


def template_files(config: LabConfig) -> dict[str, str]:
    """relpath -> template text for every file of the lab."""
    return {lf.path: template_text(config, lf.path) for lf in config.files}


def write_template(step: str, out: Path) -> list[Path]:
    config = load_config(step)
    out = Path(out)
    written = []
    for rel, text in template_files(config).items():
        p = out / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(text.encode("latin-1"))
        written.append(p)
    return written
