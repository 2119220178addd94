"""The freshness-index observer against the paper: eqs. (7)-(14), Lemmas 3 and 5,
Theorem 1 and Corollary 1."""

import numpy as np
import pytest

from netsense import (
    OMEGA,
    FreshnessObserver,
    RandomJointlyConnected,
    UniformNoise,
    design_observer,
    fig1_graphs,
    fig1_scalar,
    random_structured,
)
from netsense.systems.plants import Plant


def reference_step(des, Z, tau, y, adj):
    """Eqs. (7)-(14) written out with plain loops over agents and substates (oracle)."""
    d = des.decomposition
    N = d.num_agents
    Zn, taun = Z.copy(), tau.copy()
    for i in range(N):
        for j in range(N):
            b = d.block(j)
            lower = d.A_bar[b, :] @ Z[i] - d.A_bar[b, b] @ Z[i][b]  # sum_q A_jq z_i^(q)
            if i == j:
                if d.sizes[j]:
                    innov = y[j][: d.C_bar[j].shape[0]] - d.C_bar[j] @ Z[j]
                    Zn[i][b] = d.A_bar[b, :] @ Z[i] + des.gains[j] @ innov  # eq. (7)
                taun[i, j] = 0
                continue
            M = [l for l in range(N) if adj[i, l] and tau[l, j] != OMEGA]  # eq. (8)
            if tau[i, j] != OMEGA:
                M = [l for l in M if tau[l, j] < tau[i, j]]  # eq. (13)
            if M:
                u = min(M, key=lambda l: (tau[l, j], l))  # freshest, smallest id on ties
                taun[i, j] = tau[u, j] + 1  # eq. (9)
                Zn[i][b] = d.A_bar[b, b] @ Z[u][b] + lower  # eq. (10)
            else:
                taun[i, j] = OMEGA if tau[i, j] == OMEGA else tau[i, j] + 1  # (11), (14)
                Zn[i][b] = d.A_bar[b, b] @ Z[i][b] + lower  # eq. (12)
    return Zn, taun


@pytest.mark.parametrize("seed", range(8))
def test_vectorised_matches_loop_reference(seed):
    rng = np.random.default_rng(seed)
    N = 5
    plant = random_structured(8, N, rng=seed, num_sources=3)
    des = design_observer(plant, rho=0.6)
    obs = FreshnessObserver(des)
    obs.reset(rng.standard_normal((N, 8)))
    Z, tau = obs.z_estimates, obs.indices
    graphs = RandomJointlyConnected(N, 3, 0.2).sequence(25, seed)
    x = rng.standard_normal(8)
    for k in range(25):
        y = plant.measure(x)
        Z, tau = reference_step(des, Z, tau, y, graphs[k])
        obs.step(y, graphs[k])
        assert (obs.indices == tau).all()
        assert np.allclose(obs.z_estimates, Z, atol=1e-9 * max(1, np.abs(Z).max()))
        x = plant.step(x)


def test_fig1_indices_by_hand():
    """Fig. 1 graphs: (a) 1->2, 2->3 at even k; (b) 1->3, 3->2 at odd k (1-based)."""
    obs = FreshnessObserver(design_observer(fig1_scalar(), deadbeat=True))
    g = fig1_graphs().sequence(6)
    seen = []
    for k in range(6):
        obs.step([np.array([1.0]), np.zeros(0), np.zeros(0)], g[k])
        seen.append(obs.indices[:, 0].tolist())
    # k=0: node 2 adopts from 1 (tau=1), node 3's only neighbour is omega; k=1: node 3
    # adopts from 1, node 2 rejects node 3 (omega) and ages to 2; k=2: node 2 adopts from
    # 1, node 3 (tau=1) rejects node 2 (tau=2) and ages to 2; then it alternates.
    assert seen == [[0, 1, OMEGA], [0, 2, 1], [0, 1, 2], [0, 2, 1], [0, 1, 2], [0, 2, 1]]


@pytest.mark.parametrize("seed", range(12))
def test_lemma3_and_lemma5(seed):
    rng = np.random.default_rng(seed)
    N, T = int(rng.integers(3, 9)), int(rng.integers(1, 4))
    plant = random_structured(N, N, rng=seed, num_sources=min(N, 3))
    obs = FreshnessObserver(design_observer(plant, rho=0.5))
    graphs = RandomJointlyConnected(N, T, float(rng.uniform(0, 0.2))).sequence(8 * N * T, seed)
    x = np.ones(N)
    bar_T = (N - 1) * T
    for k in range(graphs.shape[0]):
        obs.step(plant.measure(x), graphs[k])
        x = plant.step(x)
        if k + 1 >= bar_T:
            tau = obs.indices
            assert (tau != OMEGA).all(), f"Lemma 3 violated at k={k + 1}"  # eq. (15)
            assert tau.max() <= 2 * bar_T, f"Lemma 5 violated at k={k + 1}"  # eq. (17)


def run_errors(plant, des, graphs, x0, x0_hat, rng=None):
    obs = FreshnessObserver(des)
    obs.reset(x0_hat)
    x, errs, norms = x0, [], []
    for k in range(graphs.shape[0]):
        obs.step(plant.measure(x, rng), graphs[k])
        x = plant.step(x, rng)
        errs.append(obs.errors(x))
        norms.append(np.linalg.norm(x))
    return np.array(errs), np.array(norms)


@pytest.mark.parametrize("seed", range(5))
def test_theorem1_rate(seed):
    """After the transient, log error decays with slope at most log(rho) (Theorem 1)."""
    rho, N, n, T = 0.6, 4, 6, 2
    plant = random_structured(n, N, rng=seed, num_sources=2, spectral_radius=1.1)
    des = design_observer(plant, rho=rho)
    graphs = RandomJointlyConnected(N, T, 0.1).sequence(150, seed)
    rng = np.random.default_rng(seed)
    errs, norms = run_errors(plant, des, graphs, rng.standard_normal(n),
                             rng.standard_normal((N, n)))
    worst = errs.max(1)
    # fit over the window after a transient and before rounding (~1e-12 relative) floors it
    ks = np.arange(15, 150)
    ks = ks[worst[ks] > 1e-11 * norms[ks]]
    assert ks.size >= 15
    slope = np.polyfit(ks, np.log(worst[ks]), 1)[0]
    assert slope <= np.log(rho) + 0.02, (slope, np.log(rho))


@pytest.mark.parametrize("seed", range(6))
def test_corollary1_deadbeat_finite_time(seed):
    N, n, T = 4, 5, 2
    plant = random_structured(n, N, rng=seed, num_sources=2, spectral_radius=1.1)
    des = design_observer(plant, deadbeat=True)
    bound = n + 2 * N * (N - 1) * T
    graphs = RandomJointlyConnected(N, T, 0.1).sequence(bound + 5, seed)
    rng = np.random.default_rng(seed)
    errs, norms = run_errors(plant, des, graphs, rng.standard_normal(n),
                             rng.standard_normal((N, n)))
    rel = errs / norms[:, None]
    assert rel[bound - 1:].max() <= 1e-9  # errors at steps >= n + 2N(N-1)T


def test_bounded_noise_bounded_error():
    N, n, T = 4, 6, 2
    base = random_structured(n, N, rng=11, num_sources=2, spectral_radius=1.05)
    plant = Plant(A=base.A, C=base.C, process_noise=UniformNoise(0.01),
                  measurement_noise=UniformNoise(0.01))
    des = design_observer(plant, rho=0.5)
    graphs = RandomJointlyConnected(N, T, 0.1).sequence(600, 1)
    rng = np.random.default_rng(2)
    errs, norms = run_errors(plant, des, graphs, np.zeros(n), np.zeros((N, n)), rng)
    assert np.all(np.isfinite(errs))
    # the state itself grows (unstable plant) while the error stays at the noise level
    assert errs[300:].max() < 10 * errs[100:300].max() + 1e-12
    assert errs[300:].max() < 1e-2 * norms[300:].max()


def test_batch_equals_independent_runs():
    N, n = 4, 6
    plant = random_structured(n, N, rng=3, num_sources=2)
    des = design_observer(plant, rho=0.5)
    B = 3
    rng = np.random.default_rng(0)
    seqs = [RandomJointlyConnected(N, 2, 0.2).sequence(20, s) for s in range(B)]
    x0 = rng.standard_normal((B, n))
    batched = FreshnessObserver(des, batch_size=B)
    singles = [FreshnessObserver(des) for _ in range(B)]
    x = x0.copy()
    for k in range(20):
        y = plant.measure(x)
        batched.step(y, np.stack([s[k] for s in seqs]))
        for b in range(B):
            singles[b].step(y[b], seqs[b][k])
        x = plant.step(x)
    for b in range(B):
        assert np.array_equal(batched.indices[b], singles[b].indices)
        assert np.allclose(batched.estimates[b], singles[b].estimates, rtol=1e-12, atol=1e-12)


def test_bad_input_leaves_state_untouched():
    plant = random_structured(4, 3, rng=0, num_sources=2)
    obs = FreshnessObserver(design_observer(plant, rho=0.5))
    Z0, tau0 = obs.z_estimates, obs.indices
    y = plant.measure(np.ones(4))
    with pytest.raises(ValueError, match="adjacency"):
        obs.step(y, np.ones((2, 2), bool))
    with pytest.raises(ValueError, match="self-loops"):
        obs.step(y, np.eye(3, dtype=bool))
    with pytest.raises(ValueError, match="y"):
        obs.step(np.full_like(y, np.nan), np.zeros((3, 3), bool))
    with pytest.raises(ValueError, match="x0_hat"):
        obs.reset(np.ones(5))
    assert obs.k == 0 and np.array_equal(obs.z_estimates, Z0)
    assert np.array_equal(obs.indices, tau0)
