"""Smoke-size runs of the section IV experiments, asserting the qualitative findings.

Tolerances: a method comparison counts when the paired difference of time-averaged MSE
(t in [100, 200], 600 runs, common random numbers) is at least 3 standard errors from 0.
"""

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments" / "papers"))

import robust_droppings_fig1  # noqa: E402
import robust_droppings_fig2  # noqa: E402


@pytest.fixture(scope="module")
def droppings(tmp_path_factory):
    out = tmp_path_factory.mktemp("robust")
    res = robust_droppings_fig1.main(["--runs", "600", "--steps", "200", "--out", str(out),
                                      "--mu-sweep", "", "--seed", "11"])
    return out, res


def z(summary, case, key):
    diff, se = summary[case][key]
    return diff / se


def test_droppings_writes_outputs(droppings):
    out, _ = droppings
    for name in ("robust_droppings_mse.csv", "robust_droppings_summary.csv",
                 "robust_droppings.png"):
        assert (out / name).stat().st_size > 0
    rows = np.genfromtxt(out / "robust_droppings_mse.csv", delimiter=",", names=True)
    assert rows.shape == (201,) and len(rows.dtype.names) == 10


def test_kfio_beats_kf_in_every_case(droppings):
    _, res = droppings
    for case in robust_droppings_fig1.CASES:
        assert z(res["summary"], case, "KFIO-KF") < -3


def test_rseio_beats_kf_and_kfio_for_large_errors(droppings):
    _, res = droppings
    assert z(res["summary"], (10.0, 0.8), "RSEIO-KFIO") < -3
    assert z(res["summary"], (10.0, 0.8), "RSEIO-KF") < -3


def test_kfio_beats_rseio_for_small_errors_and_mu_08(droppings):
    _, res = droppings
    assert z(res["summary"], (1.0, 0.8), "RSEIO-KFIO") > 3


def test_mu_095_gap_is_smaller_but_not_a_win(droppings):
    """The paper says RSEIO is slightly better at mu = 0.95; a faithful run finds the gap
    to KFIO shrinks as mu -> 1 but RSEIO is not better (see docs/robust.md)."""
    s = droppings[1]["summary"]
    assert s[(1.0, 0.95)]["RSEIO-KFIO"][0] < 0.5 * s[(1.0, 0.8)]["RSEIO-KFIO"][0]
    assert z(s, (1.0, 0.95), "RSEIO-KFIO") > -2


def test_theorem1_typo_check_separates_forms(droppings):
    typo = droppings[1]["typo"]
    assert typo["implemented"] < 1e-10 < 1e-3 < typo["as_printed"]


def test_p0_independence_smoke(tmp_path):
    res = robust_droppings_fig2.main(["--runs", "300", "--steps", "300", "--out",
                                      str(tmp_path), "--no-plot"])
    assert (tmp_path / "robust_p0_independence.csv").stat().st_size > 0
    # all KS / AD p-values above 0.001 (12 tests at a fixed seed)
    assert min(r["p_value"] for r in res["tests"]) > 1e-3
    # common arrivals: the four P_{t|t} collapse onto one another (contraction)
    assert res["dist"][0].max() > 5 and res["dist"][-1].max() < 1e-9


def test_p0_tests_have_power_before_convergence():
    """Negative control: after 3 steps the P_0 dependence is still visible to the KS test."""
    P, _ = robust_droppings_fig2.final_pcm((1.0, 100.0), 300, 3, (1, 2))
    assert stats.ks_2samp(P[0, :, 0, 0], P[1, :, 0, 0]).pvalue < 1e-6
