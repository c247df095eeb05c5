"""Kernel sources made from the reference: templates, the tree a submission compiles in, the release.

Every solution region (``/* BEGIN SOLUTION */`` ... ``/* END SOLUTION */``, rtlab.course.regions) belongs
to the lab step whose grading.toml lists its function. From that:

* a lab's **template** file is the reference file with the regions of this step and every later
  step stubbed (earlier steps keep the reference: a student of lab 03 needs a working lab 00);
* a submission of lab L compiles in a **student tree**: the reference kernels with every region of
  step L and later stubbed, the submission's files laid over it, each checked by the rule of
  rtlab.course.submission first. Nothing else is in it, so no include can reach a solution of this
  step or a later one;
* the **student release** stubs every region of every step.

The reference the speed tests time against and the work budgets count with is compiled by the
grader's reference worker from this installation's kernels, in a process that never loads a
submission (rtlab.course.grader).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .. import settings
from ..errors import LabError
from .config import LabConfig, lab_names, load_config
from .regions import find_regions, strip_regions
from .submission import Refusal, Refused, check_source, read_submitted, refused_placeholder, tree_rules

KERNEL_SUBDIRS = ("shared", "cuda", "opencl")
UNOWNED_STEP = "~"     # sorts after every step name: a region no lab claims is always stubbed
# The course's own regions: code no lab asks for that would show a lab's solution in another form
# (the watertight test of lab 02 in SIMD lanes, for the CPU traversals; lab 03's BVH walk as resumable
# steps, for fetching rays). Stubbed in every student tree and the release; there the library falls back
# to the scalar test and to trace_rays (rtlab.device.variants, rtlab.device.tracing).
COURSE_REGIONS = (("kernels/shared/rt_intersect_lanes.h", "watertight_axes"),
                  ("kernels/shared/rt_intersect_lanes.h", "lanes_watertight_edges"),
                  ("kernels/shared/rt_bvh_packet.h", "packet_watertight_axes"),
                  ("kernels/shared/rt_bvh.h", "bvh_trace_steps"))


def reference_kernels() -> Path:
    """The kernels this installation holds (the reference in the course's repository, stubs in a
    student release)."""
    from ..paths import REFERENCE_KERNEL_DIR
    return REFERENCE_KERNEL_DIR


def kernel_files(root: Path) -> list[str]:
    """Paths (``kernels/shared/rt_types.h``...) of the kernel sources under ``root``."""
    return [f"kernels/{sub}/{p.name}" for sub in KERNEL_SUBDIRS for p in sorted((Path(root) / sub).glob("*"))
            if p.is_file() and p.suffix in (".h", ".cl", ".cu")]


def region_owners() -> dict[tuple[str, str], str]:
    """(file path, function) -> the lab step whose grading.toml lists it."""
    owners: dict[tuple[str, str], str] = {region: UNOWNED_STEP for region in COURSE_REGIONS}
    for step in lab_names():
        for lf in load_config(step).files:
            for f in lf.functions:
                owners.setdefault((lf.path, f), step)
    return owners


def read_text(path: Path) -> str:
    """A kernel source as text, whatever its bytes (markers and rules are ASCII)."""
    return Path(path).read_bytes().decode("latin-1")


_stub_cache: dict = {}


def reference_stubs(relpath: str) -> dict[str, str]:
    """function -> its template stub statement, for the regions of this installation's ``relpath``
    (kernels/shared/rt_memory.h...): what "still the stub" is compared with, token by token
    (rtlab.course.regions.stubbed_functions). {} for a file the installation lacks."""
    from .regions import template_stubs
    path = reference_kernels().parent / relpath
    try:
        st = path.stat()
    except OSError:
        return {}
    key = (str(path), st.st_mtime_ns, st.st_size)
    if key not in _stub_cache:
        _stub_cache[key] = template_stubs(read_text(path), relpath)
    return _stub_cache[key]


def stub_steps(text: str, relpath: str, keep_before: str | None, owners=None) -> str:
    """``text`` with the regions of every step from ``keep_before`` on stubbed (each with its own
    step's TODO line); ``keep_before=None`` stubs every region."""
    owners = region_owners() if owners is None else owners
    by_step: dict[str, list[str]] = {}
    for r in find_regions(text, relpath):
        step = owners.get((relpath, r.function), UNOWNED_STEP)
        if keep_before is None or step >= keep_before:
            by_step.setdefault(step, []).append(r.function)
    for step, functions in sorted(by_step.items()):
        text = strip_regions(text, functions, step if step != UNOWNED_STEP else "course", relpath)
    return text


def template_text(config: LabConfig, relpath: str, functions=None) -> str:
    """The file as the lab's template hands it out: this step's and later steps' regions stubbed."""
    return stub_steps(read_text(reference_kernels().parent / relpath), relpath, config.step)


def copy_stubbed(src: Path, dst: Path, keep_before: str | None) -> None:
    """Copy kernel sources with the regions of every step from ``keep_before`` on stubbed (all with None)."""
    owners = region_owners()
    for rel in kernel_files(src):
        out = dst / Path(rel).relative_to("kernels")
        out.parent.mkdir(parents=True, exist_ok=True)
        text = read_text(src / Path(rel).relative_to("kernels"))
        out.write_bytes(stub_steps(text, rel, keep_before, owners).encode("latin-1"))


# --------------------------------------------------------------------------------------------------
# the submission's files
# --------------------------------------------------------------------------------------------------
def _regular_files(root: Path):
    """Files under ``root`` reached without following links (os.walk does not enter linked folders)."""
    import os
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        dirnames.sort()
        for name in sorted(filenames):
            yield Path(dirpath) / name


def find_submitted_file(submission: Path, relpath: str) -> tuple[Path | None, str | None]:
    """The submission's copy of ``relpath`` (e.g. kernels/shared/rt_types.h): by its path, by its
    path below kernels/, or by its name anywhere (Gradescope uploads arrive flat). (path, note).
    A symbolic link is returned as found (the rule refuses it); linked folders are not entered."""
    rel = Path(relpath)
    parts = rel.parts
    for k in range(len(parts)):
        sub = parts[k:]
        p = submission.joinpath(*sub)
        if not (p.is_symlink() or p.is_file()):
            continue
        if any(submission.joinpath(*sub[:j]).is_symlink() for j in range(1, len(sub))):
            continue   # reached through a linked folder
        return p, None
    found = [p for p in _regular_files(submission) if p.name == rel.name]
    if not found:
        return None, None
    if len(found) > 1:
        return found[0], (f"{len(found)} files named {rel.name} in the submission; graded "
                          f"{found[0].relative_to(submission)}")
    return found[0], None


@dataclass
class StudentTree:
    root: Path                                          # .../kernels
    notes: list[str] = field(default_factory=list)
    refused: dict[str, list[Refusal]] = field(default_factory=dict)     # relpath -> why
    stubs: dict[str, list[str]] = field(default_factory=dict)           # relpath -> functions still stubbed


# Why long: the order of its steps (copy stubbed, splice regions, refuse, write) is the grader's safety
# argument, so it stays in one reading.
def build_student_tree(config: LabConfig, submission: Path, out: Path, deadline_at: float | None = None) -> StudentTree:
    """The tree the submission compiles in (see the module docstring), at ``out/kernels``. A file
    not read by ``deadline_at`` (time.monotonic()) is refused."""
    from .regions import splice_regions, stubbed_functions
    ref = reference_kernels()
    tree = StudentTree(Path(out) / "kernels")
    copy_stubbed(ref, tree.root, config.step)
    from .checks import HARNESS_DIR
    rules = tree_rules(ref, sorted(HARNESS_DIR.glob("*")))
    owners = region_owners()
    lab_paths = {lf.path for lf in config.files}

    def take(relpath: str) -> bytes | None:
        """The submitted bytes of relpath after the rule: None when not handed in, b"" (and a refusal)
        when refused."""
        src, note = find_submitted_file(Path(submission), relpath)
        if note:
            tree.notes.append(note)
        if src is None:
            return None
        try:
            data = read_submitted(src, relpath)
            problems = check_source(data.decode("latin-1"), relpath, rules, deadline_at)
            if problems:
                raise Refused(problems)
        except Refused as e:
            tree.refused[relpath] = e.refusals
            return b""
        return data

    for lf in config.files:
        target = tree.root / Path(lf.path).relative_to("kernels")
        data = take(lf.path)
        if data is None:
            tree.notes.append(f"{lf.path} was not handed in: graded with the template's version (stubs)")
        elif lf.path in tree.refused:
            target.write_bytes(refused_placeholder(tree.refused[lf.path]))
        else:
            target.write_bytes(earlier_steps_from_reference(data, lf.path, config.step, owners, tree.notes))

    # A student release has no reference for earlier steps either: take the student's own (their
    # earlier labs), when the submission holds those files, else they stay stubbed.
    for rel in kernel_files(tree.root):
        if rel in lab_paths:
            continue
        path = tree.root / Path(rel).relative_to("kernels")
        text = read_text(path)
        stubs = reference_stubs(rel)
        earlier = [f for f in stubbed_functions(text, stubs)
                   if owners.get((rel, f), UNOWNED_STEP) < config.step]
        if not earlier:
            continue
        data = take(rel)
        if data is None:
            continue
        if rel in tree.refused:
            tree.notes.append(f"{rel} (earlier steps' functions {', '.join(earlier)}) not used: "
                              + "; ".join(str(r) for r in tree.refused.pop(rel)))
            continue
        theirs = data.decode("latin-1")
        try:
            written = [f for f in earlier if f not in stubbed_functions(theirs, stubs)
                       and f in {r.function for r in find_regions(theirs, rel)}]
        except LabError:
            continue
        if not written:
            continue
        path.write_bytes(splice_regions(text, theirs, rel, functions=written).encode("latin-1"))
        tree.notes.append(f"{', '.join(written)} ({rel}): this installation has no reference for earlier steps; "
                          f"graded with the submission's own")

    for lf in config.files:
        if lf.path in tree.refused:
            continue
        text = read_text(tree.root / Path(lf.path).relative_to("kernels"))
        stubs = [f for f in stubbed_functions(text, reference_stubs(lf.path)) if f in lf.functions]
        if stubs:
            tree.stubs[lf.path] = stubs
    return tree


def earlier_steps_from_reference(data: bytes, relpath: str, step: str, owners, notes: list[str]) -> bytes:
    """A submitted file with the regions of earlier steps (lab 04's functions in a lab 05
    rt_whitted.h) holding the reference's bodies, where this installation has them: a step is
    graded on its own functions. Everything else stays as written."""
    from .regions import splice_regions, stubbed_functions
    text = data.decode("latin-1")
    try:
        earlier = [r.function for r in find_regions(text, relpath)
                   if owners.get((relpath, r.function), UNOWNED_STEP) < step]
    except LabError:
        return data    # unbalanced markers: the file is compiled as written
    if not earlier:
        return data
    reference = read_text(reference_kernels().parent / relpath)
    theirs = {r.function: r.body(text) for r in find_regions(text, relpath)}
    ours = {r.function: r.body(reference) for r in find_regions(reference, relpath)}
    given = [f for f in earlier if f in ours and f not in stubbed_functions(reference, reference_stubs(relpath))
             and ours[f] != theirs[f]]
    if not given:
        return data
    notes.append(f"{', '.join(given)} in {relpath}: earlier steps' functions, graded with the reference's")
    return splice_regions(text, reference, relpath, functions=given).encode("latin-1")


def tree_stubs(root: Path) -> dict[str, list[str]]:
    """relpath -> functions of kernel sources that still hold a template stub."""
    from .regions import stubbed_functions
    out = {}
    for rel in kernel_files(root):
        found = stubbed_functions(read_text(Path(root) / Path(rel).relative_to("kernels")), reference_stubs(rel))
        if found:
            out[rel] = found
    return out


def has_reference(step: str | None = None) -> bool:
    """Whether this installation's kernels hold the solutions (of ``step``, or of every step): false in
    a student release."""
    stubs = {f for fs in tree_stubs(reference_kernels()).values() for f in fs}
    if step is None:
        return not stubs
    return not any(f in stubs for lf in load_config(step).files for f in lf.functions)


def kernel_sources_summary(variant=None, step: str | None = None, kernels=("render_primary",)) -> str:
    """One or two lines saying which kernel sources this process compiles (and where that choice came
    from) and which functions in it are still the template's stubs; with ``variant`` (and the lab
    ``step`` whose kernel runs), a warning when the kernels it launches call one of them."""
    from ..paths import REFERENCE_KERNEL_DIR, kernel_dir
    root = kernel_dir()
    env = settings.get("RTLAB_KERNEL_DIR")
    if env and Path(env).resolve() == root.resolve():
        origin = "from $RTLAB_KERNEL_DIR"
    elif root.resolve() == REFERENCE_KERNEL_DIR.resolve():
        origin = "this installation's kernels/"
    else:
        origin = "from --kernels"
    stubs = tree_stubs(root)
    names = {f: rel for rel, fs in stubs.items() for f in fs}
    if not names:
        return f"kernel sources: {root} ({origin}): no template stubs, every lab function is written"
    line = (f"kernel sources: {root} ({origin}): {len(names)} functions still hold the template's stub "
            f"({', '.join(sorted(names)[:8])}{', ...' if len(names) > 8 else ''})")
    if variant is not None:
        from ..device.kernels import SceneFeatures, build_defines, kernel_source, primary_step
        from .cpp import Preprocessor
        try:
            source = kernel_source(step or primary_step(variant), "opencl")
            pp = Preprocessor([root / "shared"], build_defines(variant, SceneFeatures())).run(source)
            used = sorted(f for f in pp.reachable(list(kernels)) if f in names)
        except Exception:   # a summary, never a reason to stop a render
            used = []
        if used:
            line += (f"\nwarning: this {variant.label()} render calls {', '.join(used)}, still a stub: its "
                     f"image and --check show the stub, not a solution")
    return line
