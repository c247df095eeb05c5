"""CUDA backend through pycuda (optional: ``pip install rtlab[cuda]``; needs a CUDA driver).

pycuda is imported only here, lazily, so every other part of rtlab works without it.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from .. import settings
from ..errors import BackendError, KernelBuildError
from ..paths import include_dirs, prepare_process
from .base import (CUDA_PRECISION_OPTIONS, Backend, KernelResources, Program, Texture, format_build_error, read_source,
                   report_build_log, round_up)
from .occupancy import SmLimits, cuda_occupancy
from .waiting import wait_for_kernel


def _pycuda():
    try:
        prepare_process()
        import pycuda.driver as drv
    except ImportError as e:
        raise BackendError(f"CUDA backend unavailable: pycuda is not installed ({e}); "
                           "`pip install 'rtlab[cuda]'` on a machine with nvcc and a CUDA driver") from None
    try:
        drv.init()
        if drv.Device.count() == 0:
            raise BackendError("CUDA backend unavailable: the CUDA driver sees no GPU")
    except drv.Error as e:
        raise BackendError(f"CUDA backend unavailable: no working CUDA driver ({e})") from None
    return drv


def list_devices() -> list[str]:
    drv = _pycuda()
    return [drv.Device(i).name() for i in range(drv.Device.count())]


def _arg_type(a) -> str:
    """pycuda's struct code of one kernel argument: device pointers, texture objects, scalars."""
    if isinstance(a, np.generic):
        return {np.dtype(np.int32): "i", np.dtype(np.uint32): "I", np.dtype(np.float32): "f",
                np.dtype(np.uint64): "Q", np.dtype(np.int64): "q"}[a.dtype]
    if isinstance(a, (int, float)):
        raise TypeError(f"kernel argument {a!r}: pass numpy scalars (np.int32, np.float32), not Python numbers")
    return "P"      # DeviceAllocation (or anything with an int() device address)


# A one-thread kernel that waits on the GPU's global timer: queued before a timed launch's start
# event, it keeps the device busy while the host queues the event and the kernel.
SPIN_SOURCE = r"""
extern "C" __global__ void rt_spin(unsigned long long ns)
{
    unsigned long long t0, t;
    asm volatile("mov.u64 %0, %%globaltimer;" : "=l"(t0));
    do {
        asm volatile("mov.u64 %0, %%globaltimer;" : "=l"(t));
    } while (t - t0 < ns);
}
"""
SPIN_NS = 50_000     # ≫ the host's time to record an event and queue a prepared launch (~10 µs)


class CudaProgram(Program):
    def __init__(self, backend: "CudaBackend", path: Path, defines: dict, module):
        super().__init__(backend, path, defines)
        self._module = module
        self._functions: dict = {}
        self._prepared: dict = {}
        self._constants: dict = {}

    def function(self, name: str):
        if name not in self._functions:
            self._functions[name] = self._module.get_function(name)
        return self._functions[name]

    def set_constant(self, name, array):
        """Upload to ``c_<name>``; a module that declares no such symbol does not read it: skipped."""
        drv = self.backend.drv
        data = np.ascontiguousarray(array).tobytes()
        if self._constants.get(name) == data:
            return
        try:
            ptr, size = self._module.get_global(f"c_{name}")
        except drv.LogicError:
            self._constants[name] = data
            return
        if len(data) > size:
            raise KernelBuildError(f"constant c_{name} holds {size} bytes, {len(data)} given "
                                   f"(raise RT_MAX_* for this scene)")
        drv.memcpy_htod(ptr, np.frombuffer(data, np.uint8))
        self._constants[name] = data

    def block_limits(self, kernel):
        drv, d = self.backend.drv, self.backend.cuda_device
        a = drv.device_attribute
        most = self.function(kernel).get_attribute(drv.function_attribute.MAX_THREADS_PER_BLOCK)
        axes = (a.MAX_BLOCK_DIM_X, a.MAX_BLOCK_DIM_Y, a.MAX_BLOCK_DIM_Z)
        return int(most), tuple(int(d.get_attribute(x)) for x in axes)

    def launch(self, kernel, global_size, block, args, constants=(), shared_bytes=0):
        self.check_block(kernel, block)
        drv = self.backend.drv
        block3 = tuple(block) + (1,) * (3 - len(block))
        grid = tuple(round_up(g, b) // b for g, b in zip(global_size, block))
        grid3 = grid + (1,) * (3 - len(grid))
        f = self.prepared(kernel, args)
        if shared_bytes > 48 * 1024:  # beyond 48 KiB a kernel must opt in
            f.set_attribute(drv.function_attribute.MAX_DYNAMIC_SHARED_SIZE_BYTES, int(shared_bytes))
        # The start event is recorded behind a short GPU spin, so it fires when the spin ends, by
        # which time the host has queued the kernel: the events then bracket the kernel alone, as
        # OpenCL's profiling start/end do. Without it the host's launch overhead (pycuda packs the
        # arguments in Python) lands inside the measured time on an idle GPU.
        self.backend.spin()
        start, end = self.backend.events
        start.record()
        f.prepared_async_call(grid3[:2] if grid3[2] == 1 else grid3, block3, None, *args,
                              shared_size=int(shared_bytes))
        end.record()
        wait_for_kernel(kernel, end.synchronize, done=end.query)
        return end.time_since(start)

    def prepared(self, kernel: str, args):
        """The kernel with its argument types fixed (pycuda's prepared call: no per-launch Python
        argument inspection)."""
        sig = "".join(_arg_type(a) for a in args)
        key = (kernel, sig)
        f = self._prepared.get(key)
        if f is None:
            f = self._module.get_function(kernel)
            f.prepare(sig)
            self._prepared[key] = f
        return f

    def resources(self, kernel, block=None):
        drv = self.backend.drv
        f = self.function(kernel)
        attr = drv.function_attribute
        res = KernelResources(kernel=kernel, backend="cuda",
                              registers=f.get_attribute(attr.NUM_REGS),
                              local_bytes=f.get_attribute(attr.LOCAL_SIZE_BYTES),
                              shared_bytes=f.get_attribute(attr.SHARED_SIZE_BYTES),
                              const_bytes=f.get_attribute(attr.CONST_SIZE_BYTES),
                              max_block=f.get_attribute(attr.MAX_THREADS_PER_BLOCK),
                              block=tuple(block) if block else None)
        if block:
            threads = int(np.prod(block))
            res.occupancy = cuda_occupancy(res.registers, threads, res.shared_bytes, self.backend.limits)
        return res


class CudaBackend(Backend):
    name = "cuda"
    language = "cuda"
    extension = ".cu"

    def __init__(self, device: str | None = None):
        drv = _pycuda()
        self.drv = drv
        want = device if device is not None else settings.get("RTLAB_CUDA_DEVICE")
        index = 0
        if want:
            names = [drv.Device(i).name() for i in range(drv.Device.count())]
            if want.isdigit() and int(want) < len(names):
                index = int(want)
            else:
                matches = [i for i, n in enumerate(names) if want.lower() in n.lower()]
                if not matches:
                    raise BackendError(f"no CUDA device matches '{want}'; available: {', '.join(names)}")
                index = matches[0]
        self.cuda_device = drv.Device(index)
        self.context = self.cuda_device.retain_primary_context()
        self.context.push()
        import atexit
        atexit.register(self._release)
        a = drv.device_attribute
        cc = self.cuda_device.compute_capability()
        self.arch = f"sm_{cc[0]}{cc[1]}"
        d = self.cuda_device
        self.limits = SmLimits(
            name=self.arch,
            max_warps=d.get_attribute(a.MAX_THREADS_PER_MULTIPROCESSOR) // 32,
            max_blocks=d.get_attribute(a.MAX_BLOCKS_PER_MULTIPROCESSOR),
            registers=d.get_attribute(a.MAX_REGISTERS_PER_MULTIPROCESSOR),
            shared_bytes=d.get_attribute(a.MAX_SHARED_MEMORY_PER_MULTIPROCESSOR))
        self.device_name = d.name()
        self.platform_name = f"CUDA driver {drv.get_driver_version()}, {self.arch}"
        self._programs: dict = {}
        self._spin = None
        self.events = (drv.Event(), drv.Event())

    def spin(self, ns: int = SPIN_NS) -> None:
        """Queue a GPU wait of ``ns`` nanoseconds (see CudaProgram.launch)."""
        if self._spin is None:
            from pycuda.compiler import SourceModule
            self._spin = SourceModule(SPIN_SOURCE, no_extern_c=True, arch=self.arch).get_function("rt_spin")
            self._spin.prepare("Q")
        self._spin.prepared_async_call((1, 1, 1), (1, 1, 1), None, np.uint64(ns))

    def _release(self):
        try:
            self.context.pop()
        except Exception:
            pass

    def is_gpu(self) -> bool:
        return True

    def has_warp_votes(self) -> bool:
        return True

    def compile(self, path, defines, options=()):
        from pycuda.compiler import SourceModule
        import pycuda.driver as drv
        options = CUDA_PRECISION_OPTIONS + tuple(options) + tuple((settings.get("RTLAB_NVCC_OPTIONS") or "").split())
        key = (str(path), tuple(map(str, include_dirs(path))), tuple(sorted(defines.items())), options)
        if key in self._programs:
            return self._programs[key]
        text = read_source(path)
        source = f'#line 1 "{path}"\n{text}'
        flags = [f"-D{k}={v}" for k, v in sorted(defines.items())] + list(options)
        try:
            # pycuda passes nvcc's messages on a successful build as a Python warning: into the
            # build log (shown on --verbose), not onto the user's terminal
            with warnings.catch_warnings(record=True) as said:
                warnings.simplefilter("always")
                module = SourceModule(source, options=flags, include_dirs=[*(str(d) for d in include_dirs(path)),
                                                                           str(Path(path).parent)],
                                      no_extern_c=True, arch=self.arch)
            report_build_log(path, defines, "\n".join(str(w.message) for w in said))
        except drv.CompileError as e:
            log = e.stderr or str(e)
            if isinstance(log, bytes):
                log = log.decode(errors="replace")
            raise KernelBuildError(format_build_error(path, defines, log)) from None
        prog = CudaProgram(self, Path(path), defines, module)
        self._programs[key] = prog
        return prog

    def to_device(self, array):
        data = np.ascontiguousarray(array)
        if data.nbytes == 0:
            data = np.zeros(4, np.uint8)
        return self.drv.to_device(data)

    def empty(self, nbytes):
        return self.drv.mem_alloc(max(int(nbytes), 4))

    def texture(self, buffer, dtype, channels, count):
        """A texture object over ``buffer`` (linear memory, point sampling, integers read as
        integers), passed to kernels as a 64-bit cudaTextureObject_t. pycuda has no texture-object
        API (DESIGN.md, known pitfalls): the driver's cuTexObjectCreate makes it, through cuda-python
        when installed, else through ctypes on libcuda.so.1."""
        from .cuda_texture import create_texture_object
        dtype = np.dtype(dtype)
        count = max(int(count), 1)
        ptr = int(buffer)
        align = self.cuda_device.get_attribute(self.drv.device_attribute.TEXTURE_ALIGNMENT)
        if ptr % align:
            raise BackendError(f"device buffer at {ptr:#x} is not aligned to {align} bytes, "
                               "which a linear texture needs")
        handle, destroy = create_texture_object(ptr, dtype, channels, count)
        return Texture(np.uint64(handle), buffer, dtype, channels, count, release=destroy)

    def fill(self, buffer, array):
        self.drv.memcpy_htod(buffer, np.ascontiguousarray(array))

    def to_host(self, buffer, dtype, count):
        out = np.empty(count, dtype)
        if count:
            self.drv.memcpy_dtoh(out, buffer)
        return out

    def synchronize(self):
        self.drv.Context.synchronize()
