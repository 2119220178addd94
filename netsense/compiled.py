"""Compiled drivers: one numba source, a serial and a threaded build.

A *driver* loops over batch members (``prange``) and calls the row functions of
:mod:`netsense.kernels` or :mod:`netsense.observation`. :class:`Driver` compiles it twice
from the same Python source, once serial and once with ``parallel=True``, and
:meth:`Driver.at` picks by the size of the call: a single environment (``B = 1``) runs
serially, where starting threads costs more than it saves; large batches use numba's
thread pool (``NUMBA_NUM_THREADS``, default one thread per core). Every member is computed
by the same row functions, independently, so both builds give bit-identical results
(``tests/test_kernels_compiled.py``).

Threads: numba's threading layer is left as the user configures it (``NUMBA_THREADING_LAYER``;
numba's default is OpenMP when present, whose workers spin after every call: fastest on free
cores, but on cores busy with other work every threaded call waits for a time slice — see
the README's batched section for measurements and ``workqueue`` as the remedy). Threaded
calls are serialised by a lock, so several Python threads may step their own batches under
any layer.

Drivers are compiled without numba's reference counting (``_nrt=False``): they allocate
nothing (outputs and scratch rows come from the Python wrapper), so no array needs a
reference count, and the row functions they inline run without the atomic
increments and decrements numba otherwise wraps around every array argument — at
``N = 10`` those cost more than the arithmetic of the rules (measured 10x on the source
correction).
"""

from __future__ import annotations

import threading
import types

from numba import njit

#: Work (array elements touched) from which a call runs on numba's thread pool.
PARALLEL_WORK = 1 << 16

__all__ = ["PARALLEL_WORK", "Driver"]

# numba's workqueue threading layer (a choice for busy machines, see the module docstring)
# refuses concurrent parallel calls from several Python threads (it aborts the process);
# netsense's threaded drivers therefore run one at a time, whatever the layer.
_PARALLEL_LOCK = threading.Lock()


class Driver:
    """A driver compiled twice from one source: ``serial`` and ``parallel``."""

    def __init__(self, fn) -> None:
        self.serial = njit(cache=True, _nrt=False)(_renamed(fn, "serial"))
        self.parallel = njit(cache=True, parallel=True, _nrt=False)(_renamed(fn, "parallel"))

    def at(self, work: int):
        """The build for a call that touches ``work`` array elements (the threaded one
        holds a process-wide lock while it runs)."""
        return self._threaded if work >= PARALLEL_WORK else self.serial

    def _threaded(self, *args):
        with _PARALLEL_LOCK:
            return self.parallel(*args)


def _renamed(fn, tag: str):
    """A copy of ``fn`` under its own qualified name (numba caches per name)."""
    out = types.FunctionType(fn.__code__, fn.__globals__, f"{fn.__name__}_{tag}",
                             fn.__defaults__, fn.__closure__)
    out.__qualname__ = f"{fn.__qualname__}_{tag}"
    out.__module__ = fn.__module__
    return out
