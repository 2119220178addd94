"""OpenDSS script generation from a :class:`~netsense.grid.feeder.Feeder`, and a solve.

:func:`opendss_script` writes the feeder -- our own data, not any shipped OpenDSS file --
as an OpenDSS script: a near-ideal balanced source at the slack bus, one line code per
configuration (``units=mi``, capacitance from the susceptance), one line per segment
(``units=ft``) and one single-phase delta constant-power load per loaded branch.
:func:`solve_opendss` runs it through ``opendssdirect.py`` (imported here, lazily; install
the ``grid`` extra) and returns the phase-to-ground voltages in per unit, in the node order
of :mod:`netsense.grid.linear`, for comparison with the linear model of eq. (39).
"""

from __future__ import annotations

import numpy as np

from netsense.grid.feeder import Feeder

__all__ = ["opendss_script", "solve_opendss"]

_BRANCH_NODES = ("1.2", "2.3", "3.1")


def _lower(M: np.ndarray) -> str:
    rows = [" ".join(f"{M[i, j]:.10g}" for j in range(i + 1)) for i in range(3)]
    return "(" + " | ".join(rows) + ")"


def opendss_script(feeder: Feeder, x: np.ndarray | None = None,
                   frequency: float = 60.0) -> str:
    """OpenDSS commands describing ``feeder`` with injections ``x = [p; q]`` (per unit).

    Parameters
    ----------
    feeder : Feeder
        The network.
    x : (6B,) array, optional
        Delta injections; default the nominal spot loads. Loads are ``-x`` scaled by the
        power base, as constant-power (model 1) delta loads with ``vminpu = 0.5`` so that
        OpenDSS keeps them constant-power.
    frequency : float
        System frequency in Hz (converts susceptance to capacitance).
    """
    B = feeder.B
    x = feeder.nominal_injections() if x is None else np.asarray(x, dtype=float)
    if x.shape != (6 * B,):
        raise ValueError(f"x must have shape ({6 * B},), got {x.shape}")
    kv = feeder.base_kv_ll
    lines = [
        "Clear",
        f"Set DefaultBaseFrequency={frequency:g}",
        f"New Circuit.netsense_feeder basekv={kv:g} pu=1.0 phases=3 bus1={feeder.source_bus} "
        "angle=0 MVAsc3=1e9 MVAsc1=1e9",
    ]
    for name, cfg in feeder.configs.items():
        C_nf = cfg.b_us_per_mile / (2 * np.pi * frequency) * 1e3        # uS -> nF
        lines.append(
            f"New Linecode.cfg{name} nphases=3 basefreq={frequency:g} units=mi "
            f"rmatrix={_lower(cfg.z_ohm_per_mile.real)} "
            f"xmatrix={_lower(cfg.z_ohm_per_mile.imag)} cmatrix={_lower(C_nf)}")
    for k, (a, b, length, cfg) in enumerate(feeder.lines):
        lines.append(f"New Line.seg{k} phases=3 bus1={a}.1.2.3 bus2={b}.1.2.3 "
                     f"linecode=cfg{cfg} length={length:g} units=ft")
    S = feeder.s_base_kva
    for i, bus in enumerate(feeder.buses):
        for ph in range(3):
            p = -x[3 * i + ph] * S
            q = -x[3 * B + 3 * i + ph] * S
            if p == 0 and q == 0:
                continue
            lines.append(f"New Load.d{bus}_{ph} bus1={bus}.{_BRANCH_NODES[ph]} phases=1 "
                         f"conn=delta model=1 kv={kv:g} kw={p:.10g} kvar={q:.10g} "
                         "vminpu=0.5 vmaxpu=1.5")
    lines += [f"Set VoltageBases=[{kv:g}]", "CalcVoltageBases", "Set maxiterations=100",
              "Solve"]
    return "\n".join(lines)


def solve_opendss(feeder: Feeder, x: np.ndarray | None = None) -> np.ndarray:
    """Solve the feeder in OpenDSS; returns ``(3B,)`` complex per-unit voltages.

    Raises
    ------
    ImportError
        If ``opendssdirect.py`` is not installed (``pip install netsense[grid]``).
    RuntimeError
        If OpenDSS reports that the solution did not converge.
    """
    try:
        import opendssdirect as dss
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("solve_opendss needs opendssdirect.py: pip install "
                          "'netsense[grid]'") from exc
    for cmd in opendss_script(feeder, x).splitlines():
        dss.Text.Command(cmd)
    if not dss.Solution.Converged():
        raise RuntimeError("OpenDSS power flow did not converge")
    names = [n.lower() for n in dss.Circuit.AllNodeNames()]
    raw = np.asarray(dss.Circuit.AllBusVolts(), dtype=float)
    volts = dict(zip(names, raw[0::2] + 1j * raw[1::2], strict=True))
    v = np.array([volts[f"{bus}.{ph}"] for bus in feeder.buses for ph in (1, 2, 3)])
    return v / feeder.v_base
