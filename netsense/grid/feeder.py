"""Three-phase radial feeders and their bus admittance matrix.

A :class:`Feeder` holds line configurations (3 x 3 series impedance and shunt susceptance
per mile), line segments (bus pair, length, configuration) and delta-connected spot loads
(kW/kVAr on the ab, bc and ca branches), all in the units of the public test-feeder
specifications. :func:`load_ieee37` reads the IEEE 37-node feeder transcribed in
``netsense/grid/data/ieee37.json``.

Per-unit system used throughout :mod:`netsense.grid`: the voltage base is the
line-to-neutral nominal voltage ``V_b = kV_LL / sqrt(3)``, the power base ``S_b`` (default
1 MVA) applies to each single-phase quantity (a node's or a delta branch's complex power),
so ``Z_b = V_b^2 / S_b``.

The bus admittance matrix (Section V of the asynchronous paper, "Y") follows the usual
pi model: a segment with series impedance ``Z`` and shunt admittance ``Y_sh`` between buses
``m`` and ``n`` adds ``Z^-1 + Y_sh / 2`` to blocks ``(m, m)`` and ``(n, n)`` and ``-Z^-1``
to ``(m, n)`` and ``(n, m)``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources

import numpy as np

__all__ = ["Feeder", "LineConfig", "load_ieee37", "FT_PER_MILE"]

FT_PER_MILE = 5280.0
PHASES = ("ab", "bc", "ca")


@dataclass(frozen=True, eq=False)
class LineConfig:
    """A line configuration: per-mile ``z`` (3x3, ohm) and shunt ``b`` (3x3, microsiemens)."""

    z_ohm_per_mile: np.ndarray
    b_us_per_mile: np.ndarray

    def __post_init__(self) -> None:
        z = np.asarray(self.z_ohm_per_mile, dtype=complex)
        b = np.asarray(self.b_us_per_mile, dtype=float)
        b = np.diag(b) if b.ndim == 1 else b
        if z.shape != (3, 3) or b.shape != (3, 3):
            raise ValueError(f"LineConfig needs 3x3 z and b, got {z.shape} and {b.shape}")
        if not np.allclose(z, z.T):
            raise ValueError("LineConfig.z_ohm_per_mile must be symmetric")
        object.__setattr__(self, "z_ohm_per_mile", z)
        object.__setattr__(self, "b_us_per_mile", b)


@dataclass(frozen=True, eq=False)
class Feeder:
    """A three-phase, three-wire radial feeder with delta-connected loads.

    Parameters
    ----------
    name : str
        Label.
    base_kv_ll : float
        Nominal line-to-line voltage in kV.
    source_bus : str
        The slack (substation) bus, index 0 of Section V.
    configs : dict of str -> LineConfig
        Line configurations.
    lines : tuple of (bus_from, bus_to, length_ft, config)
        Segments (every segment is three-phase).
    loads : dict of str -> (model, (P_ab, Q_ab, P_bc, Q_bc, P_ca, Q_ca))
        Delta spot loads in kW / kVAr; ``model`` is the specification's load model label
        (the linear model treats every load as constant power).
    s_base_kva : float
        Single-phase power base in kVA.
    """

    name: str
    base_kv_ll: float
    source_bus: str
    configs: dict
    lines: tuple
    loads: dict
    s_base_kva: float = 1000.0

    def __post_init__(self) -> None:
        buses = {self.source_bus}
        for i, (a, b, length, cfg) in enumerate(self.lines):
            if cfg not in self.configs:
                raise ValueError(f"lines[{i}] uses unknown configuration {cfg!r}")
            if not length > 0:
                raise ValueError(f"lines[{i}] length must be > 0 ft, got {length!r}")
            buses.update((a, b))
        for bus, (_, vals) in self.loads.items():
            if bus not in buses:
                raise ValueError(f"load at unknown bus {bus!r}")
            if len(vals) != 6:
                raise ValueError(f"load at bus {bus!r} must give 6 values (P, Q per branch)")
        if len(self.lines) != len(buses) - 1:
            raise ValueError(f"a radial feeder with {len(buses)} buses needs "
                             f"{len(buses) - 1} lines, got {len(self.lines)}")

    # ----------------------------------------------------------------- indexing
    @property
    def buses(self) -> tuple[str, ...]:
        """Non-source buses, sorted (the order of ``v``, ``p``, ``q``)."""
        names = {a for a, _, _, _ in self.lines} | {b for _, b, _, _ in self.lines}
        return tuple(sorted(names - {self.source_bus}))

    @property
    def B(self) -> int:
        """Number of non-source buses."""
        return len(self.buses)

    @property
    def v_base(self) -> float:
        """Line-to-neutral voltage base in volts."""
        return self.base_kv_ll * 1e3 / np.sqrt(3.0)

    @property
    def z_base(self) -> float:
        """Impedance base in ohm, ``V_b^2 / S_b``."""
        return self.v_base ** 2 / (self.s_base_kva * 1e3)

    @property
    def v0(self) -> np.ndarray:
        """Slack voltage ``[1, e^{-j 2pi/3}, e^{+j 2pi/3}]`` (per unit).

        Section V prints ``[1, 1 - j 2pi/3, 1 + j 2pi/3]``; the balanced positive-sequence
        phasors are the exponentials used here.
        """
        return np.exp(-2j * np.pi / 3 * np.arange(3))

    # ----------------------------------------------------------------- matrices
    def admittance(self) -> np.ndarray:
        """Three-phase bus admittance matrix in per unit, ``(3(B+1), 3(B+1))``.

        Node order: the source bus first (phases a, b, c), then :attr:`buses`.
        """
        order = (self.source_bus,) + self.buses
        pos = {b: i for i, b in enumerate(order)}
        n = 3 * len(order)
        Y = np.zeros((n, n), dtype=complex)
        for a, b, length, cfg in self.lines:
            conf = self.configs[cfg]
            miles = length / FT_PER_MILE
            Zs = conf.z_ohm_per_mile * miles / self.z_base
            Ysh = 1j * conf.b_us_per_mile * 1e-6 * miles * self.z_base
            Yser = np.linalg.inv(Zs)                 # 3x3 per segment, well conditioned
            ia, ib = slice(3 * pos[a], 3 * pos[a] + 3), slice(3 * pos[b], 3 * pos[b] + 3)
            Y[ia, ia] += Yser + Ysh / 2
            Y[ib, ib] += Yser + Ysh / 2
            Y[ia, ib] -= Yser
            Y[ib, ia] -= Yser
        return Y

    def nominal_injections(self) -> np.ndarray:
        """State ``x = [p; q]`` (per unit, length ``6B``) at the nominal spot loads.

        Injections are minus the loads; ``p`` and ``q`` are ordered bus by bus, branch
        ab, bc, ca (Section V).
        """
        p = np.zeros(3 * self.B)
        q = np.zeros(3 * self.B)
        idx = {b: i for i, b in enumerate(self.buses)}
        for bus, (_, vals) in self.loads.items():
            i = idx[bus]
            p[3 * i: 3 * i + 3] = -np.asarray(vals[0::2], dtype=float) / self.s_base_kva
            q[3 * i: 3 * i + 3] = -np.asarray(vals[1::2], dtype=float) / self.s_base_kva
        return np.concatenate([p, q])


def load_ieee37(s_base_kva: float = 1000.0) -> Feeder:
    """The IEEE 37-node test feeder from the package data (see the file's ``source``).

    The substation regulator and transformer are replaced by an ideal slack at bus 799;
    the in-line transformer XFM-1 and node 775, which carry no load, are left out. That
    leaves ``B = 35`` buses and a state of ``6B = 210`` injections.
    """
    text = resources.files("netsense.grid").joinpath("data/ieee37.json").read_text()
    raw = json.loads(text)
    configs = {}
    for name, c in raw["configurations"].items():
        z = np.array(c["z"], dtype=float)
        configs[name] = LineConfig(z[..., 0] + 1j * z[..., 1], np.asarray(c["b"], float))
    lines = tuple((a, b, float(L), cfg) for a, b, L, cfg in raw["lines"])
    loads = {bus: (v[0], tuple(float(x) for x in v[1:]))
             for bus, v in raw["loads"].items() if not bus.startswith("_")}
    return Feeder(name=raw["name"], base_kv_ll=float(raw["base_kv_ll"]),
                  source_bus=raw["source_bus"], configs=configs, lines=lines, loads=loads,
                  s_base_kva=s_base_kva)
