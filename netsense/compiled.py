"""Compiled drivers: one numba source, a serial and a threaded build.

A *driver* loops over batch members (``prange``) and calls the row functions of
:mod:`netsense.kernels` or :mod:`netsense.observation`. :class:`Driver` compiles it twice
from the same Python source, once serial and once with ``parallel=True``, and
:meth:`Driver.at` picks by the size of the call: a single environment (``B = 1``) runs
serially, where starting threads costs more than it saves; large batches use numba's
thread pool (``NUMBA_NUM_THREADS``, default one thread per core). Every member is computed
by the same row functions, independently, so both builds give bit-identical results
(``tests/test_kernels_compiled.py``).

Drivers are compiled without numba's reference counting (``_nrt=False``): they allocate
nothing (outputs and scratch rows come from the Python wrapper), so no array needs a
reference count, and the row functions they inline run without the atomic
increments and decrements numba otherwise wraps around every array argument — at
``N = 10`` those cost more than the arithmetic of the rules (measured 10x on the source
correction).
"""

from __future__ import annotations

import types

from numba import njit

#: Work (array elements touched) from which a call runs on numba's thread pool.
PARALLEL_WORK = 1 << 16

__all__ = ["PARALLEL_WORK", "Driver"]


class Driver:
    """A driver compiled twice from one source: ``serial`` and ``parallel``."""

    def __init__(self, fn) -> None:
        self.serial = njit(cache=True, _nrt=False)(_renamed(fn, "serial"))
        self.parallel = njit(cache=True, parallel=True, _nrt=False)(_renamed(fn, "parallel"))

    def at(self, work: int):
        """The build for a call that touches ``work`` array elements."""
        return self.parallel if work >= PARALLEL_WORK else self.serial


def _renamed(fn, tag: str):
    """A copy of ``fn`` under its own qualified name (numba caches per name)."""
    out = types.FunctionType(fn.__code__, fn.__globals__, f"{fn.__name__}_{tag}",
                             fn.__defaults__, fn.__closure__)
    out.__qualname__ = f"{fn.__qualname__}_{tag}"
    out.__module__ = fn.__module__
    return out
