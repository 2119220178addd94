"""Smart meters and PMUs on a feeder: selection matrices (41)-(43) and measurement noise.

The measurable quantities of every bus are stacked as
``z = [Re v; Im v; |v|; p; q] = Phi x + offset`` (eq. (40) with the known zero-load part,
see :attr:`netsense.grid.linear.LinearPowerFlow.offset`), each block of length ``3B``.

* a smart meter at bus ``s`` reports ``(|v_s|, p_s, q_s)``: 9 rows, eq. (42);
* a PMU at bus ``s`` reports ``(Re v_s, Im v_s, |v_s|, p_s, q_s)``: 15 rows, eq. (43).

Section VII: smart meters report every hour with a maximum error of 0.5 %, PMUs every
minute with 0.05 %; noise is zero-mean Gaussian with relative standard deviation
``max error / 3``, truncated at ``+-3 sigma``. "Relative" is taken with respect to the
measured value: ``|v|`` of the node for the three voltage rows, ``max(|value|, floor)``
for power rows (a floor keeps the covariance positive definite on unloaded phases).

:class:`GridMetering` ties meters, report phases and the linear model into a
:class:`netsense.sensing.multirate.MultiRateSensing` for the OASE, eqs. (44), (47)-(48).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from netsense.grid.linear import LinearPowerFlow
from netsense.sensing.multirate import MultiRateArrivals, MultiRateSensing, Sensor

__all__ = ["PMU", "SMART_METER", "GridMetering", "MeterSpec", "meter_rows",
           "selection_matrix", "truncated_normal"]


@dataclass(frozen=True)
class MeterSpec:
    """A metering device class.

    Parameters
    ----------
    kind : {"sm", "pmu"}
        Smart meter (|v|, p, q) or PMU (Re v, Im v, |v|, p, q).
    period_s : int
        Reporting period in seconds (one simulation step is one second).
    max_rel_error : float
        Maximum relative error; the noise standard deviation is a third of it.
    """

    kind: str
    period_s: int
    max_rel_error: float

    def __post_init__(self) -> None:
        if self.kind not in ("sm", "pmu"):
            raise ValueError(f"MeterSpec.kind must be 'sm' or 'pmu', got {self.kind!r}")
        if int(self.period_s) < 1:
            raise ValueError(f"MeterSpec.period_s must be >= 1, got {self.period_s!r}")
        if not 0 < self.max_rel_error < 1:
            raise ValueError(f"MeterSpec.max_rel_error must be in (0, 1), "
                             f"got {self.max_rel_error!r}")

    @property
    def sigma_rel(self) -> float:
        """Relative standard deviation (max error / 3)."""
        return self.max_rel_error / 3.0

    @property
    def blocks(self) -> tuple[int, ...]:
        """Which of the five quantity blocks (Re v, Im v, |v|, p, q) the device reports."""
        return (2, 3, 4) if self.kind == "sm" else (0, 1, 2, 3, 4)


SMART_METER = MeterSpec("sm", 3600, 0.005)
PMU = MeterSpec("pmu", 60, 0.0005)


def meter_rows(B: int, bus: int, spec: MeterSpec) -> np.ndarray:
    """Row indices into ``z`` (length ``15B``) of a meter at bus index ``bus``:
    the non-zero columns of ``S_s`` in eqs. (42)-(43)."""
    if not 0 <= bus < B:
        raise ValueError(f"bus index must be in [0, {B}), got {bus}")
    return np.concatenate([blk * 3 * B + 3 * bus + np.arange(3) for blk in spec.blocks])


def selection_matrix(B: int, meters: list[tuple[int, MeterSpec]]) -> np.ndarray:
    """``S(t) = [S_{s_1}; ...; S_{s_S}]`` of eq. (41), a 0/1 matrix with ``15B`` columns."""
    rows = [meter_rows(B, bus, spec) for bus, spec in meters]
    idx = np.concatenate(rows) if rows else np.zeros(0, dtype=int)
    S = np.zeros((idx.size, 15 * B))
    S[np.arange(idx.size), idx] = 1.0
    return S


def truncated_normal(rng: np.random.Generator, shape, limit: float = 3.0) -> np.ndarray:
    """Standard normal draws truncated to ``[-limit, limit]`` (by redrawing)."""
    z = rng.standard_normal(shape)
    bad = np.abs(z) > limit
    while bad.any():
        z[bad] = rng.standard_normal(int(bad.sum()))
        bad = np.abs(z) > limit
    return z


@dataclass(frozen=True, eq=False)
class GridMetering:
    """Meters on the buses of a feeder with asynchronous reports.

    Parameters
    ----------
    lpf : LinearPowerFlow
        The feeder's linear model (gives ``Phi`` and the offset).
    meters : tuple of (bus index, MeterSpec)
        One device per entry.
    phases : tuple of int
        First report second of every meter, in ``[0, period)``.
    x_ref : (6B,) array
        Reference state (e.g. the nominal injections) used to set the estimator's
        ``Q`` (the operator does not know the true values).
    power_floor : float
        Floor, in per unit, on the magnitude that sets the noise of power rows.
    """

    lpf: LinearPowerFlow
    meters: tuple
    phases: tuple
    x_ref: np.ndarray
    power_floor: float = 1e-3

    def __post_init__(self) -> None:
        B = self.lpf.B
        if len(self.phases) != len(self.meters):
            raise ValueError(f"phases must have one entry per meter ({len(self.meters)}), "
                             f"got {len(self.phases)}")
        x_ref = np.asarray(self.x_ref, dtype=float)
        if x_ref.shape != (6 * B,):
            raise ValueError(f"x_ref must have shape ({6 * B},), got {x_ref.shape}")
        if not self.power_floor > 0:
            raise ValueError(f"power_floor must be > 0, got {self.power_floor!r}")
        object.__setattr__(self, "x_ref", x_ref)
        object.__setattr__(self, "meters", tuple(self.meters))
        object.__setattr__(self, "phases", tuple(int(p) for p in self.phases))

    @property
    def arrivals(self) -> MultiRateArrivals:
        """The report pattern (one sensor per meter)."""
        return MultiRateArrivals(periods=tuple(s.period_s for _, s in self.meters),
                                 phases=self.phases)

    def rows(self, i: int) -> np.ndarray:
        """Rows of ``z`` reported by meter ``i``."""
        bus, spec = self.meters[i]
        return meter_rows(self.lpf.B, bus, spec)

    def scale(self, z: np.ndarray) -> np.ndarray:
        """Magnitude each quantity's relative error refers to, same shape as ``z``."""
        B3 = 3 * self.lpf.B
        z = np.asarray(z, dtype=float)
        vmag = np.abs(z[..., 2 * B3: 3 * B3])
        pq = np.maximum(np.abs(z[..., 3 * B3:]), self.power_floor)
        return np.concatenate([vmag, vmag, vmag, pq], axis=-1)

    def sigma(self) -> np.ndarray:
        """Per-quantity noise standard deviation of every meter's rows at ``x_ref``,
        concatenated in meter order (the diagonal of the estimator's ``Q``)."""
        sc = self.scale(self.lpf.quantities(self.x_ref))
        return np.concatenate([spec.sigma_rel * sc[self.rows(i)]
                               for i, (_, spec) in enumerate(self.meters)])

    def sensing(self) -> MultiRateSensing:
        """Sensors ``A_i = (S_i Phi)``, ``Q_i`` from :meth:`sigma`, ``b_i = S_i offset``."""
        Phi, off = self.lpf.Phi, self.lpf.offset
        sig = self.sigma()
        sensors, k = [], 0
        for i, (bus, spec) in enumerate(self.meters):
            r = self.rows(i)
            sensors.append(Sensor(A=Phi[r], Q=sig[k: k + r.size] ** 2, b=off[r],
                                  name=f"{spec.kind}@{bus}"))
            k += r.size
        return MultiRateSensing(tuple(sensors), self.arrivals)

    def measure(self, x: np.ndarray, meter_ids, rng: np.random.Generator) -> np.ndarray:
        """Noisy readings of the meters ``meter_ids`` for states ``x`` ``(..., 6B)``.

        Quantities come from the linear model (eq. (44)); each gets truncated Gaussian
        noise with standard deviation ``sigma_rel * scale`` of its true value.
        """
        z = self.lpf.quantities(x)
        sc = self.scale(z)
        parts = []
        for i in meter_ids:
            r = self.rows(i)
            sd = self.meters[i][1].sigma_rel * sc[..., r]
            parts.append(z[..., r] + sd * truncated_normal(rng, sd.shape))
        if not parts:
            return np.zeros(np.shape(x)[:-1] + (0,))
        return np.concatenate(parts, axis=-1)
