"""A grading test's own process: ``python -m rtlab.course.run_test TEST_DIR`` (or ``--reference``).

The grader (rtlab.course.grader) starts it with its result channel on the file descriptor
$RTLAB_RESULT_FD (rtlab.course.channel), commands on stdin, and TEST_DIR holding ``job.json`` (what to run, the
sandbox's folders) and ``inputs.pkl`` (the test's inputs, made by the grader: scene, rays, camera;
never an expected answer). In order:

1. **Sandbox, first.** One thread only (a Landlock domain binds the threads started after it), then
   limits and Landlock (rtlab.course.sandbox). A grader running as root has started it as an
   unprivileged user.
2. **Setup** (no submitted code runs): the kind's setup uploads the scene and compiles every kernel
   the test launches; each compile is checked first by the preprocessor's own list of what the
   source includes (rtlab.course.deps), by the lab-call rule on the compiler's own call graph
   (rtlab.course.lab_calls) and, on the same IR, by the structure rule (rtlab.course.structure: no
   per-ray stack in a stackless traversal...). ``{"event": "compile"}`` before each restarts the
   grader's setup limit.
3. **Close the sandbox:** PoCL's binaries built (rtlab.backends.opencl), the system-call filter
   installed; ``{"event": "ready"}``. The process then waits for the grader's go: before any
   submitted code has run, the grader takes the binaries just built into the run's shared kernel
   cache, which seeds the next test processes (a program compiled once a grading run).
4. **Run:** ``produce`` launches the submission's kernels; its raw outputs go back in one frame
   (``once``), or one per command (``serve``, the speed tests). The grader checks them.

``--reference`` is the reference worker: the installation's own kernels, never a submission's, for
the speed tests' reference launches and the work budgets' reference counts. It holds nothing a
test process could want, but is not sandboxed: it is the grader's.
"""
from __future__ import annotations

import json
import os
import sys
import time
import traceback
from pathlib import Path

def _send(header: dict, arrays=None) -> None:
    from rtlab.course.channel import write_frame
    from rtlab import settings
    write_frame(int(settings.get("RTLAB_RESULT_FD")), header, arrays)


def _error(status: str, output: str) -> None:
    _send({"event": "error", "status": status, "output": output})


class Recorder:
    """Wraps the backend's compile: a setup heartbeat before each, the preprocessor's include check,
    and the list of programs (for the grader's note on unfinished functions)."""

    def __init__(self, allowed_roots: list[Path] | None, lab_calls: dict | None = None,
                 structure: dict | None = None, runtime_macros=()):
        self.allowed = allowed_roots
        self.lab_calls = lab_calls          # rtlab.course.lab_calls' rules for this step (None: no rule)
        self.structure = structure          # rtlab.course.structure's allowances for this step (None: no rule)
        self.runtime_macros = tuple(runtime_macros)   # rtlab.course.one_text: what to ask the runtime
        self.one_text = None
        self.programs: list[dict] = []
        self.closed = False

    def tick(self) -> None:
        _send({"event": "compile"})

    def wrap(self, backend) -> None:
        compile_ = backend.compile
        if self.allowed is not None and backend.language == "opencl" and backend.is_pocl():
            # the rules and PoCL read one preprocessed text (rtlab.course.one_text); on a GPU's OpenCL
            # the program keeps its inline PTX (rt_port.h), which the rules' clang cannot read, so the
            # rules read the files as the compile does, under the lab's defines
            from rtlab.course.one_text import OneText
            self.one_text = backend.one_text = OneText(backend, self.runtime_macros)

        def compile(path, defines, options=()):
            from rtlab.errors import KernelBuildError
            key = {"path": str(path), "defines": {k: str(v) for k, v in dict(defines).items()}}
            entry = next((p for p in self.programs if p["path"] == key["path"] and p["defines"] == key["defines"]),
                         None)
            if entry is None:
                if self.closed:
                    raise KernelBuildError(f"{Path(path).name} was compiled after the sandbox closed: a grading test "
                                           f"compiles every kernel in its setup (a grader bug, not your code)")
                self.tick()
                entry = {**key, "kernels": []}
                self.programs.append(entry)
                _send({"event": "programs", "programs": self.programs})
                self.check_includes(backend, Path(path), defines)
                text = self.program_text(backend, Path(path), defines)
                unread = self.check_lab_calls(Path(path), defines, text)
            else:
                unread = None
            program = compile_(path, defines, options)
            if unread:      # clang could not read what PoCL compiled: the rule cannot say, so it refuses
                raise KernelBuildError(unread)
            if not getattr(program, "_recorded", False):
                launch = program.launch

                def recorded_launch(name, *args, **kwargs):
                    if name not in entry["kernels"]:
                        entry["kernels"].append(name)
                    return launch(name, *args, **kwargs)

                program.launch = recorded_launch
                program._recorded = True
            return program

        backend.compile = compile

    def check_includes(self, backend, path: Path, defines) -> None:
        if self.allowed is None:
            return
        from rtlab.backends.base import format_build_error
        from rtlab.errors import KernelBuildError
        from rtlab.course.deps import PreprocessorError, outside_includes
        from rtlab.course.submission import REFUSED_MARK
        from rtlab.paths import include_dirs
        try:
            outside = outside_includes(path, [*include_dirs(path), path.parent], dict(defines), backend.language,
                                       self.allowed)
        except PreprocessorError as e:
            raise KernelBuildError(format_build_error(path, dict(defines), str(e))) from None
        except RuntimeError as e:
            raise KernelBuildError(f"{REFUSED_MARK}{path.name}: {e}") from None
        if outside:
            raise KernelBuildError(f"{REFUSED_MARK}{path.name} opens {outside[0]}, outside the submission's kernel "
                                   f"tree (the preprocessor's own list of what it includes)"
                                   + (f"; also {', '.join(outside[1:4])}" if len(outside) > 1 else ""))

    def program_text(self, backend, path: Path, defines) -> str | None:
        """The program as one text (rtlab.course.one_text), made before the compile asks for it so that
        its errors read as a build's; None where the programs compile from their files."""
        if self.one_text is None:
            return None
        from rtlab.backends.base import format_build_error
        from rtlab.errors import KernelBuildError
        from rtlab.course.deps import PreprocessorError
        from rtlab.course.submission import REFUSED_MARK
        try:
            return self.one_text(path, backend.program_defines(defines))
        except PreprocessorError as e:
            raise KernelBuildError(format_build_error(path, dict(defines), str(e))) from None
        except (RuntimeError, MemoryError) as e:
            raise KernelBuildError(f"{REFUSED_MARK}{path.name}: {e}") from None

    def check_lab_calls(self, path: Path, defines, text: str | None = None) -> str | None:
        """The lab-call rule (rtlab.course.lab_calls) and the structure rule (rtlab.course.structure)
        on the program about to compile, both read from one LLVM IR: KernelBuildError when a graded
        function calls a lab function its reference does not, or keeps its state where its reference
        does not (more private arrays; for a packet, no or far more local memory); the refusal to raise
        after the compile when clang cannot build the IR (if the compiler fails too, its own error is
        the clearer one). ``text``: the program as the runtime compiles it (rtlab.course.one_text)."""
        calls = bool(self.lab_calls and self.lab_calls.get("allowed"))
        shape = bool(self.structure and self.structure.get("functions"))
        if not calls and not shape:
            return None
        from rtlab.course.deps import PreprocessorError, opencl_ir
        from rtlab.course.lab_calls import ir_call_graph, lab_call_problem, overloaded_lab_function, unread_definitions
        from rtlab.course.structure import structure_problem
        from rtlab.course.submission import REFUSED_MARK
        from rtlab.errors import KernelBuildError
        from rtlab.paths import include_dirs
        source = path if path.suffix == ".cl" else path.parent.parent / "opencl" / (path.stem + ".cl")
        if not source.is_file():
            return None                 # a CUDA-only program: no OpenCL twin to read (see lab_calls)
        try:
            ir = opencl_ir(source, [], {}, text, self.one_text.extensions) if text is not None else \
                opencl_ir(source, [*include_dirs(source), source.parent], dict(defines))
        except (PreprocessorError, RuntimeError, MemoryError) as e:
            first = str(e).strip().splitlines()[:3]
            return f"{REFUSED_MARK}{path.name}: its calls could not be read for the lab-call rule: {' '.join(first)}"
        if unread_definitions(ir):
            return f"{REFUSED_MARK}{path.name}: {unread_definitions(ir)} of its functions could not be read for the lab-call rule"
        graph = ir_call_graph(ir)
        problem = overloaded_lab_function(ir, (self.lab_calls or {}).get("owners") or {}) or \
            (lab_call_problem(graph, self.lab_calls) if calls else None) or \
            (structure_problem(ir, graph, self.structure, dict(defines)) if shape else None)
        if problem:
            raise KernelBuildError(f"{REFUSED_MARK}{problem}")
        return None


def _confine(job: dict, test_dir: Path) -> None:
    """Limits and Landlock, before any thread starts."""
    from rtlab.course import sandbox
    threads = len(os.listdir("/proc/self/task")) if os.path.isdir("/proc/self/task") else 1
    if threads != 1:
        raise RuntimeError(f"{threads} threads before the sandbox: a Landlock domain would not bind them")
    sandbox.limit_process(job.get("memory_limit_mb"))
    policy = sandbox.FilePolicy(read=[*sandbox.system_read_paths(), *(Path(p) for p in job["read"])],
                                write=[test_dir], write_files=[Path("/dev/null")])
    sandbox.apply_landlock(policy)


def _load(test_dir: Path) -> tuple[dict, dict]:
    import pickle
    job = json.loads((test_dir / "job.json").read_text())
    with open(test_dir / "inputs.pkl", "rb") as f:       # made by the grader, not by submitted code
        inputs = pickle.load(f)
    return job, inputs


def _setup(job: dict, inputs: dict, backend):
    from rtlab.device.device_scene import use_host_scene_data
    from rtlab.course import checks
    from rtlab.course.config import TestSpec
    spec = TestSpec.from_dict(job["spec"])
    kind = checks.KINDS[spec.kind]
    if inputs.get("host") is not None:
        use_host_scene_data(inputs["host"])
    inputs["step"] = job["step"]
    return spec, kind, kind.setup(spec, inputs, backend, bool(job.get("count_work")))


def _produce(kind, state, request: dict, backend, launched=None) -> None:
    t0 = time.perf_counter()
    out = kind.produce(state, {**request, "emit": lambda arrays: _send({"event": "work"}, arrays)})
    info = {**out.info, "device": backend.device_name, "language": backend.language,
            "produce_s": time.perf_counter() - t0}
    launched = {p["path"]: p["kernels"] for p in launched or []}
    _send({"event": "result", "status": "ok", "info": info, "launched": launched}, out.arrays)


def _commands():
    for line in sys.stdin:
        line = line.strip()
        if line:
            yield json.loads(line)


def test_main(test_dir: Path) -> int:
    job = json.loads((test_dir / "job.json").read_text())
    if job.get("sandbox", True):
        _confine(job, test_dir)
    job, inputs = _load(test_dir)
    from rtlab.backends import get_backend
    from rtlab.errors import KernelBuildError
    from rtlab.course import checks
    from rtlab.course import sandbox
    from rtlab.paths import kernel_dir
    backend = get_backend(job["backend"], job.get("device"))
    recorder = Recorder([kernel_dir(), checks.HARNESS_DIR] if job.get("check_includes", True) else None,
                        job.get("lab_calls") if job.get("check_includes", True) else None,
                        job.get("structure") if job.get("check_includes", True) else None,
                        job.get("runtime_macros") or ())
    recorder.wrap(backend)
    checks.on_setup_compile(recorder.tick)
    try:
        spec, kind, state = _setup(job, inputs, backend)
    except KernelBuildError as e:
        _error("compile_error", str(e))
        return 0
    except MemoryError as e:
        _error("memory", str(e))
        return 0
    if job.get("sandbox", True):
        if hasattr(backend, "prebuild_for_sandbox"):
            backend.prebuild_for_sandbox()
        recorder.closed = True
        sandbox.install_syscall_filter()
    _send({"event": "ready"})
    try:
        if job.get("mode") == "serve":
            for cmd in _commands():
                if cmd.get("op") != "produce":
                    break
                _produce(kind, state, cmd.get("request") or {}, backend, recorder.programs)
        else:
            next(_commands(), None)      # the grader's go, once it has taken the fresh binaries
            _produce(kind, state, {}, backend, recorder.programs)
    except KernelBuildError as e:
        _error("compile_error", str(e))
    return 0


def reference_main() -> int:
    """The reference worker: setup and produce commands for any test, on this installation's kernels."""
    from rtlab.backends import get_backend
    from rtlab.errors import KernelBuildError
    from rtlab.course import sandbox
    sandbox.make_undumpable()
    tests: dict[str, tuple] = {}
    backends: dict = {}
    for cmd in _commands():
        op, name = cmd.get("op"), cmd.get("test", "")
        try:
            if op == "setup":
                job, inputs = _load(Path(cmd["dir"]))
                key = (job["backend"], job.get("device"))
                if key not in backends:
                    backends[key] = get_backend(*key)
                spec, kind, state = _setup(job, inputs, backends[key])
                if hasattr(backends[key], "prebuild_for_sandbox"):
                    backends[key].prebuild_for_sandbox()     # launch the binaries a test process launches
                tests[name] = (kind, state, backends[key])
                _send({"event": "ready", "test": name})
            elif op == "produce":
                kind, state, backend = tests[name]
                _produce(kind, state, cmd.get("request") or {}, backend)
            else:
                break
        except KernelBuildError as e:
            _error("compile_error", f"the reference kernel does not build (a grader problem): {e}")
        except Exception as e:
            _error("error", f"the reference worker failed (a grader problem): {type(e).__name__}: {e}")
    return 0


def main(argv: list[str]) -> int:
    # What rtlab reads or sets up on first use happens here, before the sandbox closes: the kernels'
    # constants come from a file in the grader's folder ($RTLAB_KERNEL_CONSTANTS), and the cache
    # folder is chosen and made (rtlab.paths.prepare_process)
    from rtlab.kernel_constants import kernel_constants
    from rtlab.paths import prepare_process
    prepare_process()
    kernel_constants()
    if argv[:1] == ["--reference"]:
        return reference_main()
    return test_main(Path(argv[0]))


if __name__ == "__main__":
    try:
        sys.exit(main(sys.argv[1:]))
    except MemoryError:
        traceback.print_exc()
        print("rtlab: out of memory (MemoryError)", file=sys.stderr)
        sys.exit(4)
    except Exception:
        traceback.print_exc()
        try:
            _error("error", traceback.format_exc(limit=3)[-2000:])
        except Exception:
            pass
        sys.exit(3)
