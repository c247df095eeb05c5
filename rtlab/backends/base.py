"""The one small interface both backends implement.

A backend owns a device and a queue/stream. ``compile(path, defines)`` gives a :class:`Program`;
programs launch kernels with an explicit global size and block (work-group) shape and return the
device-event time of the launch; ``resources`` reports what the compiler gave the kernel.

Constant memory differs by API: CUDA kernels read ``__constant__`` symbols named ``c_<name>``,
OpenCL kernels take ``__constant`` pointer arguments, last, in the order the launch names them.
``Program.set_constant(name, array)`` and ``launch(..., constants=[names])`` hide that.
"""
from __future__ import annotations

import math
import os
import re
import sys
import tempfile
from abc import ABC, abstractmethod
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .. import settings
from ..errors import BackendError


# nvcc's division and square root at NVIDIA OpenCL's default precision (OpenCL C allows 2.5 ulp for
# x / y and 3 ulp for sqrt; NVIDIA's compiler emits div.full/rcp.approx/rsqrt.approx). nvcc's IEEE
# defaults add a slow-path branch per division (the trace kernel's SASS was twice OpenCL's length).
# Both GPU backends then compute the same bits, and the kernels' rounding bounds (RT_T_PAD in
# rt_intersect.h) already allow a reciprocal that is not correctly rounded. Every CUDA compile uses
# them: the backend's and the offline nvcc report's (rtlab.backends.nvcc).
CUDA_PRECISION_OPTIONS = ("--prec-div=false", "--prec-sqrt=false")


@dataclass
class KernelResources:
    """What the compiler gave a kernel, and the occupancy at a launch shape where known."""
    kernel: str
    backend: str
    registers: int | None = None          # CUDA registers per thread (NVIDIA OpenCL: from its build log)
    local_bytes: int | None = None        # CUDA local memory (stack) per thread / OpenCL private memory
    shared_bytes: int | None = None       # CUDA shared memory / OpenCL local memory per block
    const_bytes: int | None = None        # CUDA constant memory used by the module
    spill_bytes: int | None = None        # spill stores + loads (offline nvcc report only)
    max_block: int | None = None          # largest block/work-group the kernel can launch with
    block: tuple[int, ...] | None = None  # the launch shape occupancy refers to
    occupancy: float | None = None        # resident warps / maximum, 0..1 (CUDA)
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return asdict(self)


def round_up(n: int, m: int) -> int:
    return int(math.ceil(n / m) * m)


class Program(ABC):
    """A compiled kernel source with one define set."""

    def __init__(self, backend: "Backend", path: Path, defines: dict):
        self.backend = backend
        self.path = path
        self.defines = dict(defines)
        self._fitting_blocks: set = set()    # (kernel, block) shapes check_block passed

    def check_block(self, kernel: str, block: tuple[int, ...]) -> None:
        """The first step of every launch (both backends' ``launch``): a block the device cannot run
        is a BackendError naming its limit, before the launch fails with the API's bare
        INVALID_WORK_GROUP_SIZE (or CUDA's invalid value). Once per kernel and shape."""
        shape = (kernel, tuple(int(b) for b in block))
        if shape in self._fitting_blocks:
            return
        most, sizes = self.block_limits(kernel)
        threads = math.prod(shape[1])
        label = "x".join(map(str, shape[1]))
        where = f"{self.backend.device_name} ({self.backend.name})"
        if threads > most:
            raise BackendError(f"block {label} = {threads} work-items for {kernel}: {where} takes at most {most} "
                               f"a block (work-group); choose a smaller --block (Variant.block)")
        for axis, (b, limit) in enumerate(zip(shape[1], sizes)):
            if b > limit:
                raise BackendError(f"block {label} for {kernel}: {where} takes at most {limit} work-items along "
                                   f"{'xyz'[axis]}; choose a smaller --block (Variant.block)")
        self._fitting_blocks.add(shape)

    @abstractmethod
    def block_limits(self, kernel: str) -> tuple[int, tuple[int, ...]]:
        """(most threads a block of ``kernel`` may have, most along each of x, y, z) on this device."""

    @abstractmethod
    def set_constant(self, name: str, array: np.ndarray) -> None:
        """Upload ``array`` to the constant-memory item ``name`` (CUDA symbol ``c_<name>``)."""

    @abstractmethod
    def launch(self, kernel: str, global_size: tuple[int, ...], block: tuple[int, ...],
               args: list, constants: tuple[str, ...] = (), shared_bytes: int = 0) -> float:
        """Run ``kernel`` over ``global_size`` work items in blocks of ``block``; returns device ms.
        ``global_size`` is rounded up to whole blocks; kernels guard their own bounds.
        ``shared_bytes`` of dynamic shared memory a block (CUDA only) hold occupancy down without
        touching the kernel: the occupancy axis of the paper's Fig. 5."""

    @abstractmethod
    def resources(self, kernel: str, block: tuple[int, ...] | None = None) -> KernelResources:
        ...


@dataclass
class Texture:
    """A read-only texture (CUDA texture object) or image (OpenCL image1d_buffer) over a device
    buffer (§3.1.1). ``arg`` is what a kernel parameter of RT_SCENE_PARAMS takes; ``storage`` keeps
    the memory it reads alive (the buffer itself, or a padded copy)."""
    arg: object
    storage: object
    dtype: np.dtype
    channels: int
    count: int                    # elements of ``channels`` components each
    release: object = None        # callable freeing the handle (CUDA texture objects), or None

    def __del__(self):
        if self.release is not None:
            try:
                self.release()
            except Exception:  # interpreter shutdown: the driver may be gone already
                pass
            self.release = None


class Backend(ABC):
    name: str          # "opencl" or "cuda"
    language: str      # which kernel sources: "opencl" (.cl) or "cuda" (.cu)
    extension: str
    device_name: str
    platform_name: str

    @abstractmethod
    def compile(self, path: Path, defines: dict, options: tuple[str, ...] = ()) -> Program:
        """Build ``path`` with ``-D`` defines plus compiler ``options`` (rtlab.device.kernels.build_options:
        register caps); cached per (path, defines, options)."""

    def texture(self, buffer, dtype, channels: int, count: int) -> Texture:
        """A texture/image reading ``count`` elements of ``channels`` x ``dtype`` (int32 or float32;
        1, 2 or 4 channels) from ``buffer`` in place; the Texture holds a reference to the buffer."""
        raise NotImplementedError(f"{self.name} backend has no texture path")

    @abstractmethod
    def to_device(self, array: np.ndarray):
        """A read-only device copy of ``array`` (C-contiguous)."""

    @abstractmethod
    def empty(self, nbytes: int):
        """An uninitialised device buffer of ``nbytes`` (at least 1 byte)."""

    @abstractmethod
    def to_host(self, buffer, dtype, count: int) -> np.ndarray: ...

    @abstractmethod
    def fill(self, buffer, array: np.ndarray) -> None:
        """Copy ``array`` into an existing device buffer."""

    @abstractmethod
    def synchronize(self) -> None: ...

    @abstractmethod
    def is_gpu(self) -> bool: ...

    def has_warp_votes(self) -> bool:
        """Whether the kernels can count the threads of a warp (rt_port.h's rt_warp_active): CUDA, and
        NVIDIA's OpenCL through inline PTX; elsewhere the count is 1."""
        return False

    def describe(self) -> str:
        return f"{self.name}: {self.device_name} ({self.platform_name})"


def read_source(path) -> str:
    """A kernel source as text: UTF-8, or byte for byte as Latin-1 when it is not (a student's
    accented comment must not stop the build)."""
    data = Path(path).read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def verbose() -> bool:
    """Whether compiler output is shown: $RTLAB_VERBOSE set (and not 0), as `rtlab --verbose` sets it."""
    return settings.flag("RTLAB_VERBOSE")


@contextmanager
def captured_stderr():
    """What the process writes to file descriptor 2 inside the block, collected into the list it
    yields (one string, after the block). Compilers that run inside the process (PoCL's clang and
    LLVM) print their diagnostics there themselves ("1 warning generated."), past Python's
    sys.stderr; they belong in the build log, not on the user's terminal."""
    out: list[str] = []
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):        # no file descriptor 2 (an embedding host): nothing to catch
        yield out
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        _TERMINAL_FDS.append(saved)
        try:
            yield out
        finally:
            _TERMINAL_FDS.pop()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            out.append(tmp.read().decode(errors="replace"))


_TERMINAL_FDS: list[int] = []      # descriptor 2 as it was outside captured_stderr blocks


def terminal_stderr_fd() -> int:
    """The descriptor of the process's own stderr, even inside a captured_stderr block (a message that
    must reach the user as the process ends: rtlab.backends.waiting)."""
    return _TERMINAL_FDS[0] if _TERMINAL_FDS else 2


def report_build_log(path, defines: dict, log: str) -> None:
    """A successful build's compiler output (warnings, remarks) on stderr when verbose(); kept
    quiet otherwise. A failed build puts its log in the error instead (format_build_error)."""
    if log.strip() and verbose():
        defs = " ".join(f"-D{k}={v}" for k, v in sorted(defines.items()))
        print(f"rtlab: build log of {path} ({defs}):\n{log.rstrip()}", file=sys.stderr)


def format_build_error(path, defines: dict, log: str) -> str:
    """The compiler's error lines first (file:line: error ...), then the defines that were set."""
    lines = [ln for ln in log.splitlines() if ln.strip()]
    errors = [ln for ln in lines if re.search(r"error", ln, re.I)]
    shown = (errors or lines)[:12]
    defs = " ".join(f"-D{k}={v}" for k, v in sorted(defines.items()))
    return f"kernel {path} failed to compile (defines: {defs}):\n" + "\n".join("  " + ln for ln in shown)
