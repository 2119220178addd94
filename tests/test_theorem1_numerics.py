"""Theorem 1 and Corollary 1 in floating point: properties over 200 random plants each.

The measurements are those of ``experiments/papers/freshness_theorem1_numerics.py`` (see its
docstring and ``docs/theory.md``): ``N`` in 3..10, ``T`` in 1..4, single- and multi-output sources,
stable and unstable plants with ``n`` up to 30, random jointly connected graphs.
"""

import numpy as np
import pytest
from experiment_loader import load_experiment

num = load_experiment("papers/freshness_theorem1_numerics")

COUNT = 200
EPS = float(np.finfo(float).eps)
#: The noise-free relative error may sit at rounding times the observer's noise gain,
#: ``c eps G`` with ``c`` measured up to 24 (median 1.5); a floor of any other origin (the
#: staircase's ~1e-13 left in the model, say) is 1e3-1e6 times larger than that.
FLOOR_FACTOR = 64


def _report(bad: list, what: str) -> str:
    return f"{len(bad)} of {COUNT} plants {what}: " + "; ".join(map(str, bad[:5]))


@pytest.mark.slow
def test_rate_is_theorem1s_on_every_plant():
    """With the plant at x = 0 the error runs alone: its tail decays at max rho_j."""
    chosen, skipped = num.cases(COUNT, radius=(0.5, 1.1), rho=0.5)
    assert skipped <= COUNT // 20  # pole placement fails only on a few large blocks
    bad = []
    for case in chosen:
        r = num.measure_rate(case)
        if not r["rate"] <= r["rho_max"] + 0.02:
            bad.append((case, round(r["rate"], 4), r["rho_max"]))
    assert not bad, _report(bad, "decay slower than max rho_j + 0.02")


@pytest.mark.slow
def test_deadbeat_error_vanishes_within_corollary1():
    """Deadbeat gains: from n + 2N(N-1)T on the error alone is gone (1e-12 of where it
    started), and with the plant running the relative error is at most 1e-12 or the
    rounding floor eps x noise gain."""
    chosen, _ = num.cases(COUNT, radius=(0.7, 1.1), offset=10_000)
    bad = []
    for case in chosen:
        r = num.measure_deadbeat(case)
        floor = max(1e-12, FLOOR_FACTOR * EPS * r["gain"])
        if not (r["alone_after_bound"] <= 1e-12 and r["after_bound"] <= floor
                and r["nilpotency"] <= 1e-13):
            bad.append((case, r))
    assert not bad, _report(bad, "not exact after Corollary 1's bound")


@pytest.mark.slow
def test_no_error_floor_beyond_rounding():
    """Theorem 1's gains on plants with spectral radius 0.9-1.1: the relative error over
    steps 240-360 is at most 1e-12 or the rounding floor eps x noise gain."""
    chosen, skipped = num.cases(COUNT, radius=(0.9, 1.1), offset=20_000, rho=0.5)
    assert skipped <= COUNT // 20
    bad = []
    for case in chosen:
        r = num.measure_floor(case)
        if not r["floor"] <= max(1e-12, FLOOR_FACTOR * EPS * r["gain"]):
            bad.append((case, r))
    assert not bad, _report(bad, "with a floor above rounding")


def test_one_state_deadbeat_gains_are_minimum_norm():
    """Every 1-state block's deadbeat gain is within 10x of |a| / ||c|| (it is equal)."""
    ratios = [r for case in num.cases(COUNT, radius=(0.5, 1.1), offset=30_000)[0]
              for r in num.one_state_gain_ratios(case)]
    assert len(ratios) >= COUNT
    assert max(ratios) <= 10
    assert np.allclose(ratios, 1.0, rtol=1e-12)


def test_envelope_rate_recovers_a_known_rate():
    """The fit on window maxima gives the rate of a geometric sequence with a sawtooth."""
    k = np.arange(600)
    log_err = k * np.log(0.45) + 5.0 * (k % 7 == 3)  # bursts every 7 steps, window 7
    assert num.envelope_rate(log_err, 100, 7) == pytest.approx(0.45, abs=1e-9)


# ---------------------------------------------------------------- precision of the floor
#: One of theorem1_numerics' floor plants (offset 20_000) with a float64 floor far above
#: 1e-12 (3.8e-10 with a plain plant simulation; G = 9.1e5, the largest of the 200):
#: n = 12, N = 9, T = 4, nine multi-output sources.
FLOOR_PLANT = dict(seed=20013, single_output=False, radius=(0.9, 1.1))


def test_floor_scales_with_the_unit_roundoff():
    """The dtype-generic reference observer is the package's observer (float64: the same
    choices and indices, one step within rounding of the largest term, a whole run apart
    by far less than the floor); run in longdouble on a plant whose Lemma 1 structure is
    exact there, its floor drops with eps (2048x smaller; at least 100x asserted) to below
    1e-12, while a longdouble observer on the float64 plant keeps the float64 floor."""
    prec = load_experiment("papers/freshness_theorem1_precision")
    case = prec.num.sample_case(**FLOOR_PLANT)
    assert (case.n, case.N, case.T, case.sources) == (12, 9, 4, 9)
    agree = prec.agreement(case)
    assert agree["choices_equal"]
    assert agree["one_step_eps"] <= 4
    f = prec.floors(case, {k: prec.VARIANTS[k] for k in ("f64", "ld", "f64/ld")})
    assert f["f64"] > 1e-11
    assert agree["run"] <= 0.1 * f["f64"]
    assert f["ld"] <= f["f64"] / 100
    assert f["ld"] < 1e-12
    assert f["f64/ld"] >= 0.5 * f["f64"]  # the observer's arithmetic is not the cause
