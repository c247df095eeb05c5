"""Registers, stack, spills and SASS instruction counts of CUDA kernels, offline (no GPU needed).

    python experiments/nvcc_kernel_report.py SOURCE.cu VARIANT [VARIANT ...] [--define NAME=V ...]

VARIANT is "traversal/test/WxH" (e.g. bvh/watertight/8x16). Each is compiled with the loader's
defines (rtlab.device.kernels.build_defines) for FEATURES below, a fixed scene shape, so two kernel
trees (before and after a refactor) compile the same configuration: the same defines, the same
`nvcc -cubin -arch=sm_90 -Xptxas -v`; `cuobjdump -sass` gives each kernel's instruction count.

With --node-loop N, each kernel's node loop too: the smallest loop (a backward branch and the code it
jumps over) that holds at least N 128-bit loads (7 for the 4-wide BVH's node, 3 for the binary BVH's),
its instructions and how many of them issue to sm_90's half-width integer/compare pipe.
"""
from __future__ import annotations

import argparse
import re
import subprocess
import tempfile
from pathlib import Path

from rtlab.backends.base import CUDA_PRECISION_OPTIONS
from rtlab.backends.nvcc import parse_ptxas
from rtlab.device.kernels import SceneFeatures, Variant, build_defines, build_options

# A SPONZA-sized scene with lights, reflective and transparent materials: every shading feature in
FEATURES = SceneFeatures(stack_size=48, smooth_normals=False, n_lights=1, n_materials=16, near_origin=True)


# Opcodes that issue to the integer/compare pipe, 16 lanes a scheduler on sm_90 (the FMA pipe has 32)
NARROW_PIPE = {"VIMNMX", "VIMNMX3", "LOP3", "SEL", "ISETP", "FSETP", "FSEL", "IADD3", "SHF", "FMNMX", "PLOP3", "P2R",
               "R2P", "LEA", "PRMT"}


def sass_functions(text: str) -> dict[str, list[tuple[int, str]]]:
    """Each kernel's SASS as (address, instruction) pairs."""
    out = {}
    for chunk in re.split(r"(?=\s+Function : )", text):
        m = re.search(r"Function : (\w+)", chunk)
        if m:
            out[m.group(1)] = [(int(a, 16), ins.strip()) for a, ins in
                               re.findall(r"/\*([0-9a-f]{4,})\*/\s+([^;]*);", chunk)]
    return out


def node_loop(instructions: list[tuple[int, str]], wide_loads: int) -> tuple[int, int, dict] | None:
    """(instructions, of them on the narrow pipe, opcode counts) of the smallest loop holding at least
    ``wide_loads`` 128-bit global loads, or None."""
    best = None
    for addr, ins in instructions:
        m = re.search(r"BRA (0x[0-9a-f]+)", ins)
        if not m or int(m.group(1), 16) >= addr:
            continue
        body = [i for a, i in instructions if int(m.group(1), 16) <= a <= addr]
        if sum("LDG.E.128" in i for i in body) >= wide_loads and (best is None or len(body) < len(best)):
            best = body
    if best is None:
        return None
    ops: dict[str, int] = {}
    for i in best:
        op = i.split()[1 if i.startswith("@") else 0].split(".")[0]
        ops[op] = ops.get(op, 0) + 1
    return len(best), sum(n for op, n in ops.items() if op in NARROW_PIPE), ops


def sass_listing(cubin: Path, dump: Path | None = None) -> str:
    """The cubin's SASS listing (cuobjdump -sass), also written to ``dump`` when given."""
    text = subprocess.run(["cuobjdump", "-sass", str(cubin)], capture_output=True, text=True, check=True).stdout
    if dump is not None:
        dump.write_text(text)
    return text


def sass_counts(text: str) -> dict[str, int]:
    """Instructions per kernel in a SASS listing."""
    return {name: len(ins) for name, ins in sass_functions(text).items()}


def report(source: Path, variant: Variant, extra: dict, sass_dir: Path | None = None, wide_loads: int = 0) -> list[str]:
    defines = {**build_defines(variant, FEATURES), **extra}
    with tempfile.TemporaryDirectory() as tmp:
        cubin = Path(tmp) / "k.cubin"
        cmd = ["nvcc", "-cubin", "-arch=sm_90", "-Xptxas", "-v", f"-I{source.resolve().parent.parent / 'shared'}",
               *[f"-D{k}={v}" for k, v in sorted(defines.items())], *CUDA_PRECISION_OPTIONS,
               *build_options(variant, "cuda", source.stem), "-o", str(cubin), str(source)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode:
            return [f"{variant.label()}: build failed\n{proc.stderr}"]
        res = parse_ptxas(proc.stderr)
        dump = None
        if sass_dir is not None:
            sass_dir.mkdir(parents=True, exist_ok=True)
            dump = sass_dir / f"{source.stem}-{variant.label().replace('/', '-')}.sass"
        text = sass_listing(cubin, dump)
    sass = sass_counts(text)
    loops = {name: node_loop(ins, wide_loads) for name, ins in sass_functions(text).items()} if wide_loads else {}
    lines = []
    for name, r in sorted(res.items()):
        line = (f"{source.name:22} {variant.label():38} {name:26} {r.registers:4} regs {r.local_bytes:5} B stack "
                f"{r.spill_bytes:4} B spills {r.shared_bytes:6} B smem {sass.get(name, 0):6} SASS")
        loop = loops.get(name)
        if loop is not None:
            line += f"; node loop {loop[0]} ({loop[1]} narrow-pipe): " + \
                " ".join(f"{op} {n}" for op, n in sorted(loop[2].items(), key=lambda kv: -kv[1]))
        lines.append(line)
    return lines


def parse_variant(text: str) -> Variant:
    """traversal/intersection/BXxBY, optionally /rNN: a register cap in place of the program's own"""
    traversal, isect, block, *cap = text.split("/")
    bx, by = (int(b) for b in block.split("x"))
    regs = int(cap[0].lstrip("r")) if cap else 0
    return Variant(traversal=traversal, intersection=isect, block=(bx, by), max_registers=regs)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", type=Path)
    ap.add_argument("variants", nargs="+")
    ap.add_argument("--define", action="append", default=[], help="NAME=VALUE beyond the loader's")
    ap.add_argument("--sass-dir", type=Path, help="write each build's SASS listing here (to diff two trees)")
    ap.add_argument("--node-loop", type=int, default=0, metavar="N",
                    help="also each kernel's node loop: the smallest loop with at least N 128-bit loads")
    args = ap.parse_args()
    extra = dict(d.split("=", 1) for d in args.define)
    for v in args.variants:
        print("\n".join(report(args.source, parse_variant(v), extra, args.sass_dir, args.node_loop)), flush=True)


if __name__ == "__main__":
    main()
