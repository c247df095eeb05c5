"""Make docs/results.md, rtlab's current figures, from the fragments in docs/results/.

    python scripts/results_page.py            # write docs/results.md
    python scripts/results_page.py --check    # exit 1 (and say why) if docs/results.md is stale

Each fragment is one topic: a "## " title, a paragraph saying what is measured and on what, then one
or more blocks as the bench commands' ``--md`` option writes them ("### " title, ``Command:``, ``Date:``
with host and devices, the tables with their error column). To update a topic, run its command with
``--md`` (or the script it names), put the new block in place of the old one in the fragment, and run
this script: the page is never edited by hand (tests/test_docs.py checks that it is what this script
makes). What the figures were before, and why they changed, is CHANGELOG.md's.
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FRAGMENTS = ROOT / "docs" / "results"
PAGE = ROOT / "docs" / "results.md"

# The page's order: what a reader looks for first (the GPU, then the CPU), then how right it is,
# what the acceleration structures cost, and the course.
TOPICS = (
    "gpu-trace.md",
    "whitted.md",
    "paper-h100.md",
    "cpu.md",
    "numerics.md",
    "wide-bvh.md",
    "builds.md",
    "grading.md",
)

INTRO = """\
# Results

rtlab's current figures, one section a topic; each block names the command that made it, the date,
the host and the devices. This page is made by `python scripts/results_page.py` from the fragments in
`docs/results/` (edit those, not this page); how the figures came to be what they are, and every
measurement taken on the way, is in `CHANGELOG.md`.

How the figures are measured:

- **Time** is device time of the tracing kernels only (device events: CUDA events around the launch
  alone, OpenCL's profiling), the median of repeated launches after warm-up, acceleration structures
  built beforehand; Mrays/s = rays / median time. The CPU's figures give CPU time too: Mrays per
  CPU-second does not depend on the machine's load.
- **Error** is beside every time: hits compared with the float64 reference (`rtlab/reference`) by
  triangle id, exactly (mismatches; ties are rays through shared edges, vertices or coplanar overlaps
  whose answer float32 cannot decide) and by t (the largest relative difference); images by PSNR and
  the ray tree of each pixel.
- **Devices**: the lent H100 (NVIDIA H100 80GB HBM3, CUDA and NVIDIA's OpenCL; `experiments/gpu_*.sh`
  run a topic's commands in one device call) and the 2-core development machine (PoCL on an AMD EPYC,
  shared with other work: its load is in the rows). The benchmark views and the peers' figures are
  those of `../shared/bench/README.md`.
"""


def _title(text: str, name: str) -> str:
    first = text.splitlines()[0] if text else ""
    if not first.startswith("## "):
        raise SystemExit(f"docs/results/{name}: the first line must be the topic's '## ' title")
    return first[3:].strip()


def anchor(title: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", title.lower()).replace(" ", "-")


def commands(text: str) -> list[str]:
    """The commands a fragment's blocks name, shortened to what finds them: `rtlab bench rays`,
    `experiments/ab_trace_configs.py`, `make render`, ..."""
    found: list[str] = []
    for line in text.splitlines():
        if not line.startswith("Command:"):
            continue
        for cmd in re.findall(r"`([^`]+)`", line):
            words = cmd.split()
            script = next((w for w in words if w.endswith((".py", ".sh"))), None)
            if words[:2] == ["rtlab", "bench"] and len(words) > 2:
                short = " ".join(words[:3])
            elif words[:1] == ["rtlab"] and len(words) > 1:
                short = " ".join(words[:2])
            elif script:
                short = script
            elif words[:1] == ["make"]:
                short = " ".join(words[:2])
            else:
                continue
            if short not in found:
                found.append(short)
    return found


def build_page(fragments: Path = FRAGMENTS) -> str:
    texts = [(name, (fragments / name).read_text()) for name in TOPICS]
    contents = ["## Contents", ""]
    for name, text in texts:
        title = _title(text, name)
        cmds = ", ".join(f"`{c}`" for c in commands(text))
        contents.append(f"- [{title}](#{anchor(title)}): {cmds} (`docs/results/{name}`)")
    body = [text.rstrip("\n") + "\n" for _, text in texts]
    return "\n".join([INTRO, "\n".join(contents) + "\n", *body])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="only check that docs/results.md is up to date")
    args = ap.parse_args(argv)
    unknown = sorted(p.name for p in FRAGMENTS.glob("*.md") if p.name not in TOPICS)
    if unknown:
        print(f"docs/results/ holds fragments TOPICS does not list: {unknown}", file=sys.stderr)
        return 1
    page = build_page()
    if args.check:
        if not PAGE.exists() or PAGE.read_text() != page:
            print("docs/results.md is not what scripts/results_page.py makes: run it", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(page)
    print(f"wrote {PAGE.relative_to(ROOT)} ({len(page.splitlines())} lines, {len(TOPICS)} topics)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
