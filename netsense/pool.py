"""Per-member work on threads: the random draws of a batch.

Every batch member owns its generators (the reproducibility contract of
:class:`netsense.envcore.BatchedCore`), so its graphs and noise are drawn by one numpy call
per member and stream. numpy's generators fill arrays with the GIL released, so those
calls run in parallel on threads: :func:`each_part` splits the members into contiguous
parts, one per thread, and every generator is used by exactly one thread, in the same
order as a serial loop — the draws are the same numbers whatever the thread count.

The thread count is numba's (:func:`numba.get_num_threads`, the ``--threads`` of the
benchmarks), so the draws use the cores the compiled kernels use. Calls with fewer than
:data:`MIN_PART` members per thread run inline (a single environment never starts a
thread).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

__all__ = ["MIN_PART", "each_part"]

#: Fewest members a thread is given (below that, thread hand-offs cost more than draws).
MIN_PART = 16

_lock = threading.Lock()
_pool: ThreadPoolExecutor | None = None
_pool_size = 0


def _executor(threads: int) -> ThreadPoolExecutor:
    global _pool, _pool_size
    with _lock:
        if _pool is None or _pool_size < threads:
            if _pool is not None:
                _pool.shutdown(wait=True)
            _pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="netsense")
            _pool_size = threads
        return _pool


def each_part(fn: Callable[[int, int], None], count: int, threads: int | None = None) -> None:
    """Run ``fn(lo, hi)`` over contiguous parts of ``range(count)``, one part per thread.

    Parameters
    ----------
    fn : callable
        ``fn(lo, hi)`` does the work of items ``lo .. hi - 1``; parts never overlap, and
        ``fn`` must only write what belongs to its items.
    count : int
        Number of items (batch members).
    threads : int, optional
        Threads to use (default :func:`numba.get_num_threads`); 1 runs inline.

    Raises
    ------
    Exception
        The first exception a part raised (after every part finished).
    """
    if count < 0:
        raise ValueError(f"count must be >= 0, got {count}")
    if threads is None:
        import numba

        threads = numba.get_num_threads()
    parts = max(1, min(int(threads), count // MIN_PART))
    if parts == 1:
        fn(0, count)
        return
    bounds = [count * p // parts for p in range(parts + 1)]
    pool = _executor(parts - 1)
    futures = [pool.submit(fn, bounds[p], bounds[p + 1]) for p in range(1, parts)]
    error = None
    try:
        fn(bounds[0], bounds[1])  # the calling thread takes the first part
    except BaseException as exc:  # noqa: BLE001 - re-raised below, after the others
        error = exc
    for f in futures:
        try:
            f.result()
        except BaseException as exc:  # noqa: BLE001
            error = error or exc
    if error is not None:
        raise error
