"""What a grading test process may reach once it runs submitted code: the OS-level boundary.

On PoCL a student's kernel is native code in the process that launches it, so text rules on the
source are no boundary: what the process holds and may do is (rtlab.course.grader keeps the expected
answers, the secret and the reference out of it). Four layers, each applied by the process itself
(rtlab.course.run_test) or by the grader when it starts it:

* **User.** A grader running as root starts each test process as an unprivileged user
  (:func:`sandbox_user`: ``$RTLAB_SANDBOX_USER``, else ``rtlab-sandbox`` when the bundle's setup.sh
  made it, else ``nobody``); the reference kernels, the secret and the grader's folders are root's.
  Where that user cannot run the grader's Python (a pyenv under /root), the process keeps uid 0
  with every capability dropped, and Landlock alone keeps it from the grader's files.
* **Files (Landlock).** From its first line, before any thread exists (a Landlock domain binds the
  threads started after it), the process may read the Python installation, rtlab's package (not the
  checkout's kernels/ or labs/), the submission's compile tree and the system's libraries and
  compilers, and write only its scratch folder (and /dev/null). No TCP, and on kernels with Landlock
  ABI 6, no signals or abstract sockets outside its domain. :func:`landlock_abi` says what the
  running kernel has; where it has none, the user is the file boundary (README says so).
* **System calls (seccomp).** After its kernels are built (PoCL starts the system linker while it
  builds) and before the first launch of student code, :func:`install_syscall_filter` kills the
  process on any attempt to start a program or a process, open a socket, trace or signal another
  process, or use the kernel's less common interfaces (io_uring, bpf, namespaces...). The filter
  is synchronised to every thread (PoCL's worker pool exists by then: libseccomp's TSYNC).
* **Limits.** Memory (RLIMIT_DATA), file size, no core dumps, ``no_new_privs``, not dumpable (no
  other process of the same user may read its memory or trace it).

PoCL's first launch of a kernel at a work-group size normally links a specialised work-group
function with ``/usr/bin/ld``: the test process asks PoCL for every kernel's binaries while it may
still start the linker (``POCL_BINARY_SPECIALIZE_WG`` for the sizes it will launch), and launches
at any other size run PoCL's generic work-group function (rtlab.backends.opencl).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import pwd
import resource
import sys
from dataclasses import dataclass, field
from pathlib import Path

from .. import settings

# The environment variable that turns the sandbox off (debugging the grader itself, never grading)
SANDBOX_OFF_ENV = "RTLAB_GRADER_SANDBOX"
SANDBOX_USER_ENV = "RTLAB_SANDBOX_USER"
DEFAULT_USERS = ("rtlab-sandbox", "nobody")
FILE_LIMIT = 64 * 2 ** 20      # bytes a test process may write to one file (a kernel printing without end)

_libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
_libc.syscall.restype = ctypes.c_long
PR_SET_DUMPABLE = 4
PR_SET_NO_NEW_PRIVS = 38


def sandbox_enabled() -> bool:
    return settings.get(SANDBOX_OFF_ENV) is None or settings.flag(SANDBOX_OFF_ENV)


# --------------------------------------------------------------------------------------------------
# the user
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SandboxUser:
    name: str
    uid: int
    gid: int


def sandbox_user(env: dict | None = None) -> SandboxUser | None:
    """The unprivileged user test processes run as when the grader is root and that user can run
    this Python (its interpreter, numpy, pyopencl and rtlab readable to it); None otherwise: a
    grader that is not root keeps its own user, and a root grader whose Python lives where others
    cannot read it (a pyenv under /root) keeps uid 0 but drops every capability in the test process
    (:func:`drop_root_powers`), Landlock then being what keeps it from the grader's files."""
    if os.geteuid() != 0:
        return None
    wanted = settings.get(SANDBOX_USER_ENV)
    for name in ([wanted] if wanted else DEFAULT_USERS):
        try:
            pw = pwd.getpwnam(name)
        except KeyError:
            continue
        if pw.pw_uid != 0 and _can_run_python(pw.pw_uid, pw.pw_gid, env or {}):
            return SandboxUser(name, pw.pw_uid, pw.pw_gid)
    return None


_runs_python: dict = {}


def _can_run_python(uid: int, gid: int, env: dict) -> bool:
    """Whether ``uid`` can start this Python and import what a test process imports (``env``: the
    test process's own settings), tried once a user."""
    import subprocess
    if uid not in _runs_python:
        try:
            r = subprocess.run([sys.executable, "-c", "import numpy, pyopencl, pyseccomp, rtlab.course.run_test"],
                               user=uid, group=gid, extra_groups=[], cwd="/", capture_output=True, timeout=60,
                               env={"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": "/",
                                    "PYTHONDONTWRITEBYTECODE": "1", "OPENBLAS_NUM_THREADS": "1",
                                    **{k: os.environ[k] for k in ("PYTHONPATH",) if k in os.environ}, **env})
            _runs_python[uid] = r.returncode == 0
        except (OSError, subprocess.SubprocessError):
            _runs_python[uid] = False
    return _runs_python[uid]


CAP_LAST = 63
PR_CAPBSET_DROP, PR_SET_SECUREBITS = 24, 28
SECBIT_NOROOT, SECBIT_NOROOT_LOCKED, SECBIT_NO_SETUID_FIXUP, SECBIT_NO_SETUID_FIXUP_LOCKED = 1, 2, 4, 8
SECBIT_KEEP_CAPS_LOCKED, SECBIT_NO_CAP_AMBIENT_RAISE, SECBIT_NO_CAP_AMBIENT_RAISE_LOCKED = 32, 64, 128


class _CapHeader(ctypes.Structure):
    _fields_ = [("version", ctypes.c_uint32), ("pid", ctypes.c_int)]


class _CapData(ctypes.Structure):
    _fields_ = [("effective", ctypes.c_uint32), ("permitted", ctypes.c_uint32), ("inheritable", ctypes.c_uint32)]


def drop_root_powers() -> None:
    """A process of uid 0 keeps none of root's powers: no capability now or after an exec (bounding
    set cleared, securebits locked: root gains nothing from exec), so files are reached only through
    their owner bits, and Landlock decides which."""
    for cap in range(CAP_LAST + 1):
        _libc.prctl(PR_CAPBSET_DROP, cap, 0, 0, 0)
    bits = (SECBIT_NOROOT | SECBIT_NOROOT_LOCKED | SECBIT_NO_SETUID_FIXUP | SECBIT_NO_SETUID_FIXUP_LOCKED
            | SECBIT_KEEP_CAPS_LOCKED | SECBIT_NO_CAP_AMBIENT_RAISE | SECBIT_NO_CAP_AMBIENT_RAISE_LOCKED)
    if _libc.prctl(PR_SET_SECUREBITS, bits, 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_SECUREBITS) failed")
    header = _CapHeader(0x20080522, 0)          # _LINUX_CAPABILITY_VERSION_3
    data = (_CapData * 2)()
    if _libc.capset(ctypes.byref(header), data) != 0:
        raise OSError(ctypes.get_errno(), "capset failed")


def give_to(path: Path, user: SandboxUser | None, mode: int = 0o700) -> None:
    """Make a folder the test process's own (its scratch)."""
    path.mkdir(parents=True, exist_ok=True)
    if user is not None:
        os.chown(path, user.uid, user.gid)
    os.chmod(path, mode)


# --------------------------------------------------------------------------------------------------
# limits
# --------------------------------------------------------------------------------------------------
def limit_process(memory_mb: int | None) -> None:
    """Memory (RLIMIT_DATA: the heap and private writable mappings, what a compiler stuck on a
    preprocessor bomb grows; unlike RLIMIT_AS it does not count what PoCL and LLVM reserve without
    using), file size, no core dumps, no_new_privs, not dumpable; uid 0 loses root's powers."""
    if os.geteuid() == 0:
        drop_root_powers()
    if memory_mb:
        limit = int(memory_mb) * 2 ** 20
        resource.setrlimit(resource.RLIMIT_DATA, (limit, limit))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    resource.setrlimit(resource.RLIMIT_FSIZE, (FILE_LIMIT, FILE_LIMIT))
    if _libc.prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_NO_NEW_PRIVS) failed")
    _libc.prctl(PR_SET_DUMPABLE, 0, 0, 0, 0)


def make_undumpable() -> None:
    """No process of the same user may trace this one or read its memory (/proc/PID/mem): the
    grader and the reference worker call this, they hold what a test process must not see."""
    _libc.prctl(PR_SET_DUMPABLE, 0, 0, 0, 0)


# --------------------------------------------------------------------------------------------------
# Landlock (files, TCP, signals)
# --------------------------------------------------------------------------------------------------
SYS_LANDLOCK_CREATE_RULESET, SYS_LANDLOCK_ADD_RULE, SYS_LANDLOCK_RESTRICT_SELF = 444, 445, 446
LANDLOCK_CREATE_RULESET_VERSION = 1
LANDLOCK_RULE_PATH_BENEATH = 1
FS_EXECUTE, FS_WRITE_FILE, FS_READ_FILE, FS_READ_DIR = 1 << 0, 1 << 1, 1 << 2, 1 << 3
FS_REMOVE_DIR, FS_REMOVE_FILE, FS_MAKE_CHAR, FS_MAKE_DIR = 1 << 4, 1 << 5, 1 << 6, 1 << 7
FS_MAKE_REG, FS_MAKE_SOCK, FS_MAKE_FIFO, FS_MAKE_BLOCK, FS_MAKE_SYM = 1 << 8, 1 << 9, 1 << 10, 1 << 11, 1 << 12
FS_REFER, FS_TRUNCATE, FS_IOCTL_DEV = 1 << 13, 1 << 14, 1 << 15
NET_BIND_TCP, NET_CONNECT_TCP = 1 << 0, 1 << 1
SCOPE_ABSTRACT_UNIX_SOCKET, SCOPE_SIGNAL = 1 << 0, 1 << 1
FILE_RIGHTS = FS_EXECUTE | FS_WRITE_FILE | FS_READ_FILE | FS_TRUNCATE | FS_IOCTL_DEV   # rights a rule on a file may name


def _fs_rights(abi: int) -> int:
    rights = (1 << 13) - 1
    if abi >= 2:
        rights |= FS_REFER
    if abi >= 3:
        rights |= FS_TRUNCATE
    if abi >= 5:
        rights |= FS_IOCTL_DEV
    return rights


READ = FS_READ_FILE | FS_READ_DIR | FS_EXECUTE


class _RulesetAttr(ctypes.Structure):
    _fields_ = [("handled_access_fs", ctypes.c_uint64), ("handled_access_net", ctypes.c_uint64),
                ("scoped", ctypes.c_uint64)]


class _PathBeneathAttr(ctypes.Structure):
    _pack_ = 1
    _fields_ = [("allowed_access", ctypes.c_uint64), ("parent_fd", ctypes.c_int32)]


def landlock_abi() -> int:
    """The running kernel's Landlock ABI version; 0 when it has none (or it is disabled)."""
    if not sys.platform.startswith("linux"):
        return 0
    v = _libc.syscall(SYS_LANDLOCK_CREATE_RULESET, None, ctypes.c_size_t(0),
                      ctypes.c_uint32(LANDLOCK_CREATE_RULESET_VERSION))
    return max(0, int(v))


@dataclass
class FilePolicy:
    """What a test process may open: folders (and files) to read, to write, and files to write
    though they lie in a read-only tree (/dev/null)."""
    read: list[Path] = field(default_factory=list)
    write: list[Path] = field(default_factory=list)
    write_files: list[Path] = field(default_factory=list)


# /etc's secrets: the password hashes, sudo's rules, host keys and private keys. A test process kept at
# uid 0 without capabilities (where the sandbox user cannot run the grader's Python) owns them, so the
# Landlock rules, which can only allow, name every other entry of /etc instead of /etc itself.
ETC_SECRETS = frozenset({"shadow", "shadow-", "gshadow", "gshadow-", "sudoers", "sudoers.d", "ssh", "ssl", "pki",
                         "security", "krb5.keytab", "credstore", "credstore.encrypted", "letsencrypt", "polkit-1"})


def etc_read_paths(etc: Path = Path("/etc")) -> list[Path]:
    """Every entry of /etc but its secrets (ETC_SECRETS)."""
    names = sorted(os.listdir(etc)) if etc.is_dir() else []
    return [etc / name for name in names if name not in ETC_SECRETS]


def system_read_paths() -> list[Path]:
    """What any Python process with PoCL, the CUDA compiler and the system linker reads: the
    system's folders, the Python installation (prefixes and sys.path entries other than a project
    checkout), rtlab's own package."""
    from ..paths import PACKAGE_DIR, PROJECT_DIR
    paths = [Path(p) for p in ("/usr", "/lib", "/lib32", "/lib64", "/bin", "/sbin", "/proc", "/sys", "/dev", "/opt")]
    paths += etc_read_paths()
    paths += [Path(p) for p in {sys.prefix, sys.base_prefix, sys.exec_prefix, sys.base_exec_prefix}]
    for entry in sys.path:
        p = Path(entry or ".").resolve()
        # a checkout on sys.path (PYTHONPATH=., python -m from it): its package only, never kernels/
        if p == PROJECT_DIR.resolve() or (p / "kernels" / "shared").is_dir():
            continue
        paths.append(p)
    paths.append(PACKAGE_DIR)
    cuda = os.environ.get("CUDA_HOME") or os.environ.get("CUDA_PATH")
    if cuda:
        paths.append(Path(cuda))
    return paths


def apply_landlock(policy: FilePolicy) -> int:
    """Restrict this process (its calling thread and every thread started later: call it before any
    starts) to ``policy``; returns the ABI used, 0 when the kernel has no Landlock."""
    abi = landlock_abi()
    if abi <= 0:
        return 0
    fs = _fs_rights(abi)
    attr = _RulesetAttr(fs, NET_BIND_TCP | NET_CONNECT_TCP if abi >= 4 else 0,
                        SCOPE_ABSTRACT_UNIX_SOCKET | SCOPE_SIGNAL if abi >= 6 else 0)
    size = 8 if abi < 4 else 16 if abi < 6 else 24
    ruleset = _libc.syscall(SYS_LANDLOCK_CREATE_RULESET, ctypes.byref(attr), ctypes.c_size_t(size),
                            ctypes.c_uint32(0))
    if ruleset < 0:
        raise OSError(ctypes.get_errno(), "landlock_create_ruleset failed")
    try:
        def add(path: Path, rights: int) -> None:
            try:
                fd = os.open(path, os.O_PATH | os.O_CLOEXEC)
            except OSError:
                return                  # a folder this machine does not have
            try:
                if not os.path.isdir(path):
                    rights &= FILE_RIGHTS
                rule = _PathBeneathAttr(rights & fs, fd)
                if _libc.syscall(SYS_LANDLOCK_ADD_RULE, ctypes.c_int(ruleset), ctypes.c_int(LANDLOCK_RULE_PATH_BENEATH),
                                 ctypes.byref(rule), ctypes.c_uint32(0)) != 0:
                    raise OSError(ctypes.get_errno(), f"landlock_add_rule failed for {path}")
            finally:
                os.close(fd)

        for p in policy.read:
            add(p, READ)
        for p in policy.write:
            add(p, fs)
        for p in policy.write_files:
            add(p, FS_READ_FILE | FS_WRITE_FILE | FS_TRUNCATE)
        if _libc.prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_NO_NEW_PRIVS) failed")
        if _libc.syscall(SYS_LANDLOCK_RESTRICT_SELF, ctypes.c_int(ruleset), ctypes.c_uint32(0)) != 0:
            raise OSError(ctypes.get_errno(), "landlock_restrict_self failed")
    finally:
        os.close(ruleset)
    return abi


# --------------------------------------------------------------------------------------------------
# seccomp (system calls)
# --------------------------------------------------------------------------------------------------
CLONE_THREAD = 0x00010000
# Killed outright: starting programs or processes, networking, reaching other processes, and the
# kernel interfaces a ray tracer never needs (several bypass other filters: io_uring, bpf)
FORBIDDEN_SYSCALLS = (
    "execve", "execveat", "fork", "vfork", "ptrace", "process_vm_readv", "process_vm_writev", "tkill",
    "pidfd_open", "pidfd_getfd", "pidfd_send_signal", "kcmp",
    "socket", "socketpair", "connect", "bind", "listen", "accept", "accept4",
    "mount", "umount2", "pivot_root", "chroot", "unshare", "setns", "fsopen", "fsmount", "fsconfig", "move_mount",
    "open_tree", "mount_setattr",
    "setuid", "setgid", "setreuid", "setregid", "setresuid", "setresgid", "setgroups", "setfsuid", "setfsgid",
    "init_module", "finit_module", "delete_module", "kexec_load", "kexec_file_load", "reboot", "swapon", "swapoff",
    "bpf", "perf_event_open", "userfaultfd", "io_uring_setup", "io_uring_enter", "io_uring_register",
    "keyctl", "add_key", "request_key", "personality", "ioperm", "iopl", "acct", "quotactl", "syslog",
    "open_by_handle_at", "name_to_handle_at", "mknod", "mknodat", "fanotify_init", "lookup_dcookie",
    "uselib", "vhangup", "settimeofday", "clock_settime", "clock_adjtime", "adjtimex", "sethostname",
    "setdomainname")
# Signals only to itself (glibc's raise and abort send to their own process)
SELF_SIGNAL_SYSCALLS = ("kill", "tgkill", "rt_sigqueueinfo", "rt_tgsigqueueinfo")


def seccomp_available() -> str | None:
    """None when a filter can be installed here; else why not."""
    if not sys.platform.startswith("linux"):
        return "seccomp is Linux only"
    try:
        import pyseccomp  # noqa: F401
    except ImportError as e:
        return f"pyseccomp cannot be imported ({e}); `pip install pyseccomp` and libseccomp2"
    except RuntimeError as e:        # pyseccomp raises this when libseccomp is missing
        return f"{e} (install libseccomp2)"
    return None


def install_syscall_filter() -> None:
    """Kill this process (every thread: TSYNC) on any forbidden system call from now on."""
    import pyseccomp as sc
    f = sc.SyscallFilter(sc.ALLOW)
    f.set_attr(sc.Attr.CTL_TSYNC, 1)
    f.set_attr(sc.Attr.CTL_NNP, 1)
    try:
        f.set_attr(sc.Attr.CTL_OPTIMIZE, 2)      # a binary tree of rules: PoCL's threads make many futex calls
    except OSError:
        pass                                     # libseccomp < 2.5
    arch = sc.system_arch()
    for name in FORBIDDEN_SYSCALLS:
        try:
            sc.resolve_syscall(arch, name)
        except Exception:
            continue                         # not a system call on this architecture
        f.add_rule(sc.KILL_PROCESS, name)
    # clone: threads only; clone3 (whose flags sit in memory a filter cannot read) answers ENOSYS,
    # which makes glibc start threads with clone
    f.add_rule(sc.KILL_PROCESS, "clone", sc.Arg(0, sc.MASKED_EQ, CLONE_THREAD, 0))
    f.add_rule(sc.ERRNO(errno.ENOSYS), "clone3")
    me = os.getpid()
    for name in SELF_SIGNAL_SYSCALLS:
        f.add_rule(sc.KILL_PROCESS, name, sc.Arg(0, sc.NE, me))
    f.load()


SIGSYS_TEXT = ("stopped by the grader's sandbox: the process made a forbidden system call (starting a "
               "program or a process, a network connection, reaching another process). Kernels "
               "compute; they call nothing outside the process")


def describe(user: SandboxUser | None = None) -> str:
    """One line on what this machine's sandbox has (for `rtlab info` and the grading notes)."""
    abi = landlock_abi()
    why = seccomp_available()
    who = (f"user {user.name}" if user is not None else "uid 0 without capabilities" if os.geteuid() == 0
           else "the grader's own user (not root)")
    parts = [f"Landlock ABI {abi}" if abi else "no Landlock (files: the sandbox user's permissions only)",
             "seccomp filter" if why is None else f"no seccomp ({why})", who]
    return ", ".join(parts)


def problem(user: SandboxUser | None) -> str | None:
    """Why submitted code cannot be confined here, or None."""
    why = seccomp_available()
    if why:
        return why
    if os.geteuid() == 0 and user is None and landlock_abi() <= 0:
        return ("the grader runs as root, no unprivileged user can run its Python and the kernel has no Landlock: "
                "install rtlab in a Python other users can read (e.g. a venv from /usr/bin/python3) and create "
                "the user rtlab-sandbox (the bundle's setup.sh does both)")
    return None
