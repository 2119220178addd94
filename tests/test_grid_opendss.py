"""Linear model vs a full nonlinear solve in OpenDSS of the same (our own) feeder data."""

from __future__ import annotations

import numpy as np
import pytest

from netsense.grid import linearize, load_ieee37, solve_power_flow
from netsense.grid.opendss import opendss_script

pytest.importorskip("opendssdirect")
from netsense.grid.opendss import solve_opendss  # noqa: E402


def test_script_is_generated_from_our_data():
    f = load_ieee37()
    script = opendss_script(f)
    assert script.count("New Line.") == len(f.lines)
    assert script.count("New Load.") == sum(
        sum(1 for k in range(3) if vals[2 * k] or vals[2 * k + 1]) for _, vals in f.loads.values())
    assert "Redirect" not in script and "shared" not in script


def test_opendss_agrees_with_zero_load_profile_and_own_solver():
    f = load_ieee37()
    lp = linearize(f)
    np.testing.assert_allclose(solve_opendss(f, np.zeros(6 * f.B)), lp.w, atol=1e-8)
    x = f.nominal_injections()
    v_dss = solve_opendss(f, x)
    # our Z-bus fixed point and OpenDSS solve the same equations (OpenDSS tolerance ~1e-6)
    np.testing.assert_allclose(solve_power_flow(f, x), v_dss, atol=1e-5)


def test_linear_model_voltage_error_is_small_and_second_order():
    f = load_ieee37()
    lp = linearize(f)
    x = f.nominal_injections()
    e1 = np.abs(lp.voltages(x) - solve_opendss(f, x)).max()
    e_half = np.abs(lp.voltages(x / 2) - solve_opendss(f, x / 2)).max()
    # the nominal feeder without regulator drops to ~0.94 pu; the first-order model must
    # stay within 0.5 % and its error must scale with the square of the loading
    assert e1 < 5e-3
    assert e1 / e_half == pytest.approx(4.0, rel=0.15)
