"""The student release: ``rtlab lab release OUT``.

What students get, in the project's own layout so that ``pip install -e OUT`` (or the wheel) works
as it does from the course's repository:

* ``pyproject.toml``, ``README.md`` (a preface for students, then the project's), ``Makefile`` and
  ``scripts/`` (``make render``), ``rtlab/`` (the package), ``notebooks/``;
* ``kernels/`` with every solution region of every step stubbed (rtlab.course.kernel_sources): the students'
  working tree;
* ``labs/<step>/README.md`` and ``grading.toml`` with the visible tests only: no test hidden until
  the due date (and none of its parameters) and no speed test (those time against the reference,
  which only the course's grader has).

Instructors keep the repository (the reference) and make the Gradescope bundle from it. Note that
``pip install .`` (or a wheel) of the course's repository ships every solution in
``rtlab/_data/kernels``: a notebook server for students installs the release or its wheel
(``rtlab lab release OUT --wheel``), never the repository.
"""
from __future__ import annotations

import re
import shutil
import tomllib
from pathlib import Path

from ..errors import LabError
from .config import lab_names, load_config
from .kernel_sources import copy_stubbed, reference_kernels

RELEASE_ITEMS = ("pyproject.toml", "Makefile", "scripts", "rtlab", "notebooks")
IGNORE = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info", ".ipynb_checkpoints", "*.ipynb")

STUDENT_PREFACE = """\
# rtlab — student release

This is the course's release of rtlab for students: the whole tool, every lab step's instructions
(`labs/<step>/README.md`) and the kernels with every function you write replaced by a stub
(`/* TODO (lab ...) */` between `BEGIN SOLUTION` and `END SOLUTION`). `kernels/` is your working
tree: fill the functions of a lab step in place (or in a copy, see below), check them with
`rtlab render ... --check`, and grade them the way the course's autograder does with
`rtlab grade STEP .`. Labs build on each other: lab 03 runs on your camera and stack traversal of
lab 00, so do them in order (the course's grader uses its own reference for earlier steps).
rtlab's default triangle test (watertight) is one of lab 02's functions: until then, render with
`--isect moller` (given).

Local grading runs the visible tests of each step (`labs/<step>/grading.toml`); the course's
autograder also runs the tests hidden until the due date and the speed tests, which time your
kernel against the reference kernel. Each lab's README lists every test.

```sh
make render                      # or: pip install -e . (needs PoCL: apt-get install pocl-opencl-icd)
rtlab lab list
rtlab render default --size 128 --isect moller --check   # names the kernel sources it compiles
rtlab grade 00_primary .                          # your kernels/ as the grader sees them
```

A kernel of yours that never ends stops `rtlab render`, a script or a notebook after 120 s with a
message (`$RTLAB_KERNEL_TIMEOUT` sets the limit), and one that crashes `rtlab render` is named in one
line; `rtlab grade` gives each test its own process and limits.

The course's README follows. Where it names `docs/`, `tests/` or `experiments/`, it means the course's
repository: those folders are not in this release.

---

"""


def _sections(text: str) -> list[tuple[str, list[str]]]:
    """A TOML file as (header, lines) sections; comment and blank lines at the end of a section go
    with the next one (they introduce it)."""
    sections: list[tuple[str, list[str]]] = [("", [])]
    for line in text.splitlines(keepends=True):
        if re.match(r"^\s*\[", line):
            lead: list[str] = []
            body = sections[-1][1]
            while body and (not body[-1].strip() or body[-1].lstrip().startswith("#")):
                lead.insert(0, body.pop())
            sections.append((line.strip(), lead + [line]))
        else:
            sections[-1][1].append(line)
    return sections


def release_grading_toml(step: str) -> str:
    """The step's grading.toml with the visible, untimed tests only, and a comment naming what the
    course's grader adds."""
    from .checks import KINDS
    config = load_config(step)
    text = config.path.read_text(encoding="utf-8")
    kept, dropped = [], []
    for header, lines in _sections(text):
        if header == "[[tests]]":
            body = "".join(lines)
            test = tomllib.loads(body)["tests"][0]
            spec = config.test(test["name"])
            if spec.visibility != "visible" or KINDS[spec.kind].timed:
                dropped.append(spec)
                continue
        kept.append("".join(lines))
    out = "".join(kept).rstrip() + "\n"
    if dropped:
        hidden = sum(t.points for t in dropped if t.visibility != "visible")
        speed = [t for t in dropped if t.visibility == "visible"]
        parts = []
        if speed:
            parts.append(", ".join(f"{t.name} ({t.points:g} points)" for t in speed) + " against the reference kernel")
        if hidden:
            n = sum(1 for t in dropped if t.visibility != "visible")
            parts.append(f"{n} test{'s' if n > 1 else ''} hidden until the due date ({hidden:g} points)")
        out += (f"\n# The course's autograder also runs: {'; '.join(parts)}. See README.md.\n")
    return out


def write_release(out, force: bool = False) -> Path:
    """Write the student release to ``out`` (a new folder, or an existing one with ``force``)."""
    from ..paths import PROJECT_DIR
    out = Path(out)
    if out.exists():
        if not force and any(out.iterdir()):
            raise LabError(f"{out} exists and is not empty: choose a new folder (or --force to replace it)")
        shutil.rmtree(out)
    out.mkdir(parents=True)
    for item in RELEASE_ITEMS:
        src = PROJECT_DIR / item
        if src.is_dir():
            shutil.copytree(src, out / item, ignore=IGNORE)
        elif src.is_file():
            shutil.copy2(src, out / item)
    readme = PROJECT_DIR / "README.md"
    (out / "README.md").write_text(STUDENT_PREFACE + (readme.read_text(encoding="utf-8") if readme.is_file() else ""),
                                   encoding="utf-8")
    copy_stubbed(reference_kernels(), out / "kernels", None)
    for step in lab_names():
        d = out / "labs" / step
        d.mkdir(parents=True)
        shutil.copy2(PROJECT_DIR / "labs" / step / "README.md", d / "README.md")
        (d / "grading.toml").write_text(release_grading_toml(step), encoding="utf-8")
    return out


def build_wheel(release: Path) -> Path:
    """The student wheel, built from a release folder (``pip wheel``; the wheel ships the release's
    stubbed kernels as rtlab/_data/kernels), checked to hold no solution. Returns its path."""
    import subprocess
    import sys
    release = Path(release).resolve()   # a bare name ("rel") is a PyPI project to pip, not this folder
    dist = release / "dist"
    dist.mkdir(exist_ok=True)
    cmd = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(dist), str(release)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise LabError(f"building the student wheel failed: {(r.stderr or r.stdout).strip()[-1500:]}")
    wheels = sorted(dist.glob("rtlab-*.whl"), key=lambda w: w.stat().st_mtime)
    if not wheels:
        raise LabError(f"pip wheel wrote no rtlab wheel into {dist}")
    leaked = wheel_solutions(wheels[-1])
    if leaked:
        raise LabError(f"the student wheel holds solutions ({', '.join(leaked[:5])}): not released")
    return wheels[-1]


def wheel_solutions(wheel: Path) -> list[str]:
    """'file: function' for every solution region of a wheel's kernels that is not a stub."""
    import zipfile
    from .regions import find_regions, stubbed_functions
    out = []
    with zipfile.ZipFile(wheel) as z:
        for name in z.namelist():
            if "/_data/kernels/" in name and name.endswith((".h", ".cl", ".cu")):
                text = z.read(name).decode("latin-1")
                stubs = set(stubbed_functions(text))
                out += [f"{name}: {r.function}" for r in find_regions(text, name) if r.function not in stubs]
    return out
