"""KF and KFIO (netsense.estimators.kalman) against closed forms and Monte Carlo."""

import numpy as np
import pytest

from netsense.estimators.kalman import KFIO, KalmanFilter, StateSpaceModel, bmm, spd_solve


def random_model(rng, n=3, p=2, m=2):
    A = rng.normal(size=(n, n)) * 0.5
    B = rng.normal(size=(n, p))
    C = rng.normal(size=(m, n))
    Lq, Lr = rng.normal(size=(p, p)), rng.normal(size=(m, m))
    return StateSpaceModel(A, B, C, Lq @ Lq.T + np.eye(p), Lr @ Lr.T + np.eye(m))


def test_scalar_kf_matches_hand_recursion():
    a, b, c, q, r = 0.9, 1.0, 2.0, 0.5, 0.3
    f = KalmanFilter(StateSpaceModel([[a]], [[b]], [[c]], [[q]], [[r]]))
    f.reset([1.0], [[2.0]])
    x, P = 1.0, 2.0
    for y in [0.3, -1.2, 2.5, 0.0, 4.1, -0.7, 1.1, 0.2]:
        Pp = a * a * P + b * b * q
        K = Pp * c / (c * c * Pp + r)
        x = a * x + K * (y - c * a * x)
        P = (1 - K * c) * Pp
        f.step([[y]])
        np.testing.assert_allclose(f.x[0, 0], x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(f.P[0, 0, 0], P, rtol=0, atol=1e-12)


def test_information_form_of_eq5_with_mu_one():
    # P_{t+1|t+1} = (P_pred^-1 + C' R^-1 C)^-1 and gain P_{t+1|t+1} C' R^-1 (eqs. (4), (5)).
    rng = np.random.default_rng(1)
    model = random_model(rng)
    A, B, C, Q, R = model.A, model.B, model.C, model.Q, model.R
    f = KFIO(model)
    x0, P0 = rng.normal(size=3), np.eye(3) * 1.5
    f.reset(x0, P0)
    y = rng.normal(size=2)
    f.step(y[None], [True])
    Pp = A @ P0 @ A.T + B @ Q @ B.T
    P1 = np.linalg.inv(np.linalg.inv(Pp) + C.T @ np.linalg.inv(R) @ C)
    x1 = A @ x0 + P1 @ C.T @ np.linalg.inv(R) @ (y - C @ A @ x0)
    np.testing.assert_allclose(f.P[0], P1, atol=1e-12)
    np.testing.assert_allclose(f.x[0], x1, atol=1e-12)


def test_kfio_with_all_arrivals_equals_kf_and_kf_ignores_gamma():
    rng = np.random.default_rng(2)
    model = random_model(rng)
    kf, kfio, kf_drop = KalmanFilter(model), KFIO(model), KalmanFilter(model)
    for f in (kf, kfio, kf_drop):
        f.reset(np.zeros(3), np.eye(3), batch=4)
    for _ in range(25):
        y = rng.normal(size=(4, 2))
        kf.step(y)
        kfio.step(y, np.ones(4, bool))
        kf_drop.step(y, np.zeros(4, bool))      # the paper's KF does not look at gamma
    np.testing.assert_allclose(kfio.x, kf.x, atol=1e-12)
    np.testing.assert_allclose(kfio.P, kf.P, atol=1e-12)
    np.testing.assert_array_equal(kf_drop.x, kf.x)


def test_kfio_drop_is_pure_prediction_and_rows_are_independent():
    rng = np.random.default_rng(3)
    model = random_model(rng)
    gammas = rng.random((30, 3)) < 0.6
    ys = rng.normal(size=(30, 3, 2))
    ys[~gammas] = np.nan                         # dropped packets carry no usable data
    f = KFIO(model)
    f.reset(np.ones(3), np.eye(3), batch=3)
    est = f.run(ys, gammas)
    for b in range(3):
        g = KFIO(model)
        g.reset(np.ones(3), np.eye(3))
        for k in range(30):
            x_before, P_before = g.x.copy(), g.P.copy()
            g.step(ys[k, b][None], gammas[k, b][None])
            if not gammas[k, b]:
                A, B, Q = model.A, model.B, model.Q
                np.testing.assert_allclose(g.x[0], A @ x_before[0], atol=1e-12)
                np.testing.assert_allclose(g.P[0], A @ P_before[0] @ A.T + B @ Q @ B.T,
                                           atol=1e-12)
            np.testing.assert_allclose(est[k + 1, b], g.x[0], atol=1e-12)


def test_time_varying_callables_evaluated_at_the_right_times():
    # scalar LTV system; C_{t+1} and R_{t+1} are used for the step t -> t+1
    a = lambda t: [[1.0 + 0.1 * t]]  # noqa: E731
    c = lambda t: [[1.0 + t]]  # noqa: E731
    r = lambda t: [[0.5 + 0.25 * t]]  # noqa: E731
    f = KalmanFilter(StateSpaceModel(a, [[1.0]], c, [[0.2]], r))
    f.reset([0.0], [[1.0]])
    x, P = 0.0, 1.0
    for t, y in enumerate([1.0, 2.0, -1.0, 0.5]):
        at, ct, rt = 1.0 + 0.1 * t, 1.0 + (t + 1), 0.5 + 0.25 * (t + 1)
        Pp = at * at * P + 0.2
        K = Pp * ct / (ct * ct * Pp + rt)
        x, P = at * x + K * (y - ct * at * x), (1 - K * ct) * Pp
        f.step([[y]])
        np.testing.assert_allclose([f.x[0, 0], f.P[0, 0, 0]], [x, P], atol=1e-12)


def test_kfio_mse_matches_its_covariance_in_monte_carlo():
    """With an exact model E|x - x_hat|^2 = E trace P_{t|t} (Sinopoli et al.)."""
    rng = np.random.default_rng(4)
    A = np.array([[0.95, 0.2], [0.0, 0.9]])
    model = StateSpaceModel(A, np.eye(2), [[1.0, 0.0]], 0.5 * np.eye(2), [[1.0]])
    runs, steps = 3000, 60
    x = rng.standard_normal((runs, 2))
    f = KFIO(model)
    f.reset(np.zeros(2), np.eye(2), batch=runs)
    sq, tr = np.zeros(runs), np.zeros(runs)
    for t in range(steps):
        x = x @ A.T + np.sqrt(0.5) * rng.standard_normal((runs, 2))
        gamma = rng.random(runs) < 0.7
        y = gamma[:, None] * x[:, :1] + rng.standard_normal((runs, 1))
        f.step(y, gamma)
        if t >= 20:
            sq += np.sum((x - f.x) ** 2, axis=1)
            tr += np.trace(f.P, axis1=1, axis2=2)
    d = (sq - tr) / (steps - 20)
    # mean of (squared error - trace P) is 0; tolerance: 4 standard errors
    assert abs(d.mean()) < 4 * d.std(ddof=1) / np.sqrt(runs)


def test_small_matrix_helpers_match_numpy():
    rng = np.random.default_rng(5)
    X, Y = rng.normal(size=(7, 3, 4)), rng.normal(size=(7, 4, 2))
    np.testing.assert_allclose(bmm(X, Y), X @ Y, atol=1e-13)
    np.testing.assert_allclose(bmm(X[0], Y), X[0] @ Y, atol=1e-13)
    np.testing.assert_allclose(bmm(X, Y[0]), X @ Y[0], atol=1e-13)
    G = X @ np.swapaxes(X, 1, 2) + np.eye(3)
    np.testing.assert_allclose(G @ spd_solve(G, X), X, atol=1e-12)
    np.testing.assert_allclose(spd_solve(G[:, :1, :1], X[:, :1]) * G[:, :1, :1], X[:, :1])


@pytest.mark.parametrize("kwargs, match", [
    ({"A": np.ones((2, 3))}, "A must be a non-empty square"),
    ({"B": np.ones((3, 1))}, r"B must have shape \(2, \*\)"),
    ({"C": np.ones((1, 3))}, r"C must have shape \(\*, 2\)"),
    ({"Q": -np.eye(1)}, "Q must be positive definite"),
    ({"R": np.array([[1.0, 2.0], [0.0, 1.0]])}, r"R must have shape \(1, 1\)"),
    ({"R": np.array([[0.0]])}, "R must be positive definite"),
    ({"Q": np.array([[np.nan]])}, "Q contains NaN"),
])
def test_model_validation(kwargs, match):
    base = {"A": np.eye(2), "B": np.ones((2, 1)), "C": np.ones((1, 2)), "Q": np.eye(1),
            "R": np.eye(1)}
    with pytest.raises(ValueError, match=match):
        StateSpaceModel(**{**base, **kwargs})


def test_bad_inputs_raise_before_any_state_change():
    model = StateSpaceModel(np.eye(2), np.eye(2), [[1.0, 0.0]], np.eye(2),
                            lambda t: [[1.0]] if t < 3 else [[-1.0]])
    f = KFIO(model)
    with pytest.raises(ValueError, match="P0 must be positive definite"):
        f.reset(np.zeros(2), np.diag([1.0, 0.0]))
    with pytest.raises(ValueError, match="P0 must be symmetric"):
        f.reset(np.zeros(2), np.array([[1.0, 0.5], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="batch size"):
        f.reset(np.zeros((3, 2)), np.eye(2), batch=2)
    f.reset(np.zeros(2), np.eye(2), batch=2)
    for y, g, match in [(np.zeros((2, 2)), None, r"y must have shape \(batch, m\) = \(2, 1\)"),
                        (np.zeros((2, 1)), np.ones(3, bool), "gamma must be a 0/1"),
                        (np.full((2, 1), np.nan), np.ones(2, bool), "NaN")]:
        with pytest.raises(ValueError, match=match):
            f.step(y, g)
    f.step(np.zeros((2, 1)))
    f.step(np.zeros((2, 1)))
    x, P, t = f.x.copy(), f.P.copy(), f.t
    with pytest.raises(ValueError, match=r"R\(3\) must be positive definite"):
        f.step(np.zeros((2, 1)))
    assert f.t == t and np.array_equal(f.x, x) and np.array_equal(f.P, P)


def test_known_drive_and_update_only_scalar():
    a, c, q, r = 0.8, 1.5, 0.4, 0.2
    f = KFIO(StateSpaceModel([[a]], [[1.0]], [[c]], [[q]], [[r]]))
    f.reset([0.5], [[1.0]])
    # update only at t = 0 with y_0
    K = 1.0 * c / (c * c * 1.0 + r)
    x, P = 0.5 + K * (2.0 - c * 0.5), (1 - K * c) * 1.0
    f.update([[2.0]], [True])
    np.testing.assert_allclose([f.x[0, 0], f.P[0, 0, 0], f.t], [x, P, 0], atol=1e-12)
    for y, u, g in [(1.0, 0.3, True), (0.0, -1.0, False), (-2.0, 0.7, True)]:
        xp, Pp = a * x + u, a * a * P + q
        if g:
            K = Pp * c / (c * c * Pp + r)
            x, P = xp + K * (y - c * xp), (1 - K * c) * Pp
        else:
            x, P = xp, Pp
        f.step([[y]], [g], u=[[u]])
        np.testing.assert_allclose([f.x[0, 0], f.P[0, 0, 0]], [x, P], atol=1e-12)
    with pytest.raises(ValueError, match=r"u must have shape \(1, 1\)"):
        f.step([[0.0]], [True], u=np.zeros(3))
