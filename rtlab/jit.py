"""numba, imported once this process is ready for it (``from rtlab.jit import njit, prange``).

Every module that compiles with numba imports it from here, so ``import rtlab`` itself changes
nothing in the process: the two settings below are made only when numba is first needed.
"""
from .paths import prepare_process

prepare_process()

import numba  # noqa: E402
from numba import njit, prange  # noqa: E402

__all__ = ["numba", "njit", "prange"]
