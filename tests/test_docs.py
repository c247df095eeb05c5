"""Documentation of the present: docs/results.md is what scripts/results_page.py makes of the fragments
in docs/results/, every fragment names its commands, dates and devices beside an error, and neither
the docs nor the code, its comments or the command line's --help carry issue numbers or point at the
old measurement log (history is CHANGELOG.md's)."""
from __future__ import annotations

import ast
import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# An issue number however it is written: the word (plural, capitalised, inside a file name) then a
# number, with spaces, "#", a hyphen or an underscore between, or a comment's line break
# (test_the_pattern_catches_what_it_should lists the forms).
ISSUE_NUMBER = re.compile(r"(?i)(?<![a-z])issues?(?:[\s#*/_-]|<br>)*\d")
OLD_LOG = "docs/" + "benchmarks.md"      # the measurement log, now at the end of CHANGELOG.md
TEXT_SUFFIXES = {".py", ".sh", ".h", ".cu", ".cl", ".md", ".txt", ".toml", ".yaml", ".yml", ".cfg",
                 ".ini", ".json", ".csv", ".ipynb"}


def _results_page():
    spec = importlib.util.spec_from_file_location("results_page", ROOT / "scripts" / "results_page.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _text_files(folder: Path):
    for path in sorted(folder.rglob("*")):
        if path.is_file() and path.suffix in TEXT_SUFFIXES and "__pycache__" not in path.parts:
            yield path


def _offences(paths) -> list[str]:
    """'file:line: the line' for every issue number and every pointer to the old log."""
    found = []
    for path in paths:
        text = path.read_text(errors="replace")
        lines = text.splitlines()
        starts = [m.start() for m in ISSUE_NUMBER.finditer(text)]
        starts += [m.start() for m in re.finditer(re.escape(OLD_LOG), text)]
        for n in sorted({text.count("\n", 0, s) for s in starts}):
            found.append(f"{path.relative_to(ROOT)}:{n + 1}: {lines[n].strip()[:120]}")
    if any(OLD_LOG in f for f in found):
        found.append(f"({OLD_LOG} is gone: current figures are in docs/results.md, history in CHANGELOG.md)")
    return found


# ---- docs/results.md and its fragments --------------------------------------------------------

def test_results_page_is_what_the_script_makes():
    """Nobody edits docs/results.md by hand: it is scripts/results_page.py's output, every fragment
    of docs/results/ is in the script's order, and the script's --check agrees."""
    page = _results_page()
    fragments = {p.name for p in (ROOT / "docs" / "results").glob("*.md")}
    assert fragments == set(page.TOPICS), (f"docs/results/ and results_page.TOPICS differ: "
                                           f"{sorted(fragments ^ set(page.TOPICS))}")
    made = page.build_page()
    assert (ROOT / "docs" / "results.md").read_text() == made, \
        "docs/results.md is not what scripts/results_page.py makes: run `python scripts/results_page.py`"
    assert page.main(["--check"]) == 0


def _blocks(text: str) -> list[str]:
    """A fragment's blocks: from each '### ' heading to the next."""
    return ["### " + b for b in re.split(r"^### ", text, flags=re.M)[1:]]


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "docs" / "results").glob("*.md")))
def test_every_block_names_its_command_date_and_devices(name):
    """Each fragment is one topic ('## ' title) of blocks as the benches' --md writes them: every
    block names the command that made it, the date (YYYY-MM-DD) and the devices on its Date line
    (`rtlab bench cpu` names rtlab's OpenCL device and Embree there), and the fragment gives the
    error beside the figures (an error column or an Error: line)."""
    text = (ROOT / "docs" / "results" / name).read_text()
    assert text.startswith("## "), f"{name}: a fragment opens with its topic's '## ' title"
    blocks = _blocks(text)
    assert blocks, f"{name}: no '### ' block"
    for block in blocks:
        title = block.splitlines()[0]
        assert re.search(r"^Command: .*`[^`]+`", block, re.M), f"{name}, {title}: no 'Command: `...`' line"
        date = re.search(r"^Date: (\d{4})-(\d{2})-(\d{2})\b(.*)$", block, re.M)
        assert date, f"{name}, {title}: no 'Date: YYYY-MM-DD' line"
        assert re.search(r"\b(devices|rtlab): ", date.group(4)), f"{name}, {title}: its Date line names no device"
    assert re.search(r"(?i)\berror\b|\bmism", text), f"{name}: no error beside the figures"


def test_docs_and_readme_hold_no_issue_numbers():
    """docs/ describes the present: no issue numbers, no pointer to the old log (CHANGELOG.md, at the
    repository's root, is where the history and its issue numbers live)."""
    found = _offences([*_text_files(ROOT / "docs"), ROOT / "README.md"])
    assert not found, "\n".join(found)


# ---- code, comments and --help ------------------------------------------------------------------

AREAS = ["rtlab", "kernels", "experiments", "scripts", "notebooks", "labs", "tests", "Makefile", "pyproject.toml"]


def _area_files(area: str):
    path = ROOT / area
    return [path] if path.is_file() else list(_text_files(path))


@pytest.mark.parametrize("area", AREAS)
def test_code_and_comments_hold_no_issue_numbers(area):
    """Code and comments say what the code does and why in the present tense: an issue number (or a
    pointer to the old measurement log) dates them; figures live in docs/results.md, history in
    CHANGELOG.md."""
    found = _offences(_area_files(area))
    assert not found, "\n".join(found)


def test_help_texts_hold_no_issue_numbers():
    """Every command's and option's --help, as the command line shows it."""
    import typer.main

    from rtlab.cli import app

    found = []

    def walk(cmd, path):
        texts = [cmd.help or "", cmd.short_help or "", cmd.epilog or ""]
        texts += [getattr(p, "help", None) or "" for p in cmd.params]
        for text in texts:
            if ISSUE_NUMBER.search(text) or OLD_LOG in text:
                found.append(f"rtlab {' '.join(path)}: {text[:80]!r}")
        for name, sub in sorted(getattr(cmd, "commands", {}).items()):
            walk(sub, [*path, name])

    walk(typer.main.get_command(app), [])
    assert not found, "\n".join(found)


def test_the_pattern_catches_what_it_should():
    n = 13      # the examples are built, so that this file holds none itself
    for text in (f"since issue {n} the box test", f"Issue {n}'s target", f"issues {n} and {n + 1}",
                 f"issue-{n}", f"gpu_issue{n}.sh", f"(rtlab before issue\n    {n})", f"(issue\n# {n})",
                 f"ISSUE #{n}"):
        assert ISSUE_NUMBER.search(text), text
    for text in ("issue-bound", "issue slots busy", "Warp Cycles Per Issued", "the issue's goal",
                 f"tissue {n}", f"{n} issues"):
        assert not ISSUE_NUMBER.search(text), text


# ---- the labs' READMEs, as students read them in their release -----------------------------------

def test_lab_readmes_send_students_only_to_what_the_release_ships():
    """A lab README's `python path/to/script.py` names a file the student release holds
    (rtlab.course.release.RELEASE_ITEMS, labs/, kernels/; experiments/ stays in the course's repository),
    and its Python blocks import names that exist."""
    import importlib

    from rtlab.course.release import RELEASE_ITEMS
    shipped = {*RELEASE_ITEMS, "labs", "kernels"}
    found = []
    for readme in sorted((ROOT / "labs").glob("*/README.md")):
        text = readme.read_text(encoding="utf-8")
        for script in re.findall(r"\bpython3? (\S+\.py)\b", text):
            if script.split("/")[0] not in shipped or not (ROOT / script).is_file():
                found.append(f"{readme.parent.name}: python {script} (not in the student release)")
        for block in re.findall(r"```python\n(.*?)```", text, re.S):
            for node in ast.walk(ast.parse(block)):
                if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("rtlab"):
                    module = importlib.import_module(node.module)
                    found += [f"{readme.parent.name}: from {node.module} import {a.name} (no such name)"
                              for a in node.names if not hasattr(module, a.name)]
    assert not found, "\n".join(found)
