"""Equalized-recovery design (Proposition 1) and run-time estimator (eqs. (4)-(5)).

Oracles: closed-form optimal levels of scalar plants worked out by hand, and the error map
of eq. (9) built from the Appendix's stacked matrices (independent of the tree-based LP).
"""

import dataclasses

import numpy as np
import pytest

from netsense.estimators.equalized import (
    EqualizedRecoveryEstimator,
    causality_mask,
    constraint_violation,
    design_switching,
    prefix_constraints,
    worst_case_levels,
)
from netsense.estimators.equalized_design import EqualizedProblem, design
from netsense.sensing.delays import DelayLanguage

ETA = 0.1


def scalar(words, a=2.0):
    return EqualizedProblem(A=[[a]], C=[[1.0]], language=DelayLanguage.from_words(words),
                            eta_v=ETA)


def test_scalar_one_step_closed_form():
    # x~_1 = (2 + m) x~_0 + m v: feasible iff |2+m| mu + |m| eta <= mu; best m = -2,
    # mu_min = 2 eta; J = mu_1 + mu_2,0 + mu_2,1 = 3 mu_1 (levels equal mu_1)
    d = design(scalar(["0"]), rtol=1e-5)
    assert d.mu1 == pytest.approx(2 * ETA, rel=1e-4)
    assert d.cost == pytest.approx(3 * d.mu1, rel=1e-9)
    q = d.tree.children[0][1]
    assert d.M_rows[q][0, 0] == pytest.approx(-2.0, abs=1e-3)
    trace = np.array(d.stats["search"])
    assert trace[trace[:, 1] == 0, 0].max() < trace[trace[:, 1] == 1, 0].min()


def test_scalar_delayed_word_closed_form():
    # word "10": nothing at step 0 so x~_1 = 2 x~_0 (level 2 mu); at step 1
    # x~_2 = (4 + M10 + 2 M11) x~_0 + M10 v0 + M11 v1 needs mu >= 2 eta (M11 = -2).
    # word "00" is feasible at 2 eta as well (M00 = -2, M10 = 4, M11 = -2).
    P = scalar(["00", "10"])
    d = design(P, rtol=1e-5)
    assert d.mu1 == pytest.approx(2 * ETA, rel=1e-3)
    late = d.tree.children[0][0]
    assert d.level[late] == pytest.approx(2 * d.mu1, rel=1e-6)
    fixed = design(P, mu1=0.5)
    assert fixed.mu1 == 0.5 and fixed.level[fixed.tree.children[0][0]] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="infeasible"):
        design(P, mu1=0.1)


def random_problem(seed=0, s0=True, ltv=False):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(2, 2))
    A *= 1.1 / max(abs(np.linalg.eigvals(A)))
    if ltv:  # A_k differs at every step of the horizon
        A = A + 0.1 * rng.normal(size=(3, 2, 2))
    return EqualizedProblem(
        A=A, C=rng.normal(size=(1, 2)), W=0.5 * np.eye(2), V=[[1.0]], eta_w=0.02, eta_v=0.05,
        L=0.2 * rng.normal(size=(2, 1)), s0=np.array([0.01, -0.02]) if s0 else None,
        language=DelayLanguage.each_delayed_at_most(1, 3))


@pytest.mark.parametrize("ltv", [False, True])
def test_levels_match_eq9_error_map(ltv):
    P = random_problem(ltv=ltv)
    d = design(P, mu1=1.0)
    c_viol, d_viol = constraint_violation(d)
    assert c_viol == 0.0 and d_viol == 0.0
    for a in range(len(d.events)):
        wc = worst_case_levels(P, *d.stacked(a), d.mu1)
        assert wc[-1] <= d.mu1 + 1e-6
        # interior levels are minimised, so each equals max(mu_1, exact worst case)
        np.testing.assert_allclose(d.mu2[a, 1:-1], np.maximum(d.mu1, wc[1:-1]), atol=1e-6)


def test_constraint_sets_of_examples_3_and_5():
    E = DelayLanguage.each_delayed_at_most(2, 2).event_language()
    pairs = prefix_constraints(E)
    assert sorted(pairs) == [(0, 1, 1), (2, 3, 1), (2, 4, 1), (2, 5, 1), (3, 4, 1),
                             (3, 5, 1), (4, 5, 1)]
    np.testing.assert_array_equal(causality_mask(E.event_matrix(1), 1, 1),
                                  [[True, False], [True, False]])
    assert causality_mask(E.event_matrix(0), 2, 3).shape == (4, 6)
    # the fixed L acts only where the data of the step is on time (D for L)
    d = design(random_problem(s0=False), mu1=1.0)
    for q in range(1, len(d.tree)):
        k = d.tree.depth(q) - 1
        on_time = format(d.tree.prefixes[q][-1], f"0{k + 1}b")[-1] == "1"
        assert np.any(d.L_eff[q] != 0) == on_time
        assert np.all(d.nu[q] == 0)  # s0 = 0: offsets fixed to zero


def corner_run(est, P, rng, sampler, steps, mu1):
    x = rng.normal(size=P.n)
    est.reset(x - mu1 * rng.choice([-1.0, 1.0], size=P.n))
    zs, worst, modes = {}, 0.0, set()
    for k in range(steps):
        modes.add(est.mode)
        zs[k] = P.C[0] @ x + P.eta_v * rng.choice([-1.0, 1.0], size=P.p)
        x_hat = est.step({i: zs[i] for i in sampler.next()})
        t = k % P.T  # periodic reuse: the plant's A_t repeats with the horizon
        x = P.A[t] @ x + P.W[t] @ (P.eta_w * rng.choice([-1.0, 1.0], size=P.W.shape[2]))
        worst = max(worst, np.abs(x - x_hat).max() - est.bound)
    return worst, modes


@pytest.mark.parametrize("ltv, missing", [(False, False), (True, False), (False, True)])
def test_bounds_hold_in_simulation_periodic(ltv, missing):
    P = random_problem(ltv=ltv)
    if missing:  # at most one of the three measurements never arrives
        P = dataclasses.replace(P, language=DelayLanguage.at_most_missing(1, 3))
    d = design(P)
    est = EqualizedRecoveryEstimator(d)
    rng = np.random.default_rng(1)
    for _ in range(30):
        sampler = P.language.channel().sampler(rng)
        assert corner_run(est, P, rng, sampler, 4 * P.T, d.mu1)[0] <= 1e-7


def test_bounds_hold_in_simulation_switching():
    # horizon-1 invariance needs enough outputs: two sensors on a 2-state plant
    P = EqualizedProblem(A=[[1.1, 0.3], [0.0, 0.9]], C=np.eye(2), eta_v=0.05,
                         W=np.eye(2), eta_w=0.01,
                         language=DelayLanguage.each_delayed_at_most(1, 3))
    rec, perf = design_switching(P)
    assert rec.mu1 == pytest.approx(perf.mu1)
    est = EqualizedRecoveryEstimator(rec, perf)
    rng = np.random.default_rng(2)
    chan = DelayLanguage.from_words(["000", "010", "100"]).channel(truncate=False)
    modes = set()
    for _ in range(20):
        worst, seen = corner_run(est, P, rng, chan.sampler(rng), 12, rec.mu1)
        assert worst <= 1e-7
        modes |= seen
    assert modes == {"performance", "recovery"}
    with pytest.raises(ValueError, match="same mu1"):
        EqualizedRecoveryEstimator(rec, design(perf.problem, mu1=2 * perf.mu1))
    with pytest.raises(ValueError, match="start"):
        EqualizedRecoveryEstimator(design(P, mu1=rec.mu1), perf)


def test_bad_inputs_raise_before_state_changes():
    with pytest.raises(ValueError, match="C must have blocks"):
        EqualizedProblem(A=np.eye(2), C=np.ones((1, 3)), language=DelayLanguage.from_words(["0"]))
    with pytest.raises(ValueError, match="eta_v"):
        EqualizedProblem(A=[[1.0]], C=[[1.0]], eta_v=-1,
                         language=DelayLanguage.from_words(["0"]))
    with pytest.raises(ValueError, match="s0"):
        EqualizedProblem(A=[[1.0]], C=[[1.0]], s0=[0, 0],
                         language=DelayLanguage.from_words(["0"]))
    with pytest.raises(ValueError, match="sequence of T"):
        EqualizedProblem(A=np.ones((3, 1, 1)), C=[[1.0]],
                         language=DelayLanguage.from_words(["00"]))
    d = design(scalar(["00"]), mu1=1.0)
    est = EqualizedRecoveryEstimator(d)
    est.reset(np.array([0.3]))
    for bad, match in [({1: [0.0]}, "<= k"), ({0: [0.0, 1.0]}, "1 finite"),
                       ({0: [np.nan]}, "finite")]:
        with pytest.raises(ValueError, match=match):
            est.step(bad)
        assert est.k == 0 and est.estimate[0] == 0.3
    with pytest.raises(RuntimeError, match="not in the design's language"):
        est.step({})  # "00" promises data 0 on time
    assert est.k == 0 and est.estimate[0] == 0.3


def test_feasibility_is_monotone_in_mu1_on_a_grid():
    from netsense.estimators.equalized_design import build_lp, solve_fixed

    P = random_problem(seed=3, s0=False)
    tpl = build_lp(P)
    mu_min = design(P, rtol=1e-3).mu1
    grid = mu_min * np.array([0.25, 0.5, 0.9, 0.99, 1.01, 1.5, 3.0, 10.0])
    feas = [solve_fixed(P, m, template=tpl, feasibility_only=True) is not None for m in grid]
    assert feas == [False] * 4 + [True] * 4


def test_cli_command_reports_hand_checked_levels(capsys):
    from netsense.cli import main

    # {"00", "10"} on x+ = 2x: mu_1 = 2 eta; J = mu_1 + 2 mu_1 (k=0) + (mu_1 + 2 mu_1) (k=1)
    # + 2 mu_1 (k=2) = 8 mu_1
    assert main(["equalized", "--A", "[[2.0]]", "--C", "[[1.0]]", "--language", "00,10",
                 "--eta-v", "0.1", "--mu1", "0.25"]) == 0
    out = capsys.readouterr().out
    assert "mu_1 = 0.25 " in out and "max mu_2 = 0.5 " in out and "J = 2\n" in out
    assert main(["equalized", "--A", "[[2.0]]", "--C", "[[1.0]]", "--language",
                 "each:x:3"]) == 2  # one line, exit code 2 (netsense.cli)
    assert "each:M:T" in capsys.readouterr().err


def test_estimator_pickles_mid_window_and_continues_identically():
    import pickle

    P = random_problem()
    est = EqualizedRecoveryEstimator(design(P, mu1=1.0))
    est.reset(np.zeros(2))
    est.step({})
    twin = pickle.loads(pickle.dumps(est))
    for e in (est, twin):
        e.step({0: [0.3], 1: [0.1]})
    np.testing.assert_array_equal(est.estimate, twin.estimate)
    assert est.bound == twin.bound and est.node == twin.node
