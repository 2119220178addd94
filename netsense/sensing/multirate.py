"""Asynchronous multi-rate sensing: each sensor reports with its own period and phase.

Sensor ``i`` nominally reports at the steps ``k = phase_i + j * period_i`` (``j = 0, 1,
...``; the first step is ``k = 0``). Optionally each report is delayed by a uniformly
drawn ``0..jitter`` steps and dropped with probability ``drop_prob``. At step ``k`` the
central estimator receives, stacked in sensor order, the measurements of the sensors that
reported (eq. (2) of the time-varying paper, Remark 1 / eq. (12) of the asynchronous one):

.. math::  y(t) = [y_i(t)]_{i \\in S(t)}, \\quad A(t) = [A_i]_{i \\in S(t)}, \\quad
           Q_t = \\mathrm{blkdiag}(Q_i)_{i \\in S(t)},

with ``y_i = A_i x + b_i + n_i`` and ``n_i ~ N(0, Q_i)``.

Two layers:

* :class:`MultiRateArrivals` -- the report pattern alone, an
  :class:`~netsense.sensing.arrivals.ArrivalModel` (the last axis of the sampler's shape is
  the sensor axis; leading axes are independent batch copies with their own jitter/drops).
  Environment scenarios build it with :func:`multirate_from_dict`.
* :class:`MultiRateSensing` -- sensors (``A_i``, ``Q_i``, ``b_i``) plus the arrivals;
  :meth:`MultiRateSensing.stack` returns the ragged stacked ``(A(t), Q_t, b(t))`` of one
  run, :meth:`MultiRateSensing.padded` the fixed-shape batched form in which silent
  sensors have zero rows (they add nothing to the cost of eq. (6), so the OSE step is
  identical).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from netsense.sensing.arrivals import ArrivalModel, ArrivalSampler

__all__ = ["MultiRateArrivals", "MultiRateSampler", "MultiRateSensing", "Sensor",
           "multirate_from_dict"]


def _int_tuple(owner: str, name: str, values: Any, minimum: int) -> tuple[int, ...]:
    if isinstance(values, (int, np.integer)) or isinstance(values, (str, bytes)):
        raise ValueError(f"{owner}.{name} must be a sequence of integers, got {values!r}")
    try:
        out = tuple(values)
    except TypeError:
        raise ValueError(f"{owner}.{name} must be a sequence of integers, "
                         f"got {values!r}") from None
    for v in out:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < minimum:
            raise ValueError(f"{owner}.{name} must hold integers >= {minimum}, got {values!r}")
    return tuple(int(v) for v in out)


# ------------------------------------------------------------------------ arrivals
class MultiRateSampler(ArrivalSampler):
    """Per-step report indicators of a :class:`MultiRateArrivals`; picklable.

    Keeps the step counter, the next nominal report step and the next (jittered) actual
    report step of every entry.
    """

    def __init__(self, model: MultiRateArrivals, rng: np.random.Generator,
                 shape: tuple[int, ...]) -> None:
        S = len(model.periods)
        if len(shape) == 0 or shape[-1] != S:
            raise ValueError(f"the sampler shape must end with the number of sensors {S}, "
                             f"got shape {shape}")
        self.model = model
        self.rng = rng
        self.shape = shape
        self.k = 0
        self.period = np.broadcast_to(np.asarray(model.periods), shape)
        self.nominal = np.broadcast_to(np.asarray(model.phase_tuple), shape).copy()
        self.actual = self.nominal + self._jitter()

    def _jitter(self) -> np.ndarray:
        if self.model.jitter == 0:
            return np.zeros(self.shape, dtype=int)
        return self.rng.integers(0, self.model.jitter + 1, size=self.shape)

    def redraw(self, rng: np.random.Generator) -> MultiRateSampler:
        """The state before the last step drawn, that step drawn again with ``rng``
        (its jitter and drop draws redrawn; the report times fixed before it kept)."""
        if not hasattr(self, "_before"):
            raise ValueError("redraw needs a sampler that has drawn a step")
        out = object.__new__(MultiRateSampler)
        out.__dict__.update(self.__dict__)
        out.rng = rng
        out.k, out.nominal, out.actual = self._before
        out.next()
        return out

    def next(self) -> np.ndarray:
        self._before = (self.k, self.nominal, self.actual)  # (for redraw)
        reported = self.actual == self.k
        if reported.any():
            self.nominal = np.where(reported, self.nominal + self.period, self.nominal)
            self.actual = np.where(reported, self.nominal + self._jitter(), self.actual)
        if self.model.drop_prob > 0:
            reported = reported & (self.rng.random(self.shape) >= self.model.drop_prob)
        self.k += 1
        return reported


@dataclass(frozen=True)
class MultiRateArrivals(ArrivalModel):
    """Periodic asynchronous reports: sensor ``i`` reports every ``periods[i]`` steps.

    Parameters
    ----------
    periods : sequence of int
        Reporting period of every sensor, in steps (>= 1).
    phases : sequence of int, optional
        First report step of every sensor, in ``[0, period_i)``; all 0 by default.
    jitter : int, default 0
        Each report is delayed by a uniform integer in ``[0, jitter]`` steps
        (``jitter < min(periods)`` so that reports keep their order).
    drop_prob : float, default 0.0
        Probability that a report is lost.

    Notes
    -----
    Without jitter and drops, every window of ``max(periods)`` consecutive steps holds a
    report of every sensor: with sensors that each measure their own part of the state,
    this is Assumption 4 (and Lemma 3 then gives Assumption 1) with
    ``tau = max(periods)`` (see :meth:`tau_bound`).
    """

    periods: tuple[int, ...]
    phases: tuple[int, ...] | None = None
    jitter: int = 0
    drop_prob: float = 0.0

    def __post_init__(self) -> None:
        periods = _int_tuple("MultiRateArrivals", "periods", self.periods, 1)
        if not periods:
            raise ValueError("MultiRateArrivals.periods must name at least one sensor")
        object.__setattr__(self, "periods", periods)
        if self.phases is not None:
            phases = _int_tuple("MultiRateArrivals", "phases", self.phases, 0)
            if len(phases) != len(periods):
                raise ValueError(f"MultiRateArrivals.phases must have one entry per sensor "
                                 f"({len(periods)}), got {len(phases)}")
            bad = [i for i, (ph, p) in enumerate(zip(phases, periods, strict=True)) if ph >= p]
            if bad:
                raise ValueError(f"MultiRateArrivals.phases must satisfy 0 <= phase < period; "
                                 f"violated for sensors {bad}")
            object.__setattr__(self, "phases", phases)
        j = self.jitter
        if isinstance(j, bool) or not isinstance(j, (int, np.integer)) or j < 0:
            raise ValueError(f"MultiRateArrivals.jitter must be an integer >= 0, got {j!r}")
        if j >= min(periods):
            raise ValueError(f"MultiRateArrivals.jitter must be < min(periods) = "
                             f"{min(periods)}, got {j}")
        object.__setattr__(self, "jitter", int(j))
        p = self.drop_prob
        if isinstance(p, bool) or not isinstance(p, (int, float, np.integer, np.floating)) \
                or not 0.0 <= float(p) < 1.0:
            raise ValueError(f"MultiRateArrivals.drop_prob must be a number in [0, 1), got {p!r}")
        object.__setattr__(self, "drop_prob", float(p))

    @property
    def num_sensors(self) -> int:
        """Number of sensors ``S``."""
        return len(self.periods)

    @property
    def phase_tuple(self) -> tuple[int, ...]:
        """The phases, zeros when none were given."""
        return self.phases if self.phases is not None else (0,) * len(self.periods)

    def tau_bound(self) -> int:
        """Steps within which every sensor reports at least once (no drops):
        ``max_i (period_i + jitter)``; raises if ``drop_prob > 0`` (no finite bound)."""
        if self.drop_prob > 0:
            raise ValueError("with drop_prob > 0 no finite window guarantees a report")
        return max(self.periods) + self.jitter

    def sampler(self, rng: np.random.Generator, shape: tuple[int, ...]) -> MultiRateSampler:
        shape = (int(shape),) if isinstance(shape, (int, np.integer)) else tuple(
            int(s) for s in shape)
        return MultiRateSampler(self, rng, shape)

    def schedule(self, steps: int) -> np.ndarray:
        """Deterministic ``(steps, S)`` report pattern (requires ``jitter == 0`` and
        ``drop_prob == 0``)."""
        if self.jitter or self.drop_prob:
            raise ValueError("schedule() needs jitter == 0 and drop_prob == 0; use sampler()")
        k = np.arange(int(steps))[:, None]
        P, ph = np.asarray(self.periods), np.asarray(self.phase_tuple)
        return (k >= ph) & ((k - ph) % P == 0)

    def to_dict(self) -> dict:
        return {"kind": "multirate", "periods": list(self.periods),
                "phases": list(self.phase_tuple), "jitter": self.jitter,
                "drop_prob": self.drop_prob}


def multirate_from_dict(spec: dict) -> MultiRateArrivals:
    """Build a :class:`MultiRateArrivals` from
    ``{"kind": "multirate", "periods": [...], "phases": [...], "jitter": 0,
    "drop_prob": 0.0}`` (``kind``, ``phases``, ``jitter`` and ``drop_prob`` optional).

    Raises
    ------
    ValueError
        Naming the offending field when a field is unknown, missing or invalid.
    """
    if not isinstance(spec, dict):
        raise ValueError(f"multirate spec must be a dict, got {type(spec).__name__}")
    spec = dict(spec)
    kind = spec.pop("kind", "multirate")
    if kind != "multirate":
        raise ValueError(f"multirate spec field 'kind' must be 'multirate', got {kind!r}")
    allowed = {"periods", "phases", "jitter", "drop_prob"}
    unknown = sorted(set(spec) - allowed)
    if unknown:
        raise ValueError(f"multirate spec has unknown field(s) {unknown}; "
                         f"allowed: {sorted(allowed)}")
    if "periods" not in spec:
        raise ValueError("multirate spec is missing the field 'periods'")
    return MultiRateArrivals(**spec)


# ------------------------------------------------------------------------- sensors
@dataclass(frozen=True, eq=False)
class Sensor:
    """One sensor: ``y_i = A_i x + b_i + n_i`` with ``n_i ~ N(0, Q_i)``.

    Parameters
    ----------
    A : (r, N) array
        Output matrix.
    Q : (r,) variances or (r, r) covariance
        Positive definite noise covariance (also the estimator's weight ``Q_t`` block).
    b : (r,) array, optional
        Known affine offset (Remark 1); zero by default.
    name : str
        Label.
    """

    A: np.ndarray
    Q: np.ndarray
    b: np.ndarray | None = None
    name: str = "sensor"

    def __post_init__(self) -> None:
        A = np.asarray(self.A, dtype=float)
        if A.ndim != 2 or A.shape[0] == 0:
            raise ValueError(f"Sensor {self.name!r}: A must be a 2-D (r, N) matrix with r >= 1, "
                             f"got shape {A.shape}")
        r = A.shape[0]
        Q = np.asarray(self.Q, dtype=float)
        Q = np.diag(Q) if Q.ndim == 1 else Q
        if Q.shape != (r, r):
            raise ValueError(f"Sensor {self.name!r}: Q must have shape ({r},) or ({r}, {r}), "
                             f"got {np.shape(self.Q)}")
        if not np.allclose(Q, Q.T) or np.linalg.eigvalsh(Q)[0] <= 0:
            raise ValueError(f"Sensor {self.name!r}: Q must be symmetric positive definite")
        b = np.zeros(r) if self.b is None else np.asarray(self.b, dtype=float)
        if b.shape != (r,):
            raise ValueError(f"Sensor {self.name!r}: b must have shape ({r},), got {b.shape}")
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "Q", Q)
        object.__setattr__(self, "b", b)

    @property
    def rows(self) -> int:
        """Number of measured quantities ``r``."""
        return self.A.shape[0]


@dataclass(frozen=True, eq=False)
class MultiRateSensing:
    """A set of sensors with asynchronous multi-rate reports.

    Parameters
    ----------
    sensors : sequence of Sensor
        All with the same state size ``N``.
    arrivals : MultiRateArrivals
        The report pattern; ``arrivals.num_sensors`` must equal ``len(sensors)``.
    """

    sensors: tuple[Sensor, ...]
    arrivals: MultiRateArrivals
    _offsets: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        sensors = tuple(self.sensors)
        if not sensors or not all(isinstance(s, Sensor) for s in sensors):
            raise ValueError("sensors must be a non-empty sequence of Sensor")
        N = sensors[0].A.shape[1]
        for i, s in enumerate(sensors):
            if s.A.shape[1] != N:
                raise ValueError(f"sensors[{i}].A must have N = {N} columns, got {s.A.shape[1]}")
        if not isinstance(self.arrivals, MultiRateArrivals):
            raise ValueError("arrivals must be a MultiRateArrivals")
        if self.arrivals.num_sensors != len(sensors):
            raise ValueError(f"arrivals describe {self.arrivals.num_sensors} sensors but "
                             f"{len(sensors)} sensors were given")
        object.__setattr__(self, "sensors", sensors)
        object.__setattr__(self, "_offsets",
                           np.concatenate([[0], np.cumsum([s.rows for s in sensors])]))

    @property
    def N(self) -> int:
        """State size."""
        return self.sensors[0].A.shape[1]

    @property
    def total_rows(self) -> int:
        """Rows when every sensor reports, ``sum_i r_i``."""
        return int(self._offsets[-1])

    @property
    def A_full(self) -> np.ndarray:
        """All sensors' ``A_i`` stacked, ``(sum r_i, N)``."""
        return np.vstack([s.A for s in self.sensors])

    @property
    def Q_full(self) -> np.ndarray:
        """Block-diagonal covariance of all sensors."""
        Q = np.zeros((self.total_rows, self.total_rows))
        for i, s in enumerate(self.sensors):
            sl = slice(self._offsets[i], self._offsets[i + 1])
            Q[sl, sl] = s.Q
        return Q

    @property
    def b_full(self) -> np.ndarray:
        """All offsets stacked."""
        return np.concatenate([s.b for s in self.sensors])

    def row_mask(self, reported: np.ndarray) -> np.ndarray:
        """Expand a ``(..., S)`` sensor mask to the ``(..., sum r_i)`` row mask."""
        reported = np.asarray(reported, dtype=bool)
        if reported.shape[-1:] != (len(self.sensors),):
            raise ValueError(f"reported must end with the sensor axis of size "
                             f"{len(self.sensors)}, got shape {reported.shape}")
        return np.repeat(reported, np.diff(self._offsets), axis=-1)

    def stack(self, reported: Sequence[bool]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Stacked ``(A(t), Q_t, b(t))`` of the sensors that reported (one run).

        ``reported`` is a ``(S,)`` boolean mask; the result has ``M_t = sum`` of the
        reporting sensors' ``r_i`` rows (possibly 0).
        """
        rows = self.row_mask(np.asarray(reported))
        if rows.ndim != 1:
            raise ValueError("stack() takes the (S,) mask of one run; use padded() for batches")
        return self.A_full[rows], self.Q_full[np.ix_(rows, rows)], self.b_full[rows]

    def clean(self, x: np.ndarray) -> np.ndarray:
        """Noise-free outputs of every sensor, ``A_full x + b_full``, shape ``(..., sum r_i)``."""
        x = np.asarray(x, dtype=float)
        if x.shape[-1] != self.N:
            raise ValueError(f"x must end with the state size N = {self.N}, got {x.shape}")
        return x @ self.A_full.T + self.b_full

    def measure_all(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy outputs of every sensor (``n ~ N(0, Q_full)``), ``(..., sum r_i)``."""
        y = self.clean(x)
        L = np.linalg.cholesky(self.Q_full)
        return y + rng.standard_normal(y.shape) @ L.T

    def padded(self, reported: np.ndarray, y_all: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Fixed-shape ``(y, A, Q, b)`` for a batch: silent sensors get zero rows.

        Parameters
        ----------
        reported : (R, S) bool array
            Which sensors reported in every run.
        y_all : (R, sum r_i) array
            Every sensor's measurement (entries of silent sensors are ignored).

        Returns
        -------
        y, A, Q, b : (R, Mtot), (R, Mtot, N), (R, Mtot, Mtot), (R, Mtot)
            A zero row with unit variance and zero data contributes nothing to eq. (6), so
            :func:`netsense.estimators.online.ose_step` on these equals the stacked step.
        """
        rows = self.row_mask(reported)
        if rows.ndim != 2:
            raise ValueError("padded() takes an (R, S) mask; use stack() for a single run")
        y_all = np.asarray(y_all, dtype=float)
        if y_all.shape != rows.shape:
            raise ValueError(f"y_all must have shape {rows.shape}, got {y_all.shape}")
        w = rows.astype(float)
        A = self.A_full[None] * w[..., None]
        b = self.b_full[None] * w
        y = np.where(rows, y_all, 0.0)
        Q = self.Q_full[None] * (w[:, :, None] * w[:, None, :])
        Q = Q + np.eye(self.total_rows)[None] * (1.0 - w)[:, None, :]
        return y, A, Q, b
