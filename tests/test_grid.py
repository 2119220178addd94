"""Feeder data, admittance matrix, linear power flow (39)-(40) and meters (41)-(43)."""

from __future__ import annotations

import numpy as np
import pytest

from netsense.estimators import online_analysis as oa
from netsense.grid import Feeder, LineConfig, linearize, load_ieee37, solve_power_flow
from netsense.grid.feeder import FT_PER_MILE
from netsense.grid.linear import delta_incidence
from netsense.grid.meters import PMU, SMART_METER, GridMetering, meter_rows, selection_matrix


def _two_bus(z_ohm_per_mile=0.5 + 0.25j, b_us=0.0, load=(300.0, 100.0)):
    """Source 'S' -- one mile of uncoupled line -- bus 'L' with an ab delta load."""
    cfg = LineConfig(np.eye(3) * z_ohm_per_mile, np.full(3, b_us))
    return Feeder(name="two-bus", base_kv_ll=4.8, source_bus="S", configs={"c": cfg},
                  lines=(("S", "L", FT_PER_MILE, "c"),),
                  loads={"L": ("D-PQ", (load[0], load[1], 0, 0, 0, 0))})


def test_two_bus_linear_model_matches_hand_formula():
    f = _two_bus()
    lp = linearize(f)
    np.testing.assert_allclose(lp.w, f.v0, atol=1e-14)          # no shunt: w = v0
    x = f.nominal_injections()                                   # p_ab = -0.3, q_ab = -0.1
    s = x[0] + 1j * x[3]
    z = (0.5 + 0.25j) / f.z_base
    d = f.v0[0] - f.v0[1]                                        # sqrt(3) e^{j pi/6}
    # node a receives i_ab, node b gives it back: v - w = z [i, -i, 0], i = conj(s / d)
    i = np.conj(s / d)
    np.testing.assert_allclose(lp.voltages(x) - lp.w, z * np.array([i, -i, 0]), atol=1e-14)
    assert abs(d) == pytest.approx(np.sqrt(3))


def test_two_bus_nonlinear_solution_balances_power():
    f = _two_bus(load=(900.0, 400.0))
    x = f.nominal_injections()
    v = solve_power_flow(f, x)
    Y = f.admittance()
    i_node = Y[3:, :3] @ f.v0 + Y[3:, 3:] @ v
    # current injected at a equals minus that at b; c carries none
    assert abs(i_node[2]) < 1e-12
    assert i_node[0] == pytest.approx(-i_node[1], abs=1e-12)
    s_ab = (v[0] - v[1]) * np.conj(i_node[0])
    assert s_ab == pytest.approx(x[0] + 1j * x[3], abs=1e-11)


def test_admittance_structure():
    f = _two_bus(b_us=100.0)
    Y = f.admittance()
    np.testing.assert_allclose(Y, Y.T, atol=1e-15)               # reciprocal network
    # equal voltages at both ends: only the shunt halves draw current
    u = np.array([1.0, -0.5 + 0.2j, 0.3j])
    ysh = 1j * 100e-6 * f.z_base
    np.testing.assert_allclose(Y @ np.concatenate([u, u]), np.concatenate([u, u]) * ysh / 2,
                               atol=1e-14)


def test_delta_incidence_kernel():
    H = delta_incidence(2)
    np.testing.assert_allclose(H @ np.ones(6), 0)                # common mode is invisible
    assert np.linalg.matrix_rank(H) == 4


def test_ieee37_transcription_against_spec_totals():
    f = load_ieee37()
    assert f.B == 35 and len(f.lines) == 35
    kw = np.sum([v[0::2] for _, v in f.loads.values()], axis=0)
    kvar = np.sum([v[1::2] for _, v in f.loads.values()], axis=0)
    # totals of the spot-load table of the public specification
    np.testing.assert_allclose(kw, [727, 639, 1091])
    np.testing.assert_allclose(kvar, [357, 314, 530])
    total_ft = sum(L for _, _, L, _ in f.lines)
    assert total_ft == pytest.approx(18010.0)      # segment table sum (35 segments, in ft)
    z723 = f.configs["723"].z_ohm_per_mile
    assert z723[0, 0] == pytest.approx(1.2936 + 0.6713j)


def test_linearisation_error_is_second_order_on_ieee37():
    f = load_ieee37()
    lp = linearize(f)
    x = f.nominal_injections()
    errs = [np.abs(solve_power_flow(f, a * x) - lp.voltages(a * x)).max() for a in (0.2, 0.4)]
    assert errs[1] / errs[0] == pytest.approx(4.0, rel=0.1)
    # magnitudes: K is the derivative of |v| at zero load (finite difference, eps = 1e-4)
    eps = 1e-4
    dmag = (np.abs(solve_power_flow(f, eps * x)) - np.abs(lp.w)) / eps
    np.testing.assert_allclose(dmag, lp.K @ x, rtol=2e-3, atol=1e-6)


def test_meter_rows_follow_eqs_42_43():
    B = 4
    sm = meter_rows(B, 2, SMART_METER)
    pmu = meter_rows(B, 2, PMU)
    assert sm.size == 9 and pmu.size == 15
    np.testing.assert_array_equal(sm[:3], 2 * 12 + np.array([6, 7, 8]))     # |v| block
    np.testing.assert_array_equal(pmu[:3], [6, 7, 8])                        # Re v block
    S = selection_matrix(B, [(2, SMART_METER), (0, PMU)])
    assert S.shape == (24, 60) and np.all(S.sum(axis=1) == 1)


def test_metering_gives_assumption_1_with_tau_the_period_and_noise_levels():
    f = _two_bus()
    lp = linearize(f)
    gm = GridMetering(lp, meters=((0, SMART_METER),), phases=(5,),
                      x_ref=f.nominal_injections())
    sens = gm.sensing()
    A, Q, b = sens.stack([True])
    # S Phi for a smart meter contains the identity on p and q (Lemma 3)
    np.testing.assert_allclose(A[3:], np.eye(6))
    fast = GridMetering(lp, meters=((0, PMU),), phases=(7,), x_ref=f.nominal_injections())
    pattern = fast.arrivals.schedule(150)
    fs = fast.sensing()
    assert oa.smallest_tau([fs.stack(m)[0] for m in pattern]) == PMU.period_s
    rng = np.random.default_rng(0)
    x = np.tile(f.nominal_injections(), (20000, 1))
    y = gm.measure(x, [0], rng)
    z = lp.quantities(x[0])[gm.rows(0)]
    rel = (y - z) / gm.scale(lp.quantities(x[0]))[gm.rows(0)]
    assert np.abs(rel).max() <= 3 * SMART_METER.sigma_rel + 1e-15       # truncated
    assert rel.std(axis=0) == pytest.approx(
        np.full(9, SMART_METER.sigma_rel * 0.9866), rel=0.03)          # var of N trunc. 3
    np.testing.assert_allclose(np.sqrt(np.diag(Q)), gm.sigma(), rtol=1e-12)


def test_grid_inputs_are_checked():
    cfg = LineConfig(np.eye(3), np.zeros(3))
    with pytest.raises(ValueError, match="unknown configuration"):
        Feeder("x", 4.8, "S", {"c": cfg}, (("S", "L", 10.0, "d"),), {})
    with pytest.raises(ValueError, match="radial"):
        Feeder("x", 4.8, "S", {"c": cfg}, (("S", "L", 10.0, "c"), ("L", "S", 5.0, "c")), {})
    with pytest.raises(ValueError, match="6B"):
        linearize(_two_bus()).voltages(np.zeros(5))
    with pytest.raises(ValueError, match="bus index"):
        meter_rows(3, 3, PMU)


def test_cli_prints_script_built_from_our_data(capsys):
    from netsense.cli import main

    assert main(["grid", "script", "--load-scale", "0.5"]) == 0
    out = capsys.readouterr().out
    assert out.count("New Line.") == 35
    # 0.5 x the 350 kW load on branch ca of bus 701
    assert "New Load.d701_2 bus1=701.3.1 phases=1 conn=delta model=1 kv=4.8 kw=175 " in out
