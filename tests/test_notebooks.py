"""Every course notebook (notebooks/*.py, jupytext percent format) runs top to bottom: jupytext ->
nbformat -> nbclient, in a fresh kernel, on PoCL at small sizes. The notebooks assert their own
results (no mismatching pixels, the ray tree agrees with the render), so running them checks them.
The .ipynb is generated here and never committed."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

NOTEBOOK_DIR = Path(__file__).resolve().parent.parent / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("[0-9][0-9]_*.py"))
TIMEOUT_S = 600          # per cell


def test_one_notebook_per_lab_step():
    from rtlab.course import lab_names
    names = {p.stem for p in NOTEBOOKS}
    assert names, "no notebooks"
    assert set(lab_names()) <= names, f"lab steps without a notebook: {sorted(set(lab_names()) - names)}"


def test_every_notebook_assert_says_what_failed():
    """A student's notebook that stops on a wrong result says which (a bare `AssertionError:` says
    nothing): every assert carries a message."""
    import ast
    bare = [f"{p.name}:{node.lineno}" for p in NOTEBOOKS for node in ast.walk(ast.parse(p.read_text(encoding="utf-8")))
            if isinstance(node, ast.Assert) and node.msg is None]
    assert not bare, f"asserts without a message: {', '.join(bare)}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path):
    jupytext = pytest.importorskip("jupytext")
    nbclient = pytest.importorskip("nbclient")
    nb = jupytext.read(path)
    assert nb.cells and nb.cells[0].cell_type == "markdown", "a notebook opens with its lab and paper section"
    env_size = os.environ.get("RTLAB_NOTEBOOK_SIZE")
    os.environ.setdefault("RTLAB_NOTEBOOK_SIZE", "64")
    try:
        client = nbclient.NotebookClient(nb, timeout=TIMEOUT_S, kernel_name="python3",
                                         resources={"metadata": {"path": str(tmp_path)}})
        client.execute()
    finally:
        if env_size is None:
            os.environ.pop("RTLAB_NOTEBOOK_SIZE", None)
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors
    images = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if "image/png" in o.get("data", {})]
    assert images, "the notebook shows no figure"
