"""A one-line notice when netsense's compiled code starts compiling.

netsense's drivers are compiled by numba on first use and cached on disk. With a warm cache
they load in milliseconds; with a cold one (a fresh install, a new numba, an edited rule)
the first ``reset``/``step`` spends seconds to a minute compiling, which would otherwise look
like a hang. numba broadcasts a ``"numba:compile"`` event only when it really compiles (a
cache hit does not), so a listener on that event says so, once per process, the first time a
function of netsense compiles.

The notice is a ``WARNING`` of the logger ``netsense.compile``: with no logging configured
Python prints it to stderr; silence it with
``logging.getLogger("netsense.compile").setLevel(logging.ERROR)``. ``netsense warmup``
compiles everything ahead of time (see ``docs/first-run.md``).
"""

from __future__ import annotations

import logging
import os

from numba.core import event

__all__ = ["LOGGER", "install"]

LOGGER = logging.getLogger("netsense.compile")

MESSAGE = ("netsense: compiling numba kernels (first use with a cold cache: seconds to a "
           "minute, once; cached in %s). `netsense warmup` compiles them all ahead of time.")


def cache_location(dispatcher) -> str:
    """Where numba caches ``dispatcher`` (``NUMBA_CACHE_DIR``, else next to the source)."""
    path = getattr(getattr(dispatcher, "_cache", None), "_cache_path", None)
    if path:
        return str(path)
    return os.environ.get("NUMBA_CACHE_DIR") or "the package's __pycache__ folders"


class _Notice(event.Listener):
    """Logs :data:`MESSAGE` at the first compilation of a netsense function."""

    def __init__(self) -> None:
        self.done = False

    def on_start(self, ev) -> None:
        if self.done:
            return
        dispatcher = (ev.data or {}).get("dispatcher")
        module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
        if module.startswith("netsense."):
            self.done = True
            LOGGER.warning(MESSAGE, cache_location(dispatcher))

    def on_end(self, ev) -> None:
        pass


_LISTENER: _Notice | None = None


def install() -> None:
    """Register the listener (once per process; :mod:`netsense.kernels` calls this)."""
    global _LISTENER
    if _LISTENER is None:
        _LISTENER = _Notice()
        event.register("numba:compile", _LISTENER)


def mark_shown() -> None:
    """Suppress the notice for the rest of the process (``netsense warmup`` reports its
    own progress)."""
    install()
    _LISTENER.done = True
