"""Input checks shared by every layer, and the errors of numerical trouble.

Every public entry point of netsense checks its arguments before it changes any state or
runs compiled code (``docs/errors.md``): a bad argument raises :class:`ValueError` whose
message starts with the argument's name (``"batch_size must be an integer >= 1, got
'4'"``). The helpers here make those checks short and their messages uniform; compiled
code without bounds checks stays behind them.

Numerical trouble (a plant state or estimate that stopped being finite) is not bad
input: :class:`NumericalError` and :class:`NumericalWarning` report it, naming the batch
member, the agent and the step (see :class:`netsense.engine.core.BatchedCore`).

May import: numpy. Nothing else from netsense (the lowest layer's lowest module).
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["MAX_STEPS", "NumericalError", "NumericalWarning", "array", "boolean",
           "choice", "index_range", "integer", "mask", "number", "seed_value"]

#: Largest horizon, time index or freshness index netsense accepts: indices stay exact in
#: float64 and ``horizon + claim`` fits an int64 (the compiled passes' integer type).
MAX_STEPS = 2**53


class NumericalError(ArithmeticError):
    """A plant state or an estimate became non-finite (inf or NaN), or their distance
    overflowed.

    Raised by :meth:`netsense.engine.core.BatchedCore.step` with ``nonfinite="raise"``
    (before the step is committed); the message names the member, agent and step, which
    are also the attributes ``member``, ``agent`` (``None`` for the plant state), ``step``
    and ``what`` (``"state"``, ``"estimate"`` or ``"error"``).
    """

    def __init__(self, message: str, *, member: int = -1, agent: int | None = None,
                 step: int = -1, what: str = "") -> None:
        super().__init__(message)
        self.member, self.agent, self.step, self.what = member, agent, step, what


class NumericalWarning(RuntimeWarning):
    """Issued once per member and episode when a member is terminated for a non-finite
    state or estimate (``nonfinite="terminate"``, the default)."""


def _got(v: Any) -> str:
    r = repr(v)
    if len(r) > 60:
        r = r[:57] + "..."
    return f"{r} ({type(v).__name__})"


def integer(name: str, v: Any, lo: int | None = None, hi: int | None = None) -> int:
    """``v`` as a Python int: an ``int`` or numpy integer (not a bool, float or string) in
    ``[lo, hi]``; else ``ValueError`` naming ``name``."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral):
        raise ValueError(f"{name} must be an integer{_bounds(lo, hi)}, got {_got(v)}")
    v = int(v)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ValueError(f"{name} must be an integer{_bounds(lo, hi)}, got {v}")
    return v


def number(name: str, v: Any, lo: float | None = None, hi: float | None = None, *,
           lo_open: bool = False, hi_open: bool = False) -> float:
    """``v`` as a finite float: a real number (not a bool or string) in the interval from
    ``lo`` to ``hi`` (closed unless ``lo_open`` / ``hi_open``); else ``ValueError``."""
    ok = not isinstance(v, (bool, np.bool_)) and isinstance(v, numbers.Real)
    f = float(v) if ok else float("nan")
    if ok:
        ok = bool(np.isfinite(f))
    if ok and lo is not None:
        ok = f > lo if lo_open else f >= lo
    if ok and hi is not None:
        ok = f < hi if hi_open else f <= hi
    if not ok:
        lb = "" if lo is None else ("(" if lo_open else "[") + f"{lo:g}"
        ub = "" if hi is None else f"{hi:g}" + (")" if hi_open else "]")
        where = f" in {lb or '(-inf'}, {ub or 'inf)'}" if lo is not None or hi is not None \
            else ""
        raise ValueError(f"{name} must be a finite number{where}, got {_got(v)}")
    return f


def boolean(name: str, v: Any) -> bool:
    """``v`` if it is ``True`` or ``False`` (a numpy bool too); else ``ValueError``
    (the string ``"false"`` is not a bool)."""
    if not isinstance(v, (bool, np.bool_)):
        raise ValueError(f"{name} must be true or false, got {_got(v)}")
    return bool(v)


def choice(name: str, v: Any, options: Sequence) -> Any:
    """``v`` if it is one of ``options`` (compared by type and value); else ``ValueError``."""
    for o in options:
        if type(v) is type(o) and v == o:
            return v
    raise ValueError(f"{name} must be one of {list(options)}, got {_got(v)}")


def seed_value(name: str, v: Any, count: int = 1) -> int:
    """A seed: an integer ``>= 0`` such that ``v + count - 1`` fits an int64 (members are
    seeded ``v + b``)."""
    hi = 2**63 - count
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral) \
            or not 0 <= int(v) <= hi:
        top = "2^63 - 1" if count == 1 else f"2^63 - {count}"
        raise ValueError(f"{name} must be an integer in [0, {top}] or None, got {_got(v)}")
    return int(v)


def _bounds(lo, hi) -> str:
    if lo is not None and hi is not None:
        return f" in [{lo}, {hi}]"
    if lo is not None:
        return f" >= {lo}"
    if hi is not None:
        return f" <= {hi}"
    return ""


_KINDS = {"i": "integer", "b": "bool", "f": "numeric", "if": "numeric", "ib": "integer or bool",
          "ibf": "numeric"}


def array(name: str, a: Any, shape: Sequence[int | None] | None = None, *,
          kind: str | None = None, finite: bool = False) -> np.ndarray:
    """``a`` as an array with ``len(shape)`` axes whose lengths match ``shape`` (``None``:
    any length) and whose dtype is of ``kind``: ``"i"`` integers (signed or unsigned),
    ``"b"`` bools, ``"f"`` real numbers (ints and floats; converted to float64), or a
    combination such as ``"ib"``. ``finite``: no inf or NaN. Else ``ValueError`` naming
    ``name``, the expected shape and what was given."""
    try:
        out = np.asarray(a)
    except (ValueError, TypeError) as exc:  # ragged nested lists
        raise ValueError(f"{name} must be an array{_shape(shape)}: {exc}") from None
    if shape is not None and (out.ndim != len(shape) or any(
            w is not None and s != w for s, w in zip(out.shape, shape, strict=True))):
        raise ValueError(f"{name} must have shape {_shape(shape)[1:]}, got {out.shape}")
    if kind is not None:
        k = out.dtype.kind
        allowed = {"i": "iu", "b": "b", "f": "iuf"}
        ok = any(k in allowed[c] for c in kind)
        if not ok or (out.dtype == object):
            raise ValueError(f"{name} must hold {_KINDS.get(kind, kind)} values, got dtype "
                             f"{out.dtype}")
        if kind == "f" and k != "f":
            out = out.astype(float)
    if finite and out.dtype.kind == "f" and not np.isfinite(out).all():
        raise ValueError(f"{name} contains NaN or infinite entries")
    return out


def mask(name: str, a: Any, shape: Sequence[int | None] | None = None) -> np.ndarray:
    """``a`` as a bool array of ``shape``: bools, or numbers that are all 0 or 1; else
    ``ValueError`` (``[0, 2]`` is not a mask)."""
    out = array(name, a, shape, kind="ibf")
    if out.dtype.kind != "b":
        if out.size and not np.isin(out, (0, 1)).all():
            raise ValueError(f"{name} must be a bool mask (or 0/1), got values "
                             f"{np.unique(out)[:5].tolist()}")
        out = out.astype(bool)
    return out


def _shape(shape) -> str:
    if shape is None:
        return ""
    return " (" + ", ".join("*" if s is None else str(s) for s in shape) + \
        ("," if len(shape) == 1 else "") + ")"


def index_range(name: str, a: np.ndarray, lo: int, hi: int,
                where: np.ndarray | None = None) -> None:
    """Every entry of ``a`` (those where ``where`` is true, if given) lies in ``lo..hi - 1``;
    else ``ValueError`` naming ``name``, the range and the first offending entry."""
    vals = a if where is None else a[np.broadcast_to(where, a.shape)]
    if vals.size == 0:
        return
    mn, mx = vals.min(), vals.max()
    if mn >= lo and mx < hi:
        return
    bad = (a < lo) | (a >= hi)
    if where is not None:
        bad &= np.broadcast_to(where, a.shape)
    pos = tuple(int(p[0]) for p in np.nonzero(bad))
    raise ValueError(f"{name} must hold indices in {lo}..{hi - 1}"
                     f"{' where used' if where is not None else ''}; entry {list(pos)} is "
                     f"{a[pos]}")
