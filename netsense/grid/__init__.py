"""Distribution-grid case of the online estimator (Section V/VII of the asynchronous paper).

:mod:`.feeder` (feeder data, per unit, bus admittance matrix; the IEEE 37-node feeder in
``data/ieee37.json``), :mod:`.linear` (linearised power flow around the zero-load profile,
eqs. (39)-(40), and a nonlinear fixed-point solver), :mod:`.meters` (smart meters and
PMUs, eqs. (41)-(44)), :mod:`.opendss` (OpenDSS script generation and validation through
``opendssdirect.py``, imported lazily; install the ``grid`` extra).

Tool layer (a case study). May import every layer up to :mod:`netsense.env`.
"""

from netsense.grid.feeder import Feeder, LineConfig, load_ieee37
from netsense.grid.linear import LinearPowerFlow, linearize, solve_power_flow

__all__ = ["Feeder", "LineConfig", "LinearPowerFlow", "linearize", "load_ieee37",
           "solve_power_flow"]
