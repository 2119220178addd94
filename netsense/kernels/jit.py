"""Compiled drivers: one numba source, a serial and a threaded build.

A *driver* loops over batch members (``prange``) and calls the row functions of
:mod:`netsense.kernels.update` or :mod:`netsense.engine.observation`. :class:`Driver` compiles
it twice
from the same Python source, once serial and once with ``parallel=True``, and
:meth:`Driver.at` picks by the size of the call. Every member is computed by the same row
functions, independently, so both builds give bit-identical results
(``tests/test_kernels_compiled.py``).

Threads (``docs/threads.md``, with the measurements behind each choice), all decided here:

* a call runs threaded only with at least two members (so the single environment,
  ``B = 1``, never does), at least :data:`PARALLEL_WORK` array elements of work and more
  than one thread allowed;
* the thread count: :func:`set_num_threads` / ``NETSENSE_NUM_THREADS`` (0 or 1: serial),
  at most numba's pool (``NUMBA_NUM_THREADS``, default one per core);
* OpenMP workers wait passively (``OMP_WAIT_POLICY=passive`` is set at import unless the
  user set ``OMP_WAIT_POLICY`` or ``GOMP_SPINCOUNT``): spinning workers made every
  threaded call wait for a time slice whenever another process used a core;
* numba's threading layer stays the user's choice (``NUMBA_THREADING_LAYER``; numba's
  default is TBB if installed, else OpenMP);
* a process forked after its parent started numba's GNU OpenMP pool runs every driver
  serially (numba would terminate it at its first threaded call);
* threaded calls are serialised by a lock, so several Python threads may step their own
  batches under any layer (workqueue aborts on concurrent calls).

Drivers are cached on disk by numba (``cache=True``) under names that end with a digest of
the modules they inline (:func:`inlined_digest`): numba checks only the defining file's
timestamp, so an edit of :mod:`netsense.kernels.rules` alone would otherwise leave every driver
running its old machine code. Where numba can write no cache (a read-only install without
a writable home), :func:`njit_cached` caches in a private temporary directory or compiles
uncached, with one :class:`CacheWarning`.

Drivers are compiled without numba's reference counting (``_nrt=False``): they allocate
nothing (outputs and scratch rows come from the Python wrapper), so no array needs a
reference count, and the row functions they inline run without the atomic
increments and decrements numba otherwise wraps around every array argument — at
``N = 10`` those cost more than the arithmetic of the rules (measured 10x on the source
correction).

:func:`bit_streams` hands numpy's own C draw functions and the generators' states to a
driver, and :func:`bit_generator` turns them into numba's bit-generator object, so
per-member random numbers are drawn inside the threaded pass that consumes them, by
numba's implementation of numpy's algorithms, continuing each member's stream exactly:
link failures (:class:`netsense.graphs.processes.MarkovLinkFailures`) and Gaussian noise
(:meth:`netsense.sensing.noise.GaussianNoise.sample_many`). This builds on numba's own
model of numpy bit generators (``numba.np.random``, the code behind numba's support for
``np.random.Generator``); ``tests/test_kernels_compiled.py`` checks the streams against
numpy's, so a change of that model in a future numba fails there, not silently.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import stat
import tempfile
import threading
import types
import warnings
from collections.abc import Sequence
from pathlib import Path

import numba
import numpy as np
from numba import njit
from numba import types as nbtypes
from numba.core import cgutils
from numba.core import config as numba_config
from numba.core.extending import intrinsic
from numba.np.random import generator_core  # noqa: F401  (numba's bit-generator model)

#: Work (array elements touched) from which a call runs on numba's thread pool. Waking a
#: passive worker costs ~40-60 us on the 2-vCPU benchmark VM, so a threaded pass pays from
#: ~150 us of serial work: 0.3-1.2 ns per element for the step's passes (docs/threads.md).
PARALLEL_WORK = 1 << 18

__all__ = ["NO_STREAMS", "PARALLEL_WORK", "CacheWarning", "Driver", "bit_generator",
           "bit_streams", "get_num_threads", "njit_cached", "set_num_threads"]

# numba's workqueue threading layer (fork-safe, see docs/threads.md) refuses concurrent
# parallel calls from several Python threads (it aborts the process); netsense's threaded
# drivers therefore run one at a time, whatever the layer.
_PARALLEL_LOCK = threading.Lock()


# ----------------------------------------------------------------------------- threads
# OpenMP's wait policy (passive unless the user chose one) is set by the package's
# __init__, before torch or numba's pool can load libgomp: docs/threads.md.

#: Environment variable read at import: the most threads a batched call uses (``0`` or
#: ``1``: every call serial; default numba's pool, ``NUMBA_NUM_THREADS``).
NUM_THREADS_ENV = "NETSENSE_NUM_THREADS"


def _parse_threads(value, what: str) -> int | None:
    if value is None:
        return None
    try:
        k = int(value)
    except (TypeError, ValueError):
        k = -1
    if isinstance(value, bool) or k < 0 or (not isinstance(value, str) and k != value):
        raise ValueError(f"{what} must be an integer >= 0 (0 or 1: serial), got {value!r}")
    return k


_num_threads: int | None = _parse_threads(os.environ.get(NUM_THREADS_ENV), NUM_THREADS_ENV)
_serial_only = _num_threads is not None and _num_threads < 2  # (read by Driver.at)
_forked_from_omp = False  # a fork() child of a process whose GNU OpenMP pool had started


def set_num_threads(k: int | None) -> None:
    """Use at most ``k`` threads in netsense's batched calls, process-wide.

    ``0`` or ``1``: every call runs serially; ``None``: numba's thread pool, all of it
    (``NUMBA_NUM_THREADS``, default one thread per core). More than the pool gives the
    pool. The environment variable ``NETSENSE_NUM_THREADS`` sets the same at import.
    A single environment (``B = 1``) runs serially whatever ``k``.
    """
    global _num_threads, _serial_only
    _num_threads = _parse_threads(k, "set_num_threads(k): k")
    _serial_only = _num_threads is not None and _num_threads < 2


def get_num_threads() -> int:
    """The most threads a batched call uses now (1: serial), see :func:`set_num_threads`;
    1 in a process forked after its parent had started numba's GNU OpenMP pool."""
    if _serial_only or _forked_from_omp:
        return 1
    pool = int(numba_config.NUMBA_NUM_THREADS)
    return pool if _num_threads is None else min(_num_threads, pool)


def _gnu_omp_started() -> bool:
    """numba's thread pool runs on GNU OpenMP in this process (which a fork() child must
    not use: numba terminates the child at its first threaded call)."""
    from numba.np.ufunc import parallel

    if not getattr(parallel, "_is_initialized", False):
        return False
    if getattr(parallel, "_threading_layer", None) != "omp":
        return False
    try:
        from numba.np.ufunc import omppool
    except ImportError:  # pragma: no cover
        return False
    return getattr(omppool, "openmp_vendor", "GNU") == "GNU"


def _after_fork_in_child() -> None:
    """A fork() child runs every call serially if the parent had started GNU OpenMP
    (bit-identical results; the parent's pool does not exist in the child), and gets a
    fresh lock (another thread of the parent may have held it at the fork)."""
    global _forked_from_omp, _PARALLEL_LOCK
    _PARALLEL_LOCK = threading.Lock()
    if not _forked_from_omp and _gnu_omp_started():
        _forked_from_omp = True


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


# ----------------------------------------------------------------------------- disk cache
class CacheWarning(RuntimeWarning):
    """numba cannot write its cache where it looks (next to the package, ``NUMBA_CACHE_DIR``,
    the user's cache directory): netsense caches its compiled code in a private temporary
    directory instead, or compiles it in every process. Issued once per process."""


_FALLBACK: dict[str, str | None] = {}  # "dir": the fallback cache directory, once chosen


def njit_cached(**options):
    """``numba.njit(cache=True, **options)`` that works where no cache can be written.

    numba picks a cache directory when it decorates a function and raises ``RuntimeError:
    cannot cache function ...: no locator available`` when none of its places is writable
    (a package installed read-only, run by a user without a writable home). Then the
    function is cached in :func:`_fallback_cache_dir` (a private directory under the
    system's temporary directory) and, if even that fails, compiled without a cache; the
    first such fallback issues one :class:`CacheWarning` for the whole package. Setting
    ``NUMBA_CACHE_DIR`` to a writable directory avoids both.

    Compiled functions release the GIL while they run (``nogil=True`` unless ``options``
    say otherwise): they touch only the arrays they are given, and another Python thread
    (the learner while a training loop's collector steps the core,
    :attr:`netsense.rl.config.PPOConfig.overlap`) runs meanwhile.
    """
    options = {"nogil": True, **options}

    def decorate(fn):
        try:
            return njit(cache=True, **options)(fn)
        except RuntimeError as exc:
            if "no locator available" not in str(exc):
                raise
        if "dir" not in _FALLBACK:
            _FALLBACK["dir"] = where = _fallback_cache_dir()
            warnings.warn(
                f"netsense: numba cannot write its cache next to the package "
                f"({Path(__file__).parent}), in NUMBA_CACHE_DIR or in the user's cache "
                f"directory; "
                + (f"compiled code is cached in {where} instead" if where else
                   "compiled code is not cached (every process compiles it again)")
                + ". Set NUMBA_CACHE_DIR to a writable directory to choose the place.",
                CacheWarning, stacklevel=2)
        where = _FALLBACK["dir"]
        if where is not None:
            # numba reads its cache directory when it decorates (the path is kept by the
            # function's cache): point it at the fallback for this decoration only
            before = numba_config.CACHE_DIR
            numba_config.CACHE_DIR = where
            try:
                return njit(cache=True, **options)(fn)
            except RuntimeError:  # (not a file on disk, or the directory went away)
                pass
            finally:
                numba_config.CACHE_DIR = before
        return njit(**options)(fn)

    return decorate


def _fallback_cache_dir() -> str | None:
    """A directory only this user can write, for numba's cache: ``netsense-numba-<uid>``
    in the system's temporary directory (reused by later processes), else a fresh
    ``mkdtemp`` one, else None. A shared directory that someone else owns or could write
    is never used (numba's cache files are loaded as code)."""
    try:
        base = tempfile.gettempdir()
    except (OSError, FileNotFoundError):
        return None
    uid = getattr(os, "getuid", lambda: None)()
    if uid is not None:
        path = os.path.join(base, f"netsense-numba-{uid}")
        try:
            os.makedirs(path, mode=0o700, exist_ok=True)
            st = os.lstat(path)
            if (stat.S_ISDIR(st.st_mode) and st.st_uid == uid and not st.st_mode & 0o077
                    and os.access(path, os.W_OK | os.X_OK)):
                return path
        except OSError:
            pass
    try:
        return tempfile.mkdtemp(prefix="netsense-numba-")
    except OSError:
        return None


class Driver:
    """A driver compiled twice from one source: ``serial`` and ``parallel``.

    ``min_runs``: fewest members (the ``prange`` axis) for which the threaded build is
    worth it whatever the work (at least 2: one member never runs threaded), higher for
    drivers whose threaded build is erratic on few long members (measured for the Markov
    slot pass, :data:`netsense.graphs.processes.MARKOV_THREADED_RUNS`).
    """

    def __init__(self, fn, *, min_runs: int = 2) -> None:
        self.serial = njit_cached(_nrt=False)(_renamed(fn, "serial"))
        self.parallel = njit_cached(parallel=True, _nrt=False)(_renamed(fn, "parallel"))
        self.min_runs = max(2, int(min_runs))

    def at(self, work: int, *, runs: int):
        """The build for a call that touches ``work`` array elements over ``runs``
        members (the ``prange`` axis; the threaded build holds a process-wide lock
        while it runs). Fewer than two members (a single environment) always run
        serially."""
        if runs < self.min_runs or work < PARALLEL_WORK or _serial_only or _forked_from_omp:
            return self.serial
        return self._threaded

    def _threaded(self, *args):
        with _PARALLEL_LOCK:
            k = _num_threads
            if k is None:
                return self.parallel(*args)
            before = numba.get_num_threads()  # (numba's count is per Python thread)
            if before <= k:
                return self.parallel(*args)
            numba.set_num_threads(k)
            try:
                return self.parallel(*args)
            finally:
                numba.set_num_threads(before)


#: Modules whose compiled functions every driver may inline or call: the row functions,
#: numba's view of numpy's bit generators and the explicit vector code.
INLINED_SOURCES = ("rules.py", "jit.py", "lanes.py")


def inlined_digest() -> str:
    """Digest of :data:`INLINED_SOURCES` (their bytes), part of every driver's cache key.

    numba's on-disk cache checks only the timestamp of the file that defines a function,
    not of the functions it inlines: after an edit of a row function in
    :mod:`netsense.kernels.rules` alone, every driver would load its stale machine code from the
    cache and run the old rule. With this digest in the drivers' names, such an edit gives
    new names, hence a fresh compilation.
    """
    h = hashlib.sha256()
    here = Path(__file__).parent
    for name in INLINED_SOURCES:
        h.update((here / name).read_bytes())
    return h.hexdigest()[:12]


_DIGEST = inlined_digest()


def _renamed(fn, tag: str):
    """A copy of ``fn`` under its own qualified name (numba caches per name), which ends
    with :func:`inlined_digest`."""
    name = f"{fn.__name__}_{tag}_{_DIGEST}"
    out = types.FunctionType(fn.__code__, fn.__globals__, name, fn.__defaults__,
                             fn.__closure__)
    out.__qualname__ = f"{fn.__qualname__}_{tag}_{_DIGEST}"
    out.__module__ = fn.__module__
    return out


_BIT_GENERATOR = nbtypes.NumPyRandomBitGeneratorType("bit_generator")


@intrinsic
def _bit_generator(typingctx, fns, state):
    """numba's bit-generator struct over numpy's C functions ``fns`` and a raw state."""
    if not (isinstance(fns, nbtypes.Array) and fns.ndim == 1 and fns.dtype == nbtypes.uintp
            and state == nbtypes.uintp):
        return None  # typing error: fns must be bit_streams' (3,) uintp array
    sig = _BIT_GENERATOR(fns, state)

    def codegen(context, builder, signature, args):
        fns_ty = signature.args[0]
        arr = context.make_array(fns_ty)(context, builder, args[0])
        data = arr.data
        bg = cgutils.create_struct_proxy(_BIT_GENERATOR)(context, builder)
        bg.parent = context.get_constant_null(nbtypes.pyobject)
        bg.state_address = args[1]
        bg.state = args[1]
        for k, name in enumerate(("next_uint64", "next_uint32", "next_double")):
            ptr = builder.gep(data, [context.get_constant(nbtypes.intp, k)])
            setattr(bg, f"fnptr_{name}", builder.load(ptr))
        bg.bit_generator = context.get_constant(nbtypes.uintp, 0)
        return bg._getvalue()

    return sig, codegen


@njit_cached(inline="always")
def bit_generator(fns, state):
    """numba's view of one numpy bit generator: ``fns`` and ``state`` from
    :func:`bit_streams`. numba's own draws (``next_double``, ``next_uint64`` of
    ``numba.np.random.generator_core``, the distributions of
    ``numba.np.random.distributions``) take it and continue that generator's stream
    exactly as numpy's ``Generator`` methods would."""
    return _bit_generator(fns, state)


def bit_streams(rngs: Sequence[np.random.Generator]
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """``(fns (3,) uintp, states (len(rngs),) uintp)`` of the generators, or None.

    ``fns`` are the C functions ``next_uint64``, ``next_uint32`` and ``next_double`` of
    the generators' bit-generator type, from its documented ``ctypes`` interface, and
    ``states[m]`` the state of ``rngs[m]``: a driver that draws through
    ``bit_generator(fns, states[m])`` draws exactly what ``rngs[m]``'s methods would, and
    leaves ``rngs[m]`` where they would. None when the list is empty, its bit generators
    are not all of one type, or one generator appears twice (then the caller draws
    through numpy). The generators must stay alive, and nobody else may use them, while
    a driver draws (numpy's per-generator lock is not taken).
    """
    if not rngs:
        return None
    bgs = [rng.bit_generator for rng in rngs]  # (list comprehensions: this runs at every
    kinds = {type(bg) for bg in bgs}  # refill for each of 1,024 members' generators)
    if len(kinds) != 1:
        return None
    kind = kinds.pop()
    if kind not in _FNS:  # C functions of a class: cast once per process (each cast
        iface = bgs[0].ctypes  # leaves garbage for the cyclic collector)
        _FNS[kind] = np.array([ctypes.cast(f, ctypes.c_void_p).value for f in
                               (iface.next_uint64, iface.next_uint32, iface.next_double)],
                              dtype=np.uintp)
    addresses = [bg.ctypes.state_address for bg in bgs]
    if len(set(addresses)) != len(addresses):  # one generator twice: its two runs must
        return None  # be drawn one after the other
    return _FNS[kind], np.array(addresses, dtype=np.uintp)


_FNS: dict[type, np.ndarray] = {}  # bit-generator class -> its C draw functions


#: ``fns`` for drivers called without streams (never called).
NO_STREAMS = np.zeros(3, dtype=np.uintp)

