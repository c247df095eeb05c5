"""Offline CUDA resource report: compile a .cu with `nvcc -cubin -Xptxas -v` and read registers,
stack (local) bytes, spills, shared and constant memory per kernel. Works on machines without a GPU,
so CI and graders can report what the compiler gave a kernel (the paper's "Reg. usage" rows)."""
from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
from pathlib import Path

from ..errors import KernelBuildError
from ..paths import include_dirs
from .base import CUDA_PRECISION_OPTIONS, KernelResources, format_build_error
from .occupancy import SM90, cuda_occupancy


def _includes(path) -> list[str]:
    return [f"-I{d}" for d in include_dirs(path)]


def nvcc_available() -> bool:
    return shutil.which("nvcc") is not None


def nvcc_resources(path: Path, defines: dict, arch: str = "sm_90", block_threads: int = 128,
                   extra_options: tuple[str, ...] = ()) -> dict[str, KernelResources]:
    """Per-kernel resources from ptxas; occupancy for ``block_threads`` threads on sm_90 limits."""
    if not nvcc_available():
        raise KernelBuildError("nvcc not found on PATH: the offline CUDA report needs the CUDA toolkit")
    with tempfile.TemporaryDirectory() as tmp:
        cmd = ["nvcc", "-cubin", f"-arch={arch}", "-Xptxas", "-v", *_includes(path),
               *[f"-D{k}={v}" for k, v in sorted(defines.items())], *CUDA_PRECISION_OPTIONS, *extra_options,
               "-o", str(Path(tmp) / "k.cubin"), str(path)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise KernelBuildError(format_build_error(path, defines, proc.stderr))
    return parse_ptxas(proc.stderr, block_threads)


def nvcc_ptx(path: Path, defines: dict, arch: str = "sm_90", extra_options: tuple[str, ...] = ()) -> str:
    """The PTX nvcc makes of ``path``: what the kernels read from where (tex, ld.shared, ld.local)."""
    if not nvcc_available():
        raise KernelBuildError("nvcc not found on PATH: the offline CUDA report needs the CUDA toolkit")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "k.ptx"
        cmd = ["nvcc", "-ptx", f"-arch={arch}", *_includes(path),
               *[f"-D{k}={v}" for k, v in sorted(defines.items())], *CUDA_PRECISION_OPTIONS, *extra_options,
               "-o", str(out), str(path)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
                raise KernelBuildError(format_build_error(path, defines, proc.stderr))
        return out.read_text()


def parse_ptxas(log: str, block_threads: int = 128) -> dict[str, KernelResources]:
    out: dict[str, KernelResources] = {}
    for chunk in re.split(r"(?=ptxas info\s*: Compiling entry function)", log):
        m = re.search(r"Compiling entry function '([^']+)'", chunk)
        if not m:
            continue
        name = m.group(1)
        num = lambda pat: int(g.group(1)) if (g := re.search(pat, chunk)) else 0
        regs = num(r"Used (\d+) registers")
        smem = num(r"(\d+) bytes smem")
        res = KernelResources(kernel=name, backend="nvcc",
                              registers=regs,
                              local_bytes=num(r"(\d+) bytes stack frame"),
                              shared_bytes=smem,
                              const_bytes=num(r"(\d+) bytes cmem\[0\]"),
                              spill_bytes=num(r"(\d+) bytes spill stores") + num(r"(\d+) bytes spill loads"),
                              block=(block_threads,),
                              occupancy=cuda_occupancy(regs, block_threads, smem, SM90))
        out[name] = res
    return out
