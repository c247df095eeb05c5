"""The grader's sandbox, tested from where an attack runs: inside a kernel on PoCL.

A kernel on PoCL is native code in the process that launches it. These tests run kernels that make
system calls directly (inline ``syscall``, which the submission rule would refuse: here the point is
what the process may do once code like that runs anyway) in a process confined exactly as a grading
test process is (rtlab.course.sandbox, rtlab.backends.opencl's prebuilt binaries), and check that
starting a program or a process, opening a socket, signalling or tracing another process end the
process (SIGSYS), that files outside its scratch folder can be neither read nor written, and that a
test process holds none of the expected answers in its memory. Adversarial submissions graded end
to end: an exhaustive tree walk (the work budget), wild pointer writes (a crash costs its test
only), includes of the reference behind a byte-order mark, two 1 MiB files of trigraphs.
"""
from __future__ import annotations

import json
import os
import platform
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rtlab.course import grade, load_config
from rtlab.course.channel import ChannelError, FrameReader, expect_arrays, write_frame
from rtlab.course.sandbox import landlock_abi, seccomp_available
from rtlab.paths import PROJECT_DIR

from .test_grading import materialize, reference_files

X86_64 = platform.machine() in ("x86_64", "AMD64")
needs_filter = pytest.mark.skipif(not X86_64 or seccomp_available() is not None,
                                  reason="inline syscalls are written for x86-64; the filter needs libseccomp")


def _pocl_available() -> bool:
    try:
        from rtlab.backends.opencl import list_devices
        return any("Portable" in p.name for _, _, p, _ in list_devices())
    except Exception:
        return False


needs_pocl = pytest.mark.skipif(not _pocl_available(), reason="PoCL (OpenCL on the CPU) is not installed")


# --------------------------------------------------------------------------------------------------
# the result channel
# --------------------------------------------------------------------------------------------------
def _frame(header: dict, arrays=None) -> bytes:
    r, w = os.pipe()
    write_frame(w, header, arrays)
    os.close(w)
    data = b""
    while chunk := os.read(r, 1 << 16):
        data += chunk
    os.close(r)
    return data


def _raw(header: bytes, payload: bytes = b"") -> bytes:
    return b"RTLB" + len(header).to_bytes(4, "little") + header + payload


def test_channel_takes_nothing_on_trust():
    """A frame round-trips; anything else a process writes is refused with what is wrong, before
    any array is made from it."""
    t = np.arange(5, dtype=np.float32)
    [(header, arrays)] = FrameReader().feed(_frame({"event": "result"}, {"t": t}))
    assert header == {"event": "result"} and np.array_equal(arrays["t"], t)
    bad = {
        "not a grader message": b"XXXX" + _frame({"event": "result"})[4:],
        "a message header of": b"RTLB" + (1 << 20).to_bytes(4, "little"),
        "not JSON": _raw(b"{{{"),
        "not a JSON object": _raw(b"[1, 2]"),
        "is not one of": _raw(b'{"arrays": [{"name": "t", "dtype": "|O", "shape": [1]}]}', b"x" * 8),
        "a shape must be": _raw(b'{"arrays": [{"name": "t", "dtype": "<f4", "shape": [-1]}]}'),
        "bytes of arrays": _raw(b'{"arrays": [{"name": "t", "dtype": "<f8", "shape": [4096, 4096]}]}'),
        "each once": _raw(b'{"arrays": [{"name": "t", "dtype": "<f4", "shape": [1]}, '
                          b'{"name": "t", "dtype": "<f4", "shape": [1]}]}', b"x" * 8),
    }
    for why, data in bad.items():
        with pytest.raises(ChannelError, match=why):
            FrameReader().feed(data)
    with pytest.raises(ChannelError, match="came back as float64"):
        expect_arrays({"t": t.astype(np.float64)}, {"t": (np.float32, (5,))})
    with pytest.raises(ChannelError, match="returned no 'tri'"):
        expect_arrays({"t": t}, {"tri": (np.int32, (5,))})


# --------------------------------------------------------------------------------------------------
# system calls from inside a running kernel
# --------------------------------------------------------------------------------------------------
SYSCALL_KERNEL = r"""
/* One system call from inside a kernel, as submitted code that got past any text rule would make
 * it: x86-64's syscall instruction. Strings come in s0..s2; argv points at them. */
__kernel void do_syscall(__global long *out, __global long *argv, long nr, long a0, long a1, long a2,
                         __global const char *s0, __global const char *s1, __global const char *s2)
{
    argv[0] = (long)s0; argv[1] = (long)s1; argv[2] = (long)s2; argv[3] = 0;
    long x0 = a0 == -1 ? (long)s0 : a0;
    long x1 = a1 == -1 ? (long)s1 : a1 == -2 ? (long)argv : a1;
    long x2 = a2;
    long r;
    __asm__ volatile ("syscall" : "=a"(r) : "a"(nr), "D"(x0), "S"(x1), "d"(x2) : "rcx", "r11", "memory");
    out[0] = r;
}
"""

RUNNER = r"""
import json, os, sys
from pathlib import Path
scratch = Path(sys.argv[1])
nr, a0, a1, a2 = (int(x) for x in sys.argv[2:6])
strings = sys.argv[6:9]
from rtlab.course import sandbox
sandbox.limit_process(2048)
sandbox.apply_landlock(sandbox.FilePolicy(read=[*sandbox.system_read_paths(), scratch], write=[scratch],
                                          write_files=[Path("/dev/null")]))
os.environ["POCL_CACHE_DIR"] = str(scratch / "pocl")
import numpy as np
from rtlab.backends.opencl import OpenCLBackend
backend = OpenCLBackend("cpu")
program = backend.compile(scratch / "do_syscall.cl", {})
backend.prebuild_for_sandbox()
sandbox.install_syscall_filter()
out, argv = backend.empty(8), backend.empty(32)
bufs = [backend.to_device(np.frombuffer(s.encode() + b"\0", np.uint8)) for s in strings]
program.launch("do_syscall", (1,), (1,), [out, argv, np.int64(nr), np.int64(a0), np.int64(a1), np.int64(a2), *bufs])
print(json.dumps({"ret": int(backend.to_host(out, np.int64, 1)[0])}), flush=True)
"""

SYS_OPEN, SYS_SOCKET, SYS_FORK, SYS_EXECVE, SYS_KILL, SYS_PTRACE = 2, 41, 57, 59, 62, 101
O_WRONLY_CREAT = 0o1 | 0o100
EACCES = 13


def _kernel_syscall(tmp_path: Path, nr: int, a0=0, a1=0, a2=0, strings=("", "", "")):
    """Run the syscall kernel in a confined process (as the grader's test processes are); (returncode,
    the kernel's return value or None)."""
    scratch = tmp_path / "scratch"
    scratch.mkdir(exist_ok=True)
    (scratch / "do_syscall.cl").write_text(SYSCALL_KERNEL)
    (scratch / "runner.py").write_text(RUNNER)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONDONTWRITEBYTECODE="1", HOME=str(scratch),
               XDG_CACHE_HOME=str(scratch / "cache"))
    r = subprocess.run([sys.executable, str(scratch / "runner.py"), str(scratch), str(nr), str(a0), str(a1), str(a2),
                        *strings], capture_output=True, text=True, env=env, cwd=scratch, timeout=300)
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("{")]
    return r.returncode, (json.loads(lines[-1])["ret"] if lines else None), r.stderr


@needs_pocl
@needs_filter
@pytest.mark.parametrize("case", ["execve", "fork", "socket", "kill_parent", "ptrace_parent"])
def test_forbidden_system_call_from_a_kernel_kills_the_process(case, tmp_path):
    """Starting a program (the shell a return-oriented chain reaches through libc's system()), a
    process, a socket, or reaching the grader's process: the filter, synchronised to PoCL's worker
    threads that run the kernel, kills the whole process; the program never runs."""
    marker = tmp_path / "scratch" / "ran"
    calls = {"execve": (SYS_EXECVE, -1, -2, 0, ("/usr/bin/touch", str(marker), "")),
             "fork": (SYS_FORK, 0, 0, 0, ("", "", "")),
             "socket": (SYS_SOCKET, 2, 1, 0, ("", "", "")),
             "kill_parent": (SYS_KILL, os.getpid(), 0, 0, ("", "", "")),
             "ptrace_parent": (SYS_PTRACE, 16, os.getpid(), 0, ("", "", ""))}
    nr, a0, a1, a2, strings = calls[case]
    rc, ret, err = _kernel_syscall(tmp_path, nr, a0, a1, a2, strings)
    assert rc == -signal.SIGSYS, (rc, ret, err[-2000:])
    assert not marker.exists()


@needs_pocl
@needs_filter
def test_kernel_reaches_no_file_outside_its_scratch(tmp_path):
    """Landlock (from the process's first line, so every PoCL thread is bound): a file beside the
    scratch folder, as the grading secret and the reference kernels lie beside a test's folder,
    can be neither written nor read; the scratch folder can. Without Landlock, the permissions of
    the sandbox user are the boundary (README)."""
    if landlock_abi() <= 0:
        pytest.skip("this kernel has no Landlock")
    secret = tmp_path / "grading-secret"
    secret.write_text("s3cret")
    rc, ret, err = _kernel_syscall(tmp_path, SYS_OPEN, -1, 0, 0, (str(secret), "", ""))
    assert rc == 0 and ret == -EACCES, (rc, ret, err[-2000:])
    outside = tmp_path / "written"
    rc, ret, err = _kernel_syscall(tmp_path, SYS_OPEN, -1, O_WRONLY_CREAT, 0o644, (str(outside), "", ""))
    assert rc == 0 and ret == -EACCES and not outside.exists(), (rc, ret, err[-2000:])
    inside = tmp_path / "scratch" / "mine"
    rc, ret, err = _kernel_syscall(tmp_path, SYS_OPEN, -1, O_WRONLY_CREAT, 0o644, (str(inside), "", ""))
    assert rc == 0 and ret >= 0 and inside.exists(), (rc, ret, err[-2000:])
    # /etc's secrets stay out of reach even where the process keeps uid 0 (their owner); the rest of
    # /etc is read as before
    rc, ret, err = _kernel_syscall(tmp_path, SYS_OPEN, -1, 0, 0, ("/etc/passwd", "", ""))
    assert rc == 0 and ret >= 0, (rc, ret, err[-2000:])
    if os.path.exists("/etc/shadow"):
        rc, ret, err = _kernel_syscall(tmp_path, SYS_OPEN, -1, 0, 0, ("/etc/shadow", "", ""))
        assert rc == 0 and ret == -EACCES, (rc, ret, err[-2000:])


# --------------------------------------------------------------------------------------------------
# what a test process holds
# --------------------------------------------------------------------------------------------------
def _memory_regions(pid: int):
    with open(f"/proc/{pid}/maps") as f:
        for line in f:
            parts = line.split()
            lo, hi = (int(x, 16) for x in parts[0].split("-"))
            name = parts[5] if len(parts) > 5 else ""
            if "r" in parts[1] and name not in ("[vvar]", "[vsyscall]", "[vvar_vclock]"):
                yield lo, hi


def _memory_holds(pid: int, patterns: dict[str, bytes]) -> set[str]:
    """Names of the patterns found anywhere in process ``pid``'s readable memory."""
    found = set()
    fd = os.open(f"/proc/{pid}/mem", os.O_RDONLY)
    try:
        for lo, hi in _memory_regions(pid):
            at = lo
            while at < hi:
                n = min(hi - at, 1 << 24)
                try:
                    chunk = os.pread(fd, n + 256, at) if at + n < hi else os.pread(fd, n, at)
                except OSError:
                    break
                found |= {k for k, p in patterns.items() if p in chunk}
                at += n
    finally:
        os.close(fd)
    return found


def _answer_patterns(prepared) -> dict[str, bytes]:
    """Byte runs of the expected answers as the float64 reference made them and as a kernel returns them."""
    ref = prepared.expected["ref"]
    hit = np.flatnonzero(ref.tri >= 0)
    run = hit[:8] if len(hit) >= 8 else hit
    start = int(run[0])
    return {"t as float64": ref.t[start:start + 8].astype(np.float64).tobytes(),
            "tri as int64": ref.tri[start:start + 8].astype(np.int64).tobytes(),
            "t as float32": ref.t[start:start + 16].astype(np.float32).tobytes(),
            "tri as int32": ref.tri[start:start + 16].astype(np.int32).tobytes()}


@needs_pocl
@needs_filter
@pytest.mark.skipif(os.geteuid() != 0, reason="reading another process's memory needs root (the CI runs as root)")
def test_test_process_holds_no_expected_answer(tmp_path):
    """A test process, sandbox closed and kernels built, the instant before it runs the submission:
    none of the reference's answers anywhere in its memory (searched byte for byte through
    /proc/PID/mem), though its inputs are there; the same search finds the answers in the grader."""
    from rtlab.course.fixtures import prepare_test, spec_for_run
    from rtlab.course.grader import GradingRun
    from rtlab.course.processes import TestProcess
    config = load_config("00_primary")
    spec = config.test("trace_random_rays")
    run = GradingRun(config, PROJECT_DIR, [spec], "opencl", None, 1, 1.0, "x" * 32, 120.0, None, None)
    from rtlab.course.kernel_sources import build_student_tree
    run.tree = build_student_tree(config, PROJECT_DIR, run.work / "submission")
    prepared = prepare_test(spec_for_run(spec, run.secret))
    patterns = _answer_patterns(prepared)
    patterns["the rays (inputs)"] = prepared.inputs["origins"][5:9].tobytes()
    assert _memory_holds(os.getpid(), {k: v for k, v in patterns.items() if "64" in k}) == \
        {"t as float64", "tri as int64"}, "the search must find the answers where they are"
    d = run.test_dir(spec, prepared, run.job(spec, mode="serve", count_work=True))
    proc = TestProcess(d, run.start_env(d), run.limits(spec), run.user, sandboxed=True)
    try:
        proc.wait_for(("ready",), None)
        found = _memory_holds(proc.proc.pid, patterns)
    finally:
        proc.kill()
        proc.close()
        import shutil
        shutil.rmtree(run.work, ignore_errors=True)
    assert found == {"the rays (inputs)"}, found


# --------------------------------------------------------------------------------------------------
# adversarial submissions, graded
# --------------------------------------------------------------------------------------------------
@needs_pocl
def test_exhaustive_walk_fails_every_work_budget(tmp_path):
    """A traversal that visits every node and tests every leaf returns exact hits; it reads many
    times the tree the reference kernel reads on the same rays and fails every correctness test
    that walks the scene, stopped as soon as its count on the test's first rays is in (the camera
    test, which walks nothing, still passes)."""
    sub = materialize("exhaustive_walk", tmp_path / "sub")
    report = grade("00_primary", sub, tests=["camera_rays", "trace_random_rays", "render_default"])
    assert report.test("camera_rays").passed
    for name in ("trace_random_rays", "render_default"):
        t = report.test(name)
        assert t.score == 0 and "as much of the tree" in t.output and "brute force" in t.output, (name, t.output)
        work, ref = t.data["work"], t.data["reference_work"]
        assert work[0] > 4 * ref[0], (work, ref)


@needs_pocl
def test_wild_pointer_writes_cost_their_own_tests_only(tmp_path):
    """A kernel writing over its process's stack and heap (what a return-oriented chain does): its
    tests crash or fail and score 0; every other test runs in its own process and scores as before."""
    sub = materialize("wild_pointers", tmp_path / "sub")
    report = grade("00_primary", sub, tests=["camera_rays", "trace_random_rays", "render_default"])
    assert report.test("camera_rays").score == report.test("camera_rays").max_score
    for name in ("trace_random_rays", "render_default"):
        t = report.test(name)
        assert t.score == 0 and t.status in ("crashed", "failed", "error"), (name, t.status, t.output)


@needs_pocl
def test_byte_order_mark_hides_no_include(tmp_path):
    """Each of lab 03's files as one line, `#include "<the reference header's absolute path>"`,
    behind a UTF-8 byte-order mark (clang skips it; the old rule's lexer read the directive as
    text: 100 / 100): every file is refused at line 1, every test scores 0 and names the file."""
    config = load_config("03_traversal")
    sub = tmp_path / "sub"
    for lf in config.files:
        dst = sub / lf.path
        dst.parent.mkdir(parents=True, exist_ok=True)
        dst.write_bytes(b"\xef\xbb\xbf" + f'#include "{PROJECT_DIR / lf.path}"\n'.encode())
    report = grade("03_traversal", sub, tests=["compile", "trace_restart", "trace_bvh"])
    assert report.score == 0
    for t in report.tests:
        assert t.status == "refused" and ":1: #include" in t.output and "names a path" in t.output, t.output


def test_preprocessor_lists_what_the_lexer_might_miss(tmp_path):
    """The preprocessor's own dependency list is the include check's source of truth: a byte-order
    mark, an include built by a macro, a line splice: each file it opens outside the tree is named."""
    from rtlab.course.deps import find_clang, outside_includes
    if find_clang() is None:
        pytest.skip("no clang on PATH")
    tree = tmp_path / "kernels" / "shared"
    tree.mkdir(parents=True)
    secret = tmp_path / "reference.h"
    secret.write_text("#define ANSWER 42\n")
    (tree / "bom.h").write_bytes(b"\xef\xbb\xbf" + f'#include "{secret}"\n'.encode())
    (tree / "macro.h").write_text(f'#define WHERE "{secret}"\n#include WHERE\n')
    (tree / "splice.h").write_text(f'#inc\\\nlude "{secret}"\n')
    for name in ("bom.h", "macro.h", "splice.h"):
        src = tmp_path / f"k_{name}.cl"
        src.write_text(f'#include "{name}"\n__kernel void k(void) {{}}\n')
        assert outside_includes(src, [tree], {}, "opencl", [tree.parent, src]) == [str(secret)], name
    ok = tmp_path / "ok.cl"
    ok.write_text('#include "bom.h"\n')
    (tree / "bom.h").write_bytes(b"\xef\xbb\xbf#define X 1\n")
    assert outside_includes(ok, [tree], {}, "opencl", [tree.parent, ok]) == []


@needs_pocl
def test_two_megabytes_of_trigraphs_are_graded_quickly(tmp_path):
    """Two 1 MiB files of ??= (the old lexer: 86 s each, quadratic; 2.25 GB; a 109 MB results.json):
    refused in seconds, with a bounded message and a results.json well under 1 MB."""
    from rtlab.cli import main
    sub = reference_files("03_traversal", tmp_path / "sub")
    for name in ("rt_kd_restart.h", "rt_kd_ropes.h"):
        (sub / "kernels/shared" / name).write_bytes((b"??=" * (1 << 19))[:1 << 20])
    out = tmp_path / "results.json"
    t0 = time.monotonic()
    assert main(["grade", "03_traversal", str(sub), "--tests", "compile,trace_restart,trace_ropes,trace_bvh",
                 "--format", "gradescope", "--out", str(out)]) == 0
    seconds = time.monotonic() - t0
    data = json.loads(out.read_text())
    assert out.stat().st_size < 100_000 and seconds < 60, (out.stat().st_size, seconds)
    by = {t["name"]: t for t in data["tests"]}
    assert by["trace_restart"]["score"] == 0 and "trigraph" in by["trace_restart"]["output"]
    assert by["trace_bvh"]["score"] == by["trace_bvh"]["max_score"]
    assert len(by["trace_restart"]["output"]) <= 8000


def test_lexer_reads_as_clang_does():
    """A leading byte-order mark is skipped (the first line's directive is a directive); any other
    byte above 127 outside comments and strings is refused with its line; attributes that run code
    when a binary loads are refused."""
    from rtlab.course.submission import check_source, tree_rules
    from rtlab.paths import REFERENCE_KERNEL_DIR
    rules = tree_rules(REFERENCE_KERNEL_DIR)
    rel = "kernels/shared/rt_kd_restart.h"
    bom = check_source("\xef\xbb\xbf#include \"/etc/passwd\"\n", rel, rules)
    assert [(r.line, "names a path" in r.reason) for r in bom] == [(1, True)]
    text = "int a; /* caf\xe9 */\nint b\xc2\xa0= 1;\n__attribute__((constructor)) void f(void) {}\n"
    problems = check_source(text, rel, rules)
    assert [(r.line, r.reason.split(" (")[0][:24]) for r in problems] == \
        [(2, "a byte outside ASCII out"), (3, "the attribute constructo")], problems


def test_conditionals_test_only_the_labs_macros():
    """A conditional on a macro only the runtime's compiler defines (PoCL's POCL_DEVICE_ADDRESS_BITS, a
    CPU's __AVX2__) hid a call to lab 00's traverse_kd_stack from the rules that read the code with
    clang beside the compile (67 / 100 for lab 03); the lab's own macros, those the file's reference
    tests and the file's own stay testable, and every reference file passes."""
    from rtlab.course.submission import check_source, tree_rules
    from rtlab.paths import REFERENCE_KERNEL_DIR
    rules = tree_rules(REFERENCE_KERNEL_DIR)
    rel = "kernels/shared/rt_kd_restart.h"
    text = (REFERENCE_KERNEL_DIR / "shared" / "rt_kd_restart.h").read_text()
    assert check_source(text, rel, rules) == []
    hidden = text.replace("/* BEGIN SOLUTION */", "/* BEGIN SOLUTION */\n#ifdef POCL_DEVICE_ADDRESS_BITS\n"
                          "    traverse_kd_stack(RT_SCENE_ARGS, scene_min, scene_max, ray, hit, any_hit);\n#endif\n"
                          "#if defined(__AVX2__) && RT_STACK_SIZE > 4\n#endif\n", 1)
    reasons = [p.reason for p in check_source(hidden, rel, rules)]
    for refused in ("#ifdef tests POCL_DEVICE_ADDRESS_BITS,", "#if tests __AVX2__,",
                    "POCL_DEVICE_ADDRESS_BITS is a name the compiler or the OpenCL runtime provides",
                    "__AVX2__ is a name the compiler or the OpenCL runtime provides"):
        assert any(r.startswith(refused) for r in reasons), (refused, reasons)
    # the languages' own keywords and the names the lab's kernels use stay allowed
    keywords = text.replace("/* BEGIN SOLUTION */", "/* BEGIN SOLUTION */\n    __private int k = 0; (void)k;\n", 1)
    assert check_source(keywords, rel, rules) == []
    stringized = text.replace("/* BEGIN SOLUTION */", "/* BEGIN SOLUTION */\n#define MY_STR(x) #x\n", 1)
    assert [p.reason.split(" (")[0] for p in check_source(stringized, rel, rules)] == ["the # operator"]
    from rtlab.course.deps import runtime_only_macros
    assert "LLVM_15_0" in runtime_only_macros() or not runtime_only_macros()     # PoCL's own (_kernel.h)
    for name in ("__CLANG_ATOMIC_LLONG_LOCK_FREE", "cl_khr_fp16", "HALF_MAX", "M_PI_H", "CLK_AVC_ME_INITIALIZE_INTEL",
                 "__builtin_constant_p", *(("LLVM_15_0", "CLANG_MAJOR") if runtime_only_macros() else ())):
        probe = text.replace("/* BEGIN SOLUTION */", f"/* BEGIN SOLUTION */\n    int k = {name}; (void)k;\n", 1)
        assert any(f"{name} is a name the compiler" in p.reason for p in check_source(probe, rel, rules)), name
    fine = text.replace("/* BEGIN SOLUTION */", "/* BEGIN SOLUTION */\n#define MY_DEPTH 3\n#if MY_DEPTH > 2 && "
                        "RT_STACK_SIZE > 4 && defined(RT_TRAVERSAL)\n#endif\n", 1)
    assert check_source(fine, rel, rules) == []


def test_student_wheel_holds_no_solution(tmp_path, monkeypatch):
    """`rtlab lab release --wheel`: the wheel a notebook server installs ships the release's stubbed
    kernels only; the same check finds every solution in the repository's kernels (what `pip install .`
    of the repository would ship). The release is named as a bare relative folder, which pip once read
    as a PyPI project of that name."""
    import zipfile
    from rtlab.course.release import build_wheel, wheel_solutions, write_release
    monkeypatch.chdir(tmp_path)
    release = write_release(Path("release"))
    wheel = build_wheel(Path("release"))
    assert wheel.name.startswith("rtlab-") and wheel.parent == (tmp_path / "release" / "dist")
    assert wheel_solutions(wheel) == [] and any("_data/kernels/shared/rt_kdtree.h" in n
                                                 for n in zipfile.ZipFile(wheel).namelist())
    repo = tmp_path / "repo.whl"
    with zipfile.ZipFile(repo, "w") as z:
        for f in sorted((PROJECT_DIR / "kernels").rglob("*.h")):
            z.write(f, f"rtlab/_data/kernels/{f.relative_to(PROJECT_DIR / 'kernels')}")
    assert any(s.endswith(": traverse_kd_stack") for s in wheel_solutions(repo))


def test_grader_reads_a_test_log_through_its_own_file(tmp_path):
    """A test process owns its folder: it can put a link to a secret where its log's name was. The
    grader quotes the log it opened, never what the name points to now."""
    from rtlab.course.processes import _log_tail
    secret = tmp_path / "grading-secret"
    secret.write_text("s3cret-value\n")
    log_path = tmp_path / "test" / "log.txt"
    log_path.parent.mkdir()
    with open(log_path, "w+b") as log:
        log.write(b"Traceback: the kernel's own words\n")
        log.flush()
        log_path.unlink()
        log_path.symlink_to(secret)
        tail = _log_tail(log)
    assert "the kernel's own words" in tail and "s3cret" not in tail
