"""A grading test's programs on PoCL as one text: each program is preprocessed once, by the rules' clang
(rtlab.course.deps.preprocessed_opencl), and that text is what both the runtime's compiler builds and
the rules (rtlab.course.lab_calls, rtlab.course.structure) read. A conditional, a stringized name or
a macro's value then cannot read one way in the rules and another in the program that runs: every
directive but ``#pragma`` is gone before either sees the code.

The kernels test a few macros the runtime's compiler defines (``cl_khr_fp64``, ``__AVX__``): so that the
kernels still take the runtime's branches, a tiny program asks the runtime for their values first
(:func:`runtime_macro_values`: a program of empty kernels, one a fact, that it compiles but never
runs), and the preprocessing gives them those; the rules' clang also takes the runtime's set of OpenCL
extensions (its built-ins and extension macros). The names come from the reference's tree
(:func:`runtime_tested_macros`, in the grader), not from the submission.

What the one text leaves to the runtime is its own headers: PoCL still renames the built-ins there
(``#define sin _cl_sin``), so the submission rule refuses names that begin with ``_``
(rtlab.course.submission), and the rules refuse overloads of a lab function (rtlab.course.lab_calls).
"""
from __future__ import annotations

import functools
from pathlib import Path


@functools.lru_cache(maxsize=None)
def runtime_tested_macros(root: Path) -> tuple[str, ...]:
    """Macros the conditionals of the kernel tree at ``root`` test that the tree never defines and that
    are no lab option (``RT_``, given as -D): those a compiler or runtime provides."""
    from .submission import tree_rules
    rules = tree_rules(Path(root))
    tested = frozenset().union(*rules.tested_by_file.values())
    return tuple(sorted(n for n in tested - rules.defined_anywhere if not n.startswith("RT_")))


VALUE_BITS = 31        # a macro's value is read bit by bit, its sign apart


def _probe_source(names, values: bool) -> str:
    """One empty kernel for each fact: ``d_i`` where name i is defined, ``n_i`` where its value is
    negative, ``b_i_k`` where bit k of its magnitude is set (read back from the program's kernel
    names: the runtime's compiler answers, nothing runs)."""
    lines = ["kernel void rtlab_probe(void) {}"]
    for i, n in enumerate(names):
        lines += [f"#if defined({n})", f"kernel void d_{i}(void) {{}}"]
        if values:
            v = f"({n} + 0)"
            lines += [f"#if {v} < 0", f"kernel void n_{i}(void) {{}}", "#endif"]
            for k in range(VALUE_BITS):
                lines += [f"#if (({v} < 0 ? -{v} : {v}) >> {k}) & 1", f"kernel void b_{i}_{k}(void) {{}}", "#endif"]
        lines += ["#endif"]
    return "\n".join(lines) + "\n"


def runtime_macro_values(backend, names) -> dict[str, str | None]:
    """What the runtime's OpenCL compiler defines ``names`` to (an integer below 2^31, as text), or None
    where it leaves one undefined, asked of the runtime's own compiler. Where some name's value is no
    integer the preprocessor can evaluate, each defined name is taken as 1."""
    import pyopencl as cl
    names = list(names)
    if not names:
        return {}
    for values in (True, False):
        try:
            program = cl.Program(backend.context, _probe_source(names, values)).build()
        except cl.RuntimeError:
            continue
        facts = set(program.kernel_names.split(";"))
        out: dict[str, str | None] = {}
        for i, n in enumerate(names):
            if f"d_{i}" not in facts:
                out[n] = None
                continue
            magnitude = sum(1 << k for k in range(VALUE_BITS) if f"b_{i}_{k}" in facts) if values else 1
            out[n] = str(-magnitude if f"n_{i}" in facts else magnitude)
        return out
    raise RuntimeError(f"the runtime's compiler builds no program that reads its own macros ({', '.join(names)})")


class OneText:
    """(path, defines) -> the program's one text, made once (the Recorder asks first, for the rules;
    the backend's compile asks again)."""

    def __init__(self, backend, names):
        self.backend = backend
        self.names = tuple(names)
        # the runtime's extensions: the rules' clang then declares the built-ins the runtime does
        device = getattr(backend, "device", None)
        self.extensions = tuple(str(device.extensions).split()) if device is not None else None
        self._runtime: dict | None = None
        self._texts: dict = {}

    def runtime(self) -> dict:
        if self._runtime is None:
            self._runtime = runtime_macro_values(self.backend, self.names)
        return self._runtime

    def __call__(self, path: Path, defines: dict) -> str:
        from rtlab.paths import include_dirs
        from .deps import preprocessed_opencl
        key = (str(path), tuple(sorted((k, str(v)) for k, v in defines.items())))
        if key not in self._texts:
            self._texts[key] = preprocessed_opencl(Path(path), [*include_dirs(path), Path(path).parent], defines,
                                                   self.runtime(), self.extensions)
        return self._texts[key]
