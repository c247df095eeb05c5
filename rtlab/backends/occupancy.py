"""CUDA occupancy from a kernel's registers and shared memory (the paper's Fig. 5 quantity).

Occupancy = resident warps per multiprocessor / the maximum. Registers are allocated per warp in
units of 256; shared memory per block in units of 128 bytes (sm_90 rules, CUDA occupancy calculator).
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SmLimits:
    name: str = "sm_90"
    max_warps: int = 64
    max_blocks: int = 32
    registers: int = 65536
    reg_alloc_unit: int = 256          # registers, per warp
    max_regs_per_thread: int = 255
    shared_bytes: int = 233472         # 228 KiB usable per SM
    shared_alloc_unit: int = 128
    shared_reserved_per_block: int = 1024
    warp_size: int = 32


SM90 = SmLimits()


def cuda_occupancy(registers: int, threads_per_block: int, shared_bytes: int = 0,
                   limits: SmLimits = SM90) -> float:
    """Fraction 0..1 of the multiprocessor's warp slots kept busy by this kernel."""
    if threads_per_block <= 0:
        raise ValueError("threads_per_block must be positive")
    warps_per_block = -(-threads_per_block // limits.warp_size)
    by_warps = limits.max_warps // warps_per_block
    regs_per_warp = -(-max(registers, 1) * limits.warp_size // limits.reg_alloc_unit) * limits.reg_alloc_unit
    by_regs = limits.registers // (regs_per_warp * warps_per_block)
    smem = shared_bytes + limits.shared_reserved_per_block
    smem = -(-smem // limits.shared_alloc_unit) * limits.shared_alloc_unit
    by_smem = limits.shared_bytes // smem if shared_bytes > 0 else limits.max_blocks
    blocks = max(0, min(limits.max_blocks, by_warps, by_regs, by_smem))
    return blocks * warps_per_block / limits.max_warps
