"""What a quantised child plane costs to decode on sm_90, offline (nvcc and cuobjdump, no GPU).

A quantised node (experiments/bvh4_quantised_cost.py counts what its grown boxes cost the walk) stores
each child plane as a small integer or a half, which the visit turns into a float before its fma. This
compiles each way of doing that, four planes from one 32-bit word (two for halves), and prints the SASS
each plane takes: which instructions, and how many go to sm_90's half-rate integer pipe or to the
conversion unit (16 lanes a clock an SM: an instruction a warp holds it for 8 of the scheduler's clocks).

    python experiments/quantised_decode_sass.py        (needs nvcc; cuobjdump on PATH or beside nvcc)
"""
from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from nvcc_kernel_report import NARROW_PIPE, sass_functions   # noqa: E402

# Each form: (planes a word, the expression of plane j of word x as a float). s, b: the fma's operands.
FORMS = {
    "8-bit, (float) of the byte": (4, "(float)((x >> (8 * J)) & 255u)"),
    "8-bit, exponent trick (byte into 2^23's mantissa, minus 2^23)":
        (4, "(__int_as_float(__byte_perm(x, 0x4B000000u, 0x7650 + J)) - 8388608.0f)"),
    "16-bit half (a fraction of the node's box)":
        (2, "(J == 0 ? __low2float(*reinterpret_cast<const __half2 *>(&x)) "
            ": __high2float(*reinterpret_cast<const __half2 *>(&x)))"),
}
CONVERSION_UNIT = {"I2F", "F2F", "F2I"}     # sm_90 SASS opcodes of the 16-lane conversion unit


def kernel_source(planes: int, expr: str) -> str:
    terms = " + ".join(f"fmaf({expr.replace('J', str(j))}, s, b)" for j in range(planes))
    return ("#include <cuda_fp16.h>\n"
            "extern \"C\" __global__ void k(const unsigned *w, const float *a, float *out)\n"
            "{\n    unsigned x = w[threadIdx.x];\n    float s = a[0], b = a[1];\n"
            f"    out[threadIdx.x] = {terms};\n}}\n")


def main():
    nvcc = shutil.which("nvcc")
    if nvcc is None:
        sys.exit("nvcc not found: this script reads the SASS that nvcc makes for sm_90")
    cuobjdump = shutil.which("cuobjdump") or str(Path(nvcc).parent / "cuobjdump")
    print("| decode | a plane: instructions besides its fma | integer pipe (half rate) | conversion unit | opcodes |")
    print("|---|---:|---:|---:|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name, (planes, expr) in FORMS.items():
            src, cubin = Path(tmp) / "k.cu", Path(tmp) / "k.cubin"
            src.write_text(kernel_source(planes, expr))
            subprocess.run([nvcc, "-cubin", "-arch=sm_90", "-o", str(cubin), str(src)], check=True)
            sass = subprocess.run([cuobjdump, "-sass", str(cubin)], capture_output=True, text=True, check=True).stdout
            ops: dict[str, int] = {}
            for _, ins in sass_functions(sass)["k"]:
                op = ins.split()[1 if ins.startswith("@") else 0].split(".")[0]
                ops[op] = ops.get(op, 0) + 1
            # what the decode adds: all but the loads, the fmas, the sum's planes - 1 adds, the kernel's frame
            # and constant moves (HFMA2 -RZ, RZ: a MOV)
            decode = {op: n for op, n in ops.items()
                      if op not in {"LDG", "LDC", "STG", "S2R", "IMAD", "FFMA", "EXIT", "BRA", "NOP", "ULDC", "MOV",
                                    "HFMA2"}}
            decode["FADD"] = decode.get("FADD", 0) - (planes - 1)
            decode = {op: n for op, n in decode.items() if n > 0}
            total = sum(decode.values()) / planes
            narrow = sum(n for op, n in decode.items() if op in NARROW_PIPE) / planes
            conv = sum(n for op, n in decode.items() if op in CONVERSION_UNIT) / planes
            listing = ", ".join(f"{op} {n}" for op, n in sorted(decode.items(), key=lambda kv: -kv[1]))
            print(f"| {name} | {total:.2f} | {narrow:.2f} | {conv:.2f} | {listing} (for {planes} planes) |")
    print("The exponent trick's FADD is exact (the byte in 2^23's mantissa); folding the 2^23 into the fma's "
          "addend would round it by up to half a quantisation step.")


if __name__ == "__main__":
    main()
