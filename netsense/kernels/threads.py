"""The thread pools of worker processes: one statement of which variables size them.

BLAS (OpenBLAS, MKL), OpenMP (torch's intra-op pool too), numba and netsense's compiled
passes (:data:`netsense.kernels.jit.NUM_THREADS_ENV`) each read a variable once, when the
library loads. A process pool that runs K workers on K cores gives each worker a pool of
one thread by setting these variables in the environment the workers are spawned with
(:func:`spawn_environment`); an initializer would run after the worker had imported
numpy and numba. Used by the benchmark's process backend and the training launcher.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

from netsense.kernels.jit import NUM_THREADS_ENV

__all__ = ["THREAD_VARS", "spawn_environment", "thread_env"]

#: Environment variables that size a process's thread pools when their library loads.
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
               "NUMBA_NUM_THREADS", NUM_THREADS_ENV)


def thread_env(threads: int | None) -> dict[str, str]:
    """The :data:`THREAD_VARS` a worker starts with: each ``str(threads)`` unless this
    process's environment sets it (then that value); ``{}`` for ``threads=None``."""
    if threads is None:
        return {}
    return {k: os.environ.get(k, str(threads)) for k in THREAD_VARS}


@contextmanager
def spawn_environment(env: dict[str, str]) -> Iterator[None]:
    """``env`` in ``os.environ`` while worker processes are spawned (they copy it when
    they start, before they import anything), then restored."""
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
