"""RSEIO (Theorem 1) against independent computations: the minimiser of cost (2) (eq. (a.8)),
Theorem 2's recursion (eq. (9)) and its reductions to KFIO."""

import numpy as np
import pytest

from netsense.estimators.kalman import KFIO, StateSpaceModel
from netsense.estimators.robust import RSEIO, sensitivity_matrices

inv = np.linalg.inv


def random_case(seed, n=3, p=2, m=2, n_e=2):
    rng = np.random.default_rng(seed)
    model = StateSpaceModel(rng.normal(size=(n, n)), rng.normal(size=(n, p)),
                            rng.normal(size=(m, n)), np.diag(rng.uniform(0.5, 2, p)),
                            np.diag(rng.uniform(0.5, 2, m)))
    derivs = {"dA": rng.normal(size=(n_e, n, n)), "dB": rng.normal(size=(n_e, n, p)),
              "dC": rng.normal(size=(n_e, m, n))}
    L = rng.normal(size=(n, n))
    return rng, model, derivs, L @ L.T + 0.5 * np.eye(n)


def minimiser_of_cost2(model, S, T, lam, x0, P, y):
    """x_{t+1|t+1} = [A B] alpha_hat and [A B] M^-1 [A B]' from the normal equations (a.8)."""
    A, B, C, Q, R = model.A, model.B, model.C, model.Q, model.R
    n, p = B.shape
    AB, ST = np.hstack([A, B]), np.hstack([S, T])
    D = np.block([[inv(P), np.zeros((n, p))], [np.zeros((p, n)), inv(Q)]])
    M = D + lam * ST.T @ ST + AB.T @ C.T @ inv(R) @ C @ AB
    alpha = np.linalg.solve(M, D @ np.r_[x0, np.zeros(p)] + AB.T @ C.T @ inv(R) @ y)
    return AB @ alpha, AB @ np.linalg.solve(M, AB.T)


@pytest.mark.parametrize("seed, mu", [(0, 0.6), (1, 0.9), (2, 0.3)])
def test_theorem1_minimises_cost2(seed, mu):
    rng, model, derivs, P = random_case(seed)
    f = RSEIO(model, mu, **derivs)
    x0, y = rng.normal(size=3), rng.normal(size=2)
    f.reset(x0, P)
    f.step(y[None], [True])
    S, T = f.sensitivities(0)
    x_star, P_star = minimiser_of_cost2(model, S, T, (1 - mu) / mu, x0, P, y)
    np.testing.assert_allclose(f.x[0], x_star, atol=1e-10)
    np.testing.assert_allclose(f.P[0], P_star, atol=1e-10)


def test_printed_theorem1_forms_do_not_minimise_cost2():
    """The printed Q_hat lacks an inverse and A_hat a lambda (cf. eqs. (a.9)-(a.12))."""
    rng, model, derivs, P = random_case(0)
    f = RSEIO(model, 0.6, **derivs)
    S, T = f.sensitivities(0)
    A, B, C, Q, R = model.A, model.B, model.C, model.Q, model.R
    lam, x0, y = 0.4 / 0.6, rng.normal(size=3), rng.normal(size=2)
    x_star, P_star = minimiser_of_cost2(model, S, T, lam, x0, P, y)
    P_hat = inv(inv(P) + lam * S.T @ S)
    Q_printed = inv(inv(Q) + lam * T.T @ (np.eye(len(S)) + lam * S @ P @ S.T) @ T)
    B_hat = B - lam * A @ P_hat @ S.T @ T
    P_pred = A @ P_hat @ A.T + B_hat @ Q_printed @ B_hat.T
    P_new = inv(inv(P_pred) + C.T @ inv(R) @ C)
    assert np.abs(P_new - P_star).max() > 1e-3


@pytest.mark.parametrize("seed, mu", [(3, 0.5), (4, 0.8)])
def test_pcm_matches_theorem2_recursion(seed, mu):
    """Eq. (9): P^-1_{t+1|t+1} = (A~ P A~' + B Q~ B')^-1 + C~' R~^-1 C~ when gamma = 1."""
    rng, model, derivs, P = random_case(seed, n_e=1)
    f = RSEIO(model, mu, **derivs)
    f.reset(np.zeros(3), P)
    f.step(np.zeros((1, 2)), [True])
    S, T = f.sensitivities(0)
    A, B, C, Q, R = model.A, model.B, model.C, model.Q, model.R
    lam, q = (1 - mu) / mu, S.shape[0]
    Q_chk = inv(inv(Q) + lam * T.T @ T)
    A_chk = A - lam * B @ Q_chk @ T.T @ S
    B_t = inv(A_chk) @ B
    w, V = np.linalg.eigh(np.eye(q) + lam * T @ Q @ T.T)
    S_t = np.sqrt(lam) * (V / np.sqrt(w)) @ V.T @ S
    A_t = A_chk + B @ Q_chk @ B_t.T @ S_t.T @ S_t
    Q_t = Q_chk + Q_chk @ B_t.T @ S_t.T @ S_t @ B_t @ Q_chk
    C_t = np.vstack([S_t @ inv(A_chk), C])
    R_t = np.block([[np.eye(q) + S_t @ B_t @ Q_chk @ B_t.T @ S_t.T, np.zeros((q, 2))],
                    [np.zeros((2, q)), R]])
    P_thm2 = inv(inv(A_t @ P @ A_t.T + B @ Q_t @ B.T) + C_t.T @ inv(R_t) @ C_t)
    np.testing.assert_allclose(f.P[0], P_thm2, atol=1e-10)


def _run_pair(model, f, g, seed, steps=40, batch=5):
    rng = np.random.default_rng(seed)
    for h in (f, g):
        h.reset(np.ones(model.n), np.eye(model.n), batch=batch)
    for _ in range(steps):
        y, gamma = rng.normal(size=(batch, model.m)), rng.random(batch) < 0.7
        f.step(y, gamma)
        g.step(y, gamma)


def test_mu_one_is_kfio():
    _, model, derivs, _ = random_case(5)
    f, g = RSEIO(model, 1.0, **derivs), KFIO(model)
    _run_pair(model, f, g, 0)
    np.testing.assert_allclose(f.x, g.x, atol=1e-12)
    np.testing.assert_allclose(f.P, g.P, atol=1e-12)


@pytest.mark.parametrize("mu", [0.2, 0.8])
def test_zero_derivatives_is_kfio_for_any_mu(mu):
    # an exact model (S = T = 0) leaves nothing to penalise: RSEIO reduces to KFIO
    _, model, _, _ = random_case(6)
    f, g = RSEIO(model, mu, dA=np.zeros((1, 3, 3))), KFIO(model)
    _run_pair(model, f, g, 1)
    np.testing.assert_allclose(f.x, g.x, atol=1e-12)
    np.testing.assert_allclose(f.P, g.P, atol=1e-12)


def test_penalty_changes_only_arrived_steps():
    _, model, derivs, P = random_case(7)
    f, g = RSEIO(model, 0.5, **derivs), KFIO(model)
    for h in (f, g):
        h.reset(np.ones(3), P)
        h.step([[np.nan, np.nan]], [False])
    np.testing.assert_allclose(f.x, g.x, atol=1e-13)
    np.testing.assert_allclose(f.P, g.P, atol=1e-13)
    f.step([[1.0, 2.0]], [True])
    g.step([[1.0, 2.0]], [True])
    assert np.abs(f.P - g.P).max() > 1e-3


def test_sensitivity_matrices_section_iv_plant():
    A = np.array([[0.9802, 0.0196], [0.0, 0.9802]])
    dA = np.array([[[0.0, 0.0198 * 5], [0.0, 0.0]]])
    C = np.array([[1.0, -1.0]])
    S, T = sensitivity_matrices(A, np.eye(2), C, dA, np.zeros((1, 2, 2)), np.zeros((1, 1, 2)))
    np.testing.assert_allclose(S, [[0.0, 0.099], [0.0, 0.0]], atol=1e-15)
    np.testing.assert_array_equal(T, np.zeros((2, 2)))


def test_callable_derivatives_and_mu():
    _, model, derivs, _ = random_case(8, n_e=1)
    const = RSEIO(model, 0.7, **derivs)
    func = RSEIO(model, lambda t: 0.7, dA=lambda t: derivs["dA"][0],
                 dB=lambda t: derivs["dB"], dC=lambda t: derivs["dC"], n_e=1)
    _run_pair(model, const, func, 2, steps=10)
    np.testing.assert_allclose(const.x, func.x, atol=1e-13)


@pytest.mark.parametrize("mu", [0.0, -0.1, 1.5, float("nan"), True])
def test_mu_outside_unit_interval_raises(mu):
    _, model, derivs, _ = random_case(9)
    with pytest.raises(ValueError, match=r"mu must lie in \(0, 1\]"):
        RSEIO(model, mu, **derivs)


def test_bad_derivatives_and_late_mu_raise_before_state_change():
    _, model, derivs, _ = random_case(10, n_e=2)
    with pytest.raises(ValueError, match=r"dA must have shape \(\*, 3, 3\)"):
        RSEIO(model, 0.5, dA=np.ones((2, 3, 2)))
    with pytest.raises(ValueError, match="disagree on the number of parameters"):
        RSEIO(model, 0.5, dA=derivs["dA"], dC=derivs["dC"][:1])
    with pytest.raises(ValueError, match="n_e must be given"):
        RSEIO(model, 0.5, dA=lambda t: derivs["dA"])
    f = RSEIO(model, lambda t: 0.5 if t < 2 else 2.0, **derivs)
    f.reset(np.zeros(3), np.eye(3))
    f.step([[0.0, 0.0]], [True])
    f.step([[0.0, 0.0]], [True])
    x, P = f.x.copy(), f.P.copy()
    with pytest.raises(ValueError, match="at t = 2"):
        f.step([[0.0, 0.0]], [True])
    assert f.t == 2 and np.array_equal(f.x, x) and np.array_equal(f.P, P)


# ------------------------------------------------------------ source-node adapters
def _two_source_plant():
    from netsense.sensing.noise import GaussianNoise
    from netsense.systems.plants import Plant

    A = np.array([[0.98, 0.0], [0.1, 0.95]])
    return Plant(A=A, C=(np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]]), np.zeros((0, 2))),
                 process_noise=GaussianNoise(0.5), measurement_noise=GaussianNoise(1.0))


def _run_observer(source, B, K, seed, arrival_p=0.7):
    from netsense.observers.freshness import FreshnessObserver
    from netsense.sensing.drops import BernoulliArrivals
    from netsense.systems.design import design_observer

    plant = _two_source_plant()
    rng = np.random.default_rng(seed)
    obs = FreshnessObserver(design_observer(plant, rho=0.5), batch_size=B,
                            source_estimator=source)
    obs.reset(np.zeros(2))
    arrivals = BernoulliArrivals(arrival_p).sampler(rng, (B, 3))
    x = rng.standard_normal((B, 2))
    adj = ~np.eye(3, dtype=bool)
    hist = []
    for _ in range(K):
        y, arr = plant.measure(x, rng), arrivals.next()
        obs.step(y, adj, arrived=arr)
        x = plant.step(x, rng)
        hist.append((y, arr, obs.z_estimates.copy(), x))
    return obs, hist


def test_kfio_source_matches_scalar_kfio_predictor():
    from netsense.observers.source_estimators import KFIOSource

    obs, hist = _run_observer(KFIOSource(Q=0.25, R=1.0, P0=2.0), B=3, K=25, seed=0)
    assert np.allclose(obs.design.decomposition.T, np.eye(2))    # block 0 is x_1
    a, q, r = 0.98, 0.25, 1.0
    xh, P = np.zeros(3), np.full(3, 2.0)
    for y, arr, Z, _ in hist:
        K = np.where(arr[:, 0], P / (P + r), 0.0)
        xf, Pf = xh + K * (y[:, 0, 0] - xh), (1 - K) * P
        xh, P = a * xf, a * a * Pf + q
        np.testing.assert_allclose(Z[:, 0, 0], xh, atol=1e-12)


def test_kfio_source_beats_fixed_gain_under_noise_and_drops():
    from netsense.observers.source_estimators import KFIOSource

    def mse(source):
        _, hist = _run_observer(source, B=400, K=120, seed=1)
        e = np.stack([np.sum((Z - x[:, None]) ** 2, -1) for _, _, Z, x in hist[40:]])
        return e.mean(axis=(0, 2))                                 # per run
    # same seed: the same plant, noise and arrivals for both sources
    d = mse(KFIOSource(Q=0.25, R=1.0)) - mse(None)
    assert d.mean() < -4 * d.std(ddof=1) / np.sqrt(d.size)


def test_rseio_source_mu_one_is_kfio_source_and_validation():
    from netsense.observers.source_estimators import KFIOSource, RSEIOSource

    dA = np.array([[[0.5, 0.0], [0.0, 0.2]]])
    _, h1 = _run_observer(KFIOSource(Q=0.25, R=1.0), B=4, K=20, seed=2)
    _, h2 = _run_observer(RSEIOSource(Q=0.25, R=1.0, mu=1.0, dA=dA), B=4, K=20, seed=2)
    _, h3 = _run_observer(RSEIOSource(Q=0.25, R=1.0, mu=0.5, dA=dA), B=4, K=20, seed=2)
    np.testing.assert_allclose(h1[-1][2], h2[-1][2], atol=1e-12)
    assert np.abs(h1[-1][2] - h3[-1][2]).max() > 1e-3
    with pytest.raises(ValueError, match="R must hold 3 per-agent"):
        _run_observer(KFIOSource(Q=0.25, R=[1.0]), B=1, K=1, seed=0)
    with pytest.raises(ValueError, match="Q must be positive definite"):
        _run_observer(KFIOSource(Q=-1.0, R=1.0), B=1, K=1, seed=0)
    with pytest.raises(ValueError, match=r"mu must lie in \(0, 1\]"):
        _run_observer(RSEIOSource(Q=0.25, R=1.0, mu=0.0), B=1, K=1, seed=0)


def test_kfio_source_inside_the_environment():
    """Scenario link_failures-v0 (measurement noise, 5 % measurement drops, message drops)
    with the source update swapped from eq. (7) to KFIO through CoreModel.source_estimator.
    Three seeded episodes of 60 steps; the KFIO source has the lower mean error over
    steps 30..59 in each."""
    import dataclasses

    from netsense.env import registry as scenarios
    from netsense.env.pettingzoo_env import NetSenseEnv
    from netsense.env.policies import make_policy
    from netsense.observers.source_estimators import KFIOSource

    model = scenarios.build_model(scenarios.load("link_failures-v0"))

    def episode(source, seed):
        env = NetSenseEnv(dataclasses.replace(model, source_estimator=source))
        policy = make_policy("freshness", env)
        obs, infos = env.reset(seed=seed)
        errs = []
        for k in range(60):
            obs, _, _, _, infos = env.step(policy.act_dict(env, obs, infos))
            if k >= 30:
                errs.append(np.mean([infos[a]["error"] for a in env.possible_agents]))
        return np.mean(errs), env

    for seed in range(3):
        e_kfio, env = episode(lambda: KFIOSource(Q=1e-4, R=1e-4), seed)
        e_fixed, _ = episode(None, seed)
        assert type(env.core.source).__name__ == "KFIOSource"
        assert np.isfinite(e_kfio) and e_kfio < e_fixed
