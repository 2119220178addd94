"""Topology sweep measurements against hand-computed values and an independent reference."""

from __future__ import annotations

import numpy as np
import pytest

from netsense import design_observer, random_structured
from netsense.graphs.aoi import aoi_stats, trigger_step, worst_index
from netsense.graphs.bounds import corollary1_bound, lemma3_bound, lemma5_bound, sharp_index_bound
from netsense.graphs.families import (
    RoundRobinRing,
    StaticGraph,
    make_graph_process,
    window_connectivity,
)
from netsense.graphs.processes import RandomJointlyConnected, check_joint_connectivity
from netsense.kernels.update import OMEGA
from netsense.observers.freshness import FreshnessObserver
from netsense.observers.run import relative_error, run_observer, steps_to_tolerance
from netsense.studies.sweep import SweepCase, run_case, sample_graphs


def reference_indices(graphs: np.ndarray) -> np.ndarray:
    """Eqs. (8)-(14) transcribed literally with Python loops; ``None`` is omega.

    Tie-break as documented in the freshness module: the smallest node index wins.
    """
    K, N, _ = graphs.shape
    tau = [[0 if i == j else None for j in range(N)] for i in range(N)]
    out = [tau]
    for k in range(K):
        new = [[None] * N for _ in range(N)]
        for j in range(N):
            for i in range(N):
                if i == j:
                    new[i][j] = 0
                    continue
                M = [l for l in range(N) if graphs[k, i, l] and tau[l][j] is not None]  # (8)
                if tau[i][j] is None:
                    if M:  # Case 1, eq. (9)
                        u = min(M, key=lambda l: (tau[l][j], l))
                        new[i][j] = tau[u][j] + 1
                    else:  # eq. (11)
                        new[i][j] = None
                else:
                    F = [l for l in M if tau[l][j] < tau[i][j]]  # (13)
                    if F:
                        u = min(F, key=lambda l: (tau[l][j], l))
                        new[i][j] = tau[u][j] + 1
                    else:  # eq. (14)
                        new[i][j] = tau[i][j] + 1
        tau = new
        out.append(tau)
    return np.array([[[OMEGA if v is None else v for v in row] for row in t] for t in out])


def _index_history(graphs: np.ndarray, n: int = 3, seed: int = 0) -> np.ndarray:
    """Batched freshness-index history for ``graphs`` (B, K, N, N)."""
    N = graphs.shape[2]
    plant = random_structured(n, N, rng=seed)
    obs = FreshnessObserver(design_observer(plant, deadbeat=True), batch_size=graphs.shape[0])
    return run_observer(obs, plant, graphs, np.ones((graphs.shape[0], n))).tau


def _first_trigger(tau: np.ndarray) -> np.ndarray:
    """[i, j]: first step at which tau_i^(j) is finite (single run)."""
    return np.argmax(tau != OMEGA, axis=0)


# ----------------------------------------------------------------------------- hand-computed
def test_static_ring_is_tight_for_lemma3():
    # 0->1->2->3->0 at every step: node j+d first hears source j at step d and keeps
    # tau = d for ever, so every index is triggered at N-1 = (N-1)T (Lemma 3 is tight) and
    # the worst index is N-1 (half of Lemma 5's 2(N-1)T).
    N = 4
    g = RoundRobinRing(N, 1).sequence(12)[None]
    tau = _index_history(g)
    assert trigger_step(tau).tolist() == [3] == [lemma3_bound(N, 1)]
    assert worst_index(tau, trigger_step(tau)).tolist() == [3]
    d = (np.arange(N)[:, None] - np.arange(N)[None, :]) % N  # distance j -> i
    assert np.array_equal(tau[-1, 0], d)
    assert np.array_equal(_first_trigger(tau[:, 0]), d)


def test_round_robin_ring_period2_hand_table():
    # N = 4, T = 2, forward: 0->1 and 2->3 at even k, 1->2 and 3->0 at odd k.
    # First trigger step of tau_i^(j), worked out by hand (rows i, columns j):
    #   substate 0: node 1 @1, node 2 @2, node 3 @3
    #   substate 1: node 2 @2, node 3 @3, node 0 @4
    #   substate 2: node 3 @1, node 0 @2, node 1 @3
    #   substate 3: node 0 @2, node 1 @3, node 2 @4
    hand = np.array([[0, 4, 2, 2],
                     [1, 0, 3, 3],
                     [2, 2, 0, 4],
                     [3, 3, 1, 0]])
    g = RoundRobinRing(4, 2).sequence(20)[None]
    tau = _index_history(g)
    assert np.array_equal(_first_trigger(tau[:, 0]), hand)
    assert trigger_step(tau).tolist() == [4]  # <= (N-1)T = 6
    # Steady state: node at distance d is refreshed to d every 2 steps -> worst d + 1 = 4.
    assert worst_index(tau, 4).tolist() == [4]
    assert lemma5_bound(4, 2) == 12


def test_token_ring_and_backward_ring():
    # Token ring (T = N, forward): source j's info runs around without waiting; the last
    # substate starts at step N-1, so everything is triggered at 2N-2; a node at distance
    # d is refreshed to d every N steps, so the worst index is (N-1) + (N-1) = 2N-2.
    for N in (3, 4, 5):
        tau = _index_history(RoundRobinRing(N, N).sequence(6 * N)[None])
        assert trigger_step(tau).tolist() == [2 * N - 2]
        assert worst_index(tau, trigger_step(tau)).tolist() == [2 * N - 2]
    # Backward schedule, N = T = 3: edges 2->0 @k≡0, 1->2 @k≡1, 0->1 @k≡2; each hop waits
    # two steps. Source 0: node 1 tau=1 @3, node 2 gets tau_1[4]+1 = 3 @5 -> trigger 5;
    # node 2 ages from 3 to 5 before each refresh -> worst index 5 (bound (N-1)T = 6).
    tau = _index_history(RoundRobinRing(3, 3, "backward").sequence(30)[None])
    assert trigger_step(tau).tolist() == [5]
    assert worst_index(tau, 5).tolist() == [5]
    # For T = N the backward ring needs (N-1)^2 + 1 steps: close to Lemma 3's (N-1)N.
    tau = _index_history(RoundRobinRing(5, 5, "backward").sequence(60)[None])
    assert trigger_step(tau).tolist() == [17]


def test_messages_and_adoptions_on_static_ring():
    N = 4
    plant = random_structured(3, N, rng=0)
    obs = FreshnessObserver(design_observer(plant, deadbeat=True), batch_size=1)
    tr = run_observer(obs, plant, RoundRobinRing(N, 1).sequence(10)[None], np.ones((1, 3)))
    assert np.all(tr.messages == N)  # one message per ring edge per step
    # Every non-source pair adopts from its predecessor once it has heard anything:
    # at step k the pairs at distance d <= k + 1 adopt -> min(k+1, N-1) * N pairs.
    assert tr.adoptions[:, 0].tolist() == [min(k + 1, N - 1) * N for k in range(10)]


# ----------------------------------------------------------------------------- reference
@pytest.mark.parametrize("family,T,param", [("random_jsc", 3, 0.2), ("gossip", 1, 0.0),
                                            ("markov", 1, 0.4), ("mobility", 1, 0.35)])
def test_indices_match_literal_reference(family, T, param):
    N = 5
    g = sample_graphs(make_graph_process(family, N, T, param), 3, 40, np.random.default_rng(1))
    tau = _index_history(g)
    for b in range(3):
        assert np.array_equal(tau[:, b], reference_indices(g[b]))


def test_bounds_hold_on_random_jsc():
    N, T, n = 5, 3, 4
    case = SweepCase("random_jsc", N, T, n=n, param=0.1, seeds=6, steps=120, seed=3)
    rows = run_case(case)
    for r in rows:
        assert r["assumption1"] and r["T_used"] == T
        assert 0 <= r["trigger"] <= lemma3_bound(N, T)
        assert r["worst_after_lemma3"] <= lemma5_bound(N, T)
        assert 0 <= r["steps_deadbeat"] <= corollary1_bound(n, N, T)
        assert r["steps_rho"] > 0


@pytest.mark.parametrize("family,N,T,param", [("random_jsc", 4, 4, 0.0), ("random_jsc", 5, 2, 0.2),
                                              ("gossip", 5, 1, 0.0), ("markov", 6, 1, 0.4),
                                              ("mobility", 5, 1, 0.3)])
def test_sharpened_index_bound_holds_and_is_attained(family, N, T, param):
    # NT - 1 (sharp_index_bound's proof) after (N-1)T, with the guaranteed or measured T.
    rows = run_case(SweepCase(family, N, T, n=3, param=param, seeds=8, steps=200, seed=1))
    held = [r for r in rows if r["assumption1"]]
    assert held
    for r in held:
        assert r["worst_after_lemma3"] <= sharp_index_bound(N, r["T_used"]) < r["bound_lemma5"]
    if (family, N, T) == ("random_jsc", 4, 4):
        assert max(r["worst_after_lemma3"] for r in rows) == 15  # = NT - 1: attained
    assert sharp_index_bound(4, 1) == 3  # the static ring's worst index (test above)


def test_deadbeat_error_vanishes_by_corollary1_on_static_graph():
    N, n = 4, 4
    plant = random_structured(n, N, rng=5)
    obs = FreshnessObserver(design_observer(plant, deadbeat=True), batch_size=2)
    K = int(corollary1_bound(n, N, 1)) + 5
    g = StaticGraph(RoundRobinRing(N, 1).sequence(1)[0]).sequence(K)
    tr = run_observer(obs, plant, np.stack([g, g]), np.random.default_rng(0).normal(size=(2, n)))
    rel = relative_error(tr)
    assert np.all(rel[int(corollary1_bound(n, N, 1)):] < 1e-9)


# ----------------------------------------------------------------------------- measures
def test_trigger_and_tolerance_on_synthetic_histories():
    tau = np.zeros((6, 2, 2, 2), dtype=int)
    tau[:3, 0, 0, 1] = OMEGA  # run 0 triggered at step 3
    tau[:, 1, 1, 0] = OMEGA  # run 1 never
    assert trigger_step(tau).tolist() == [3, -1]
    tau[4, 0, 1, 0] = 7
    assert worst_index(tau, np.array([3, 0])).tolist() == [7, 0]
    assert worst_index(tau, 5).tolist() == [0, 0]
    rel = np.array([[1.0, 1.0], [1e-9, 1.0], [1.0, 1e-9], [1e-9, 1e-9], [1e-9, 1e-9]])
    assert steps_to_tolerance(rel, 1e-6).tolist() == [3, 2]
    rel[-1, 1] = np.nan
    assert steps_to_tolerance(rel, 1e-6).tolist() == [3, -1]
    with pytest.raises(ValueError, match="eps"):
        steps_to_tolerance(rel, 0.0)


def test_aoi_stats_hand_values():
    seq = [OMEGA, 1, 2, 3, 1, 2, 1]
    tau = np.array(seq).reshape(7, 1, 1, 1)
    st = aoi_stats(tau)
    assert st["mean"][0, 0, 0] == pytest.approx(10 / 6)
    assert st["peak"][0, 0, 0] == pytest.approx((3 + 2) / 2)  # ages just before refreshes
    assert st["max"][0, 0, 0] == 3
    assert st["omega_fraction"][0, 0, 0] == pytest.approx(1 / 7)
    # never refreshed: no peak
    st = aoi_stats(np.arange(5).reshape(5, 1, 1, 1))
    assert np.isnan(st["peak"][0, 0, 0]) and st["max"][0, 0, 0] == 4


def test_window_connectivity_timeline():
    ring = RoundRobinRing(3, 3).sequence(9)
    seq = ring.copy()
    seq[3:6] = False  # second window empty
    assert window_connectivity(seq, 3).tolist() == [True, False, True]
    assert check_joint_connectivity(seq, 3).first_failure == (3, 6)


def test_processes_reproducible_and_validated():
    p = RandomJointlyConnected(5, 2, 0.1)
    assert np.array_equal(p.sequence(20, 4), p.sequence(20, 4))
    assert check_joint_connectivity(RoundRobinRing(6, 3, "backward").sequence(30), 3).holds
    with pytest.raises(ValueError, match="period"):
        RoundRobinRing(4, 5)
    with pytest.raises(ValueError, match="order"):
        RoundRobinRing(4, 2, "sideways")
    with pytest.raises(ValueError, match="family"):
        make_graph_process("hypercube", 4)
    with pytest.raises(ValueError, match="family"):
        SweepCase("hypercube", 4)
    with pytest.raises(ValueError, match="rho"):
        SweepCase("ring", 4, rho=1.5)
