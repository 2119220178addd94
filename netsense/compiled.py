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

:func:`uniform_streams` hands numpy's own ``next_double`` and the generators' states to a
driver, so per-member uniforms are drawn inside the threaded pass that consumes them
(:class:`netsense.graphs.MarkovLinkFailures`), continuing each member's stream exactly.
"""

from __future__ import annotations

import ctypes
import threading
import types
from collections.abc import Sequence

import numba.experimental.function_type  # noqa: F401  (lets numba type the class below)
import numpy as np
from numba import njit
from numba import types as nbtypes

#: Work (array elements touched) from which a call runs on numba's thread pool.
PARALLEL_WORK = 1 << 16

__all__ = ["PARALLEL_WORK", "Driver", "NextDouble", "uniform_streams"]

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


class NextDouble(nbtypes.WrapperAddressProtocol):
    """numpy's own ``next_double`` of one bit-generator type, callable in compiled code.

    The C function a :class:`numpy.random.BitGenerator` exposes through its documented
    ``ctypes`` interface, handed to numba as a first-class function (``fn(state_address)``
    returns the next double in ``[0, 1)`` and advances that generator). It is what
    ``Generator.random`` calls once per value, so compiled draws continue each
    generator's stream exactly (``tests/test_kernels_compiled.py``). It is passed as an
    argument, never baked into the code, so drivers that take it stay cacheable.
    """

    def __init__(self, address: int) -> None:
        self.address = int(address)

    def __wrapper_address__(self) -> int:
        return self.address

    def signature(self):
        return nbtypes.float64(nbtypes.uintp)  # (void *state): a pointer-sized integer


def uniform_streams(rngs: Sequence[np.random.Generator]
                    ) -> tuple[NextDouble, np.ndarray] | None:
    """``(next_double, state addresses (len(rngs),) uintp)`` of the generators, or None.

    A driver that calls ``next_double(states[m])`` ``K`` times draws exactly what
    ``rngs[m].random(K)`` would, and leaves ``rngs[m]`` where that call would. None when
    the list is empty, its bit generators are not all of one type, or one generator
    appears twice (then the caller draws through numpy). The generators must stay alive,
    and nobody else may use them, while a driver draws (numpy's per-generator lock is not
    taken).
    """
    if not rngs:
        return None
    fns: dict[type, int] = {}  # one C function per bit-generator class
    states = np.empty(len(rngs), dtype=np.uintp)
    for m, rng in enumerate(rngs):
        bg = rng.bit_generator
        iface = bg.ctypes
        if type(bg) not in fns:
            fns[type(bg)] = ctypes.cast(iface.next_double, ctypes.c_void_p).value
        states[m] = iface.state_address
    if len(fns) != 1 or np.unique(states).size != states.size:  # one generator twice:
        return None  # its two runs must be drawn one after the other
    return NextDouble(fns.popitem()[1]), states
