"""Registers, stack, spills and SASS instruction counts of CUDA kernels, offline (no GPU needed).

    python experiments/nvcc_kernel_report.py SOURCE.cu VARIANT [VARIANT ...] [--define NAME=V ...]

VARIANT is "traversal/test/WxH" (e.g. bvh/watertight/8x16). Each is compiled with the loader's
defines (rtlab.device.kernels.build_defines) for FEATURES below, a fixed scene shape, so two kernel
trees (before and after a refactor) compile the same configuration: the same defines, the same
`nvcc -cubin -arch=sm_90 -Xptxas -v`; `cuobjdump -sass` gives each kernel's instruction count.
"""
from __future__ import annotations

import argparse
import re
import subprocess
import tempfile
from pathlib import Path

from rtlab.backends.base import CUDA_PRECISION_OPTIONS
from rtlab.backends.nvcc import parse_ptxas
from rtlab.device.kernels import SceneFeatures, Variant, build_defines

# A SPONZA-sized scene with lights, reflective and transparent materials: every shading feature in
FEATURES = SceneFeatures(stack_size=48, smooth_normals=False, n_lights=1, n_materials=16, near_origin=True)


def sass_counts(cubin: Path, dump: Path | None = None) -> dict[str, int]:
    """Instructions per kernel in the cubin's SASS; the listing written to ``dump`` when given."""
    text = subprocess.run(["cuobjdump", "-sass", str(cubin)], capture_output=True, text=True, check=True).stdout
    if dump is not None:
        dump.write_text(text)
    out: dict[str, int] = {}
    for chunk in re.split(r"(?=\s+Function : )", text):
        m = re.search(r"Function : (\w+)", chunk)
        if m:
            out[m.group(1)] = len(re.findall(r"/\*[0-9a-f]{4,}\*/\s+[^;]*;", chunk))
    return out


def report(source: Path, variant: Variant, extra: dict, sass_dir: Path | None = None) -> list[str]:
    defines = {**build_defines(variant, FEATURES), **extra}
    with tempfile.TemporaryDirectory() as tmp:
        cubin = Path(tmp) / "k.cubin"
        cmd = ["nvcc", "-cubin", "-arch=sm_90", "-Xptxas", "-v", f"-I{source.resolve().parent.parent / 'shared'}",
               *[f"-D{k}={v}" for k, v in sorted(defines.items())], *CUDA_PRECISION_OPTIONS, "-o", str(cubin), str(source)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode:
            return [f"{variant.label()}: build failed\n{proc.stderr}"]
        res = parse_ptxas(proc.stderr)
        dump = None
        if sass_dir is not None:
            sass_dir.mkdir(parents=True, exist_ok=True)
            dump = sass_dir / f"{source.stem}-{variant.label().replace('/', '-')}.sass"
        sass = sass_counts(cubin, dump)
    return [f"{source.name:22} {variant.label():38} {name:26} {r.registers:4} regs {r.local_bytes:5} B stack "
            f"{r.spill_bytes:4} B spills {r.shared_bytes:6} B smem {sass.get(name, 0):6} SASS"
            for name, r in sorted(res.items())]


def parse_variant(text: str) -> Variant:
    traversal, isect, block = text.split("/")
    bx, by = (int(b) for b in block.split("x"))
    return Variant(traversal=traversal, intersection=isect, block=(bx, by))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", type=Path)
    ap.add_argument("variants", nargs="+")
    ap.add_argument("--define", action="append", default=[], help="NAME=VALUE beyond the loader's")
    ap.add_argument("--sass-dir", type=Path, help="write each build's SASS listing here (to diff two trees)")
    args = ap.parse_args()
    extra = dict(d.split("=", 1) for d in args.define)
    for v in args.variants:
        print("\n".join(report(args.source, parse_variant(v), extra, args.sass_dir)), flush=True)


if __name__ == "__main__":
    main()
