"""What a kernel source includes, as the C preprocessor itself finds it: the source of truth for
the include rule (rtlab.course.submission reads the text; this runs the compiler's preprocessor).

A test process calls :func:`outside_includes` before each compile, with the compile's own include
folders and defines: clang's ``-M -MG`` lists every file the preprocessor opens (a byte-order mark,
a macro, a line splice or any other spelling the rule's lexer reads otherwise changes nothing
here). Every file must lie in the kernel sources being compiled or the grader's harness folder
(clang's own OpenCL header aside); anything else refuses the compile, naming the file. The clang
that PoCL was built with (``clang-15`` for PoCL 3.1's LLVM 15) is preferred; any clang works.

The same clang gives the lab-call rule (rtlab.course.lab_calls) the program's call graph:
:func:`opencl_ir`, the program as LLVM IR before any optimisation.
"""
from __future__ import annotations

import functools
import os
import re
import shutil
import subprocess
from pathlib import Path

TIMEOUT_S = 120        # the grader's setup limit stops it sooner
MEMORY_SIGNS = ("bad_alloc", "out of memory", "Cannot allocate memory", "Allocation failed")


@functools.lru_cache(maxsize=None)
def find_clang() -> str | None:
    """A clang on PATH: the newest versioned one (Debian names them clang-NN), else plain clang."""
    found: dict[int, str] = {}
    for folder in os.environ.get("PATH", "").split(os.pathsep):
        try:
            for f in Path(folder or ".").glob("clang-[0-9]*"):
                m = re.fullmatch(r"clang-(\d+)", f.name)
                if m and os.access(f, os.X_OK):
                    found.setdefault(int(m.group(1)), str(f))
        except OSError:
            continue
    return found[max(found)] if found else shutil.which("clang")


@functools.lru_cache(maxsize=None)
def _resource_dir(clang: str) -> Path | None:
    try:
        out = subprocess.run([clang, "-print-resource-dir"], capture_output=True, text=True, timeout=TIMEOUT_S)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return Path(out.stdout.strip()).resolve() if out.returncode == 0 and out.stdout.strip() else None


def _make_deps(text: str) -> list[str]:
    """The prerequisites of a make rule as clang writes it (continuations, escaped spaces)."""
    body = text.replace("\\\n", " ")
    _, _, rest = body.partition(":")
    parts = re.split(r"(?<!\\)\s+", rest.strip())
    return [p.replace("\\ ", " ").replace("$$", "$") for p in parts if p]


def _run_clang(source: Path, include_dirs: list[Path], defines: dict, language: str, flags: list[str],
               text: str | None = None) -> str:
    """clang on ``source`` as the compile sees it (its folders and defines), with ``flags``: its output,
    or PreprocessorError (its diagnostics), MemoryError or RuntimeError. With ``text``, clang reads that
    (standard input) in place of the file, ``source`` naming it in messages."""
    clang = find_clang()
    if clang is None:
        raise RuntimeError("no clang on PATH to read the kernel as the compiler does (Debian's PoCL brings clang-NN)")
    lang = ["-x", "cl", "-cl-std=CL1.2"] if language == "opencl" else \
        ["-x", "c++", "-D__CUDACC__", "-D__CUDA_ARCH__=900", "-nostdinc", "-nostdinc++"]
    cmd = [clang, *lang, *flags, *(f"-I{Path(d).resolve()}" for d in include_dirs),
           *(f"-D{k}={v}" for k, v in sorted(defines.items())), "-" if text is not None else str(Path(source).resolve())]
    try:
        out = subprocess.run(cmd, input=text, capture_output=True, text=True, timeout=TIMEOUT_S, errors="replace")
    except subprocess.TimeoutExpired:
        raise RuntimeError(f"clang did not finish reading {source.name} in {TIMEOUT_S} s")
    except OSError as e:
        raise RuntimeError(f"cannot run {clang}: {e}")
    if out.returncode != 0:
        if any(sign in out.stderr for sign in MEMORY_SIGNS):
            raise MemoryError(f"clang ran out of memory on {source.name}")
        raise PreprocessorError(out.stderr)
    return out.stdout


def included_files(source: Path, include_dirs: list[Path], defines: dict, language: str) -> list[Path]:
    """Every file the preprocessor opens for ``source`` (itself first); RuntimeError when it cannot say."""
    text = _run_clang(source, include_dirs, defines, language, ["-E", "-M", "-MG", "-MT", "x"])
    return [Path(p) for p in _make_deps(text)]


def extension_flags(extensions) -> list[str]:
    """clang's options for exactly the runtime's OpenCL extensions (``None``: clang's own set): so that
    the rules' clang declares the built-ins, and defines the extension macros, the runtime does."""
    if extensions is None:
        return []
    return ["-Xclang", "-cl-ext=" + ",".join(["-all", *(f"+{e}" for e in extensions)])]


def opencl_ir(source: Path, include_dirs: list[Path], defines: dict, text: str | None = None,
              extensions=None) -> str:
    """An OpenCL C program's LLVM IR before any optimisation (nothing inlined away): who calls whom,
    as the compiler reads the code (rtlab.course.lab_calls), and what each function keeps where
    (rtlab.course.structure): local variables keep their names, and OpenCL's address spaces their
    numbers (clang's fake map on the host target: 1 global, 2 constant, 3 local; the target, and so
    every macro the kernels test, stays the host's, for the host's own CPU as PoCL compiles for it:
    ``-march=native``, so that a CPU macro the kernels use, ``__AVX__``, has PoCL's value here too and no
    branch on it is dead here and live there; and with PoCL's own language defines, POCL_LANGUAGE_DEFINES).
    ``text``: the program as :func:`preprocessed_opencl` gave it, read in place of ``source``;
    ``extensions``: the runtime's (:func:`extension_flags`)."""
    return _run_clang(source, include_dirs, defines, "opencl",
                      [*POCL_LANGUAGE_DEFINES, "-march=native", *extension_flags(extensions), "-emit-llvm", "-S", "-o", "-",
                       "-Xclang", "-disable-llvm-passes", "-Xclang", "-finclude-default-header", "-Xclang", "-ffake-address-space-map",
                       "-fno-discard-value-names", "-w"], text)


def preprocessed_opencl(source: Path, include_dirs: list[Path], defines: dict, runtime: dict | None = None,
                        extensions=None) -> str:
    """The program as one text, every directive but ``#pragma`` resolved by the rules' clang (as
    :func:`opencl_ir` preprocesses it): given to the runtime's compiler and to the rules alike, so that
    no conditional, stringized name or macro value can read one way here and another there. ``runtime``:
    the values the runtime's compiler gives the macros the kernels test (``None``: it leaves one
    undefined), so that the kernels take the runtime's branches; ``extensions``: the runtime's OpenCL
    extensions (:func:`extension_flags`). Line markers name the files the text
    came from (compiler messages point there); clang's own headers are left out (the runtime brings its
    own), their macros expanded where the program uses them."""
    predefined = [f"-D{k}={v}" if v is not None else f"-U{k}" for k, v in sorted((runtime or {}).items())]
    out = _run_clang(source, include_dirs, defines, "opencl",
                     [*POCL_LANGUAGE_DEFINES, "-march=native", *extension_flags(extensions), *predefined, "-E",
                      "-Xclang", "-finclude-default-header", "-w"])
    clang = find_clang()
    resource = _resource_dir(clang) if clang else None
    kept, keep = [], True
    for line in out.splitlines():
        m = LINE_MARKER.match(line)
        if m is None:
            if keep:
                kept.append(line)
            continue
        name = m.group(2)
        keep = not (name.startswith("<") or (resource is not None and Path(name).resolve().is_relative_to(resource)))
        if keep:        # without flags: the runtime's compiler keeps no include stack for this text
            kept.append(f"# {m.group(1)} \"{name}\"")
    return "\n".join(kept) + "\n"


LINE_MARKER = re.compile(r'^# (\d+) "((?:[^"\\]|\\.)*)"(?: \d)*$')


# What PoCL's own compile command defines that changes the language, given to the rules' clang too: PoCL
# builds every kernel with -Dinline= (its other -D options name reserved, CL_, cl_ and POCL_ macros,
# which submitted files may not use). Without it, `inline` was a keyword here and nothing there, and a
# macro that tests for an empty argument folded a call away here that ran there.
POCL_LANGUAGE_DEFINES = ("-Dinline=",)

# Where PoCL keeps the headers it puts in front of every kernel it compiles (Debian's pocl-opencl-icd, a
# local build); a pip PoCL's are found under the Python installation
POCL_INCLUDE_DIRS = ("/usr/share/pocl/include", "/usr/local/share/pocl/include")
# PoCL's renames of OpenCL's built-in functions (sin -> _cl_sin): the same functions in both compilers
POCL_RENAMES_HEADER = "_builtin_renames.h"


@functools.lru_cache(maxsize=None)
def runtime_only_macros() -> frozenset:
    """Macros PoCL's kernel headers define that the rules' clang (opencl_ir's) does not: a name such as
    ``LLVM_15_0`` or ``CLANG_MAJOR`` means one thing in the compile that runs a kernel and nothing in the
    one the grader's rules read (rtlab.course.submission refuses them in submitted files). Empty when
    neither PoCL's headers nor clang is found."""
    import sys
    dirs = [Path(d) for d in POCL_INCLUDE_DIRS] + sorted(Path(sys.prefix).glob("lib/python3*/site-packages/pocl*/**/include"))
    pocl: set[str] = set()
    for d in dirs:
        for h in (sorted(d.glob("*.h")) if d.is_dir() else []):
            if h.name == POCL_RENAMES_HEADER:
                continue
            try:
                text = h.read_text(errors="replace")
            except OSError:
                continue
            pocl.update(re.findall(r"^[ \t]*#[ \t]*define[ \t]+([A-Za-z_]\w*)", text, re.M))
    clang = find_clang()
    if not pocl or clang is None:
        return frozenset(pocl)
    try:
        out = subprocess.run([clang, "-x", "cl", "-cl-std=CL1.2", *POCL_LANGUAGE_DEFINES, "-march=native",
                              "-Xclang", "-finclude-default-header",
                              "-dM", "-E", "-"], input="", capture_output=True, text=True, timeout=TIMEOUT_S).stdout
    except (OSError, subprocess.TimeoutExpired):
        return frozenset(pocl)
    ours = set(re.findall(r"^#define ([A-Za-z_]\w*)", out, re.M))
    return frozenset(pocl - ours)


class PreprocessorError(RuntimeError):
    """The preprocessor stopped on the source (its diagnostics: a #error, a bad #if...)."""


def outside_includes(source: Path, include_dirs: list[Path], defines: dict, language: str,
                     allowed: list[Path]) -> list[str]:
    """Files the preprocessor opens for ``source`` outside ``allowed`` (and clang's own headers)."""
    roots = [Path(a).resolve() for a in allowed]
    clang = find_clang()
    resource = _resource_dir(clang) if clang else None
    if resource is not None:
        roots.append(resource)
    out = []
    for f in included_files(source, include_dirs, defines, language):
        p = f.resolve()
        if not any(p == r or r in p.parents for r in roots):
            out.append(str(f))
    return out
