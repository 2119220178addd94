"""Training pipeline, stage *resume*: what a run needs to continue where it stopped.

At every checkpoint :func:`netsense.rl.ppo.train_ppo` writes ``resume.pt``
(:data:`RESUME_FILE`, atomically, after the checkpoint and the log's row): the learner
(actor, critic, optimiser, value and return normalisers), the random generators (torch's
and NumPy's global ones, the collector's action generator, the environments' generators
and seed stream), the collection's state (every environment member mid-episode, the
observation and mask it acts on next, the running returns, a recurrent actor's state),
the collector's actor (one update behind the learner's in an overlapped run), the
iteration, the step count and the run's counters. ``train_ppo(..., resume=True)`` rebuilds
the run from its config, loads that state and goes on from the next iteration: with the
serial loop (``overlap=False``) the resumed run ends with the same weights, bit for bit,
as one never interrupted.

**The file is data.** It is a ``torch.save`` of tensors and plain containers, loaded with
``torch.load(weights_only=True)``. The environments' state is a pickle inside it (a byte
tensor), read by :func:`loads_state`, an unpickler that builds only the classes of
netsense's simulation layers and NumPy's arrays, scalars and generators, and refuses every
other name (any function, any class of another package), so loading runs no code of the
file's choosing. ``resume.pt`` is removed when the run finishes.

Imports: torch, numpy and the standard library.
"""

from __future__ import annotations

import importlib
import io
import pickle
from pathlib import Path

import numpy as np
import torch

__all__ = ["RESUME_FILE", "dumps_state", "loads_state", "numpy_rng_state",
           "read_resume", "set_numpy_rng_state"]

#: The resume state of a run folder.
RESUME_FILE = "resume.pt"

#: netsense layers whose classes a simulation state may hold (the engine and below).
_LAYERS = ("kernels", "sensing", "systems", "graphs", "estimators", "observers", "engine",
           "env", "grid")
#: Functions of NumPy that rebuild arrays, scalars and generators (what pickling them
#: names), and the harmless builtins.
_FUNCTIONS = {
    ("numpy._core.multiarray", "_reconstruct"), ("numpy.core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "scalar"), ("numpy.core.multiarray", "scalar"),
    ("numpy._core.numeric", "_frombuffer"), ("numpy.core.numeric", "_frombuffer"),
    ("numpy.random._pickle", "__bit_generator_ctor"),
    ("numpy.random._pickle", "__generator_ctor"),
    ("numpy.random._pickle", "__randomstate_ctor"),
    ("numpy.random.bit_generator", "__pyx_unpickle_SeedSequence"),
    ("builtins", "slice"), ("builtins", "set"), ("builtins", "frozenset"),
    ("builtins", "complex"), ("builtins", "range"), ("builtins", "bytearray"),
    ("collections", "OrderedDict"),
}


def _allowed(module: str, name: str):
    """The object ``module.name`` if a simulation state may name it, else ``None``."""
    if (module, name) in _FUNCTIONS:
        return getattr(importlib.import_module(module), name)
    parts = module.split(".")
    netsense = parts[0] == "netsense" and len(parts) > 1 and parts[1] in _LAYERS
    if not (netsense or parts[0] == "numpy"):
        return None
    try:
        obj = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError):
        return None
    if not isinstance(obj, type):  # classes only: constructing one is all a file can ask
        return None
    if parts[0] == "numpy" and not (issubclass(obj, (np.ndarray, np.generic, np.dtype,
                                                     np.random.BitGenerator,
                                                     np.random.Generator,
                                                     np.random.SeedSequence))
                                    or obj is np.dtype):
        return None
    return obj


class _Unpickler(pickle.Unpickler):
    def __init__(self, data: bytes, where: str) -> None:
        super().__init__(io.BytesIO(data))
        self.where = where

    def find_class(self, module: str, name: str):
        obj = _allowed(module, name)
        if obj is None:
            raise ValueError(f"{self.where}: the saved environment state names "
                             f"{module}.{name}, which a netsense simulation state never "
                             "holds; the file was not written by netsense's trainer (or "
                             "was altered): refused without running it")
        return obj


def dumps_state(obj) -> bytes:
    """``obj`` (environment cores, NumPy arrays and generators, plain containers) as bytes
    that :func:`loads_state` reads back."""
    return pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)


def loads_state(data: bytes, where: str):
    """The object of :func:`dumps_state`'s ``data``, building only netsense simulation
    classes and NumPy objects.

    Raises
    ------
    ValueError
        Naming ``where``: the data names anything else, or is not a readable pickle.
    """
    try:
        return _Unpickler(bytes(data), where).load()
    except ValueError:
        raise
    except Exception as exc:  # noqa: BLE001 - a damaged state: named, not a traceback
        raise ValueError(f"{where}: the saved environment state is unreadable "
                         f"({type(exc).__name__}: {exc})") from None


def numpy_rng_state() -> dict:
    """NumPy's global generator state (``np.random.get_state``) as tensors and numbers."""
    # the legacy global generator: saved because libraries may draw from it
    name, keys, pos, has_gauss, gauss = np.random.get_state()  # noqa: NPY002
    return {"name": str(name), "keys": torch.from_numpy(np.asarray(keys, np.int64)),
            "pos": int(pos), "has_gauss": int(has_gauss), "gauss": float(gauss)}


def set_numpy_rng_state(state: dict) -> None:
    """Restore :func:`numpy_rng_state`'s ``state``."""
    legacy = (state["name"], state["keys"].numpy().astype(np.uint32), state["pos"],
              state["has_gauss"], state["gauss"])
    np.random.set_state(legacy)  # noqa: NPY002


def read_resume(path: str | Path) -> dict:
    """The contents of a run's ``resume.pt`` (``torch.load(weights_only=True)``).

    Raises
    ------
    ValueError
        Naming the file: unreadable, or not a resume state of this trainer.
    """
    path = Path(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unreadable file: named, not a traceback
        raise ValueError(f"{path}: not a readable resume state ({type(exc).__name__}: "
                         f"{exc})") from None
    need = ("format", "iteration", "config", "learner", "collector", "counters", "rng")
    if not isinstance(state, dict) or any(k not in state for k in need) or \
            state["format"] != "netsense-resume":
        raise ValueError(f"{path}: not a resume state of netsense's batched trainer")
    return state
