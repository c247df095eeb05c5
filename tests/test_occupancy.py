from rtlab.backends.nvcc import parse_ptxas
from rtlab.backends.occupancy import SM90, cuda_occupancy


def test_occupancy_known_points():
    # 65536 registers / (32 regs * 32 lanes) = 64 warps: full
    assert cuda_occupancy(32, 256) == 1.0
    # 64 regs: 32 warps of 64
    assert cuda_occupancy(64, 128) == 0.5
    # 40 regs round to 1280/warp -> 51 warps -> 12 blocks of 4 warps = 48 warps
    assert cuda_occupancy(40, 128) == 48 / 64
    # 255 regs: 8160 -> 8192 per warp -> 8 warps
    assert cuda_occupancy(255, 32) == 8 / 64
    # shared memory bound: 100 KB a block -> 2 blocks of 8 warps
    assert cuda_occupancy(16, 256, 100 * 1024) == 16 / 64
    # block-count bound: 32 blocks of one warp
    assert cuda_occupancy(16, 32) == 32 / SM90.max_warps


def test_parse_ptxas_log():
    log = """ptxas info    : Compiling entry function 'render_primary' for 'sm_90'
ptxas info    : Function properties for render_primary
    1024 bytes stack frame, 8 bytes spill stores, 4 bytes spill loads
ptxas info    : Used 40 registers, used 0 barriers, 1024 bytes cumulative stack size, 368 bytes cmem[0]
"""
    r = parse_ptxas(log)["render_primary"]
    assert (r.registers, r.local_bytes, r.spill_bytes, r.const_bytes) == (40, 1024, 12, 368)
