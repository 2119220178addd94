"""OSE/OASE step, eqs. (7)-(8): oracle checks against independent computations."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from netsense.estimators.online import OnlineStateEstimator, OSEConfig, lambda_matrix, ose_step


def _argmin_lstsq(x_prev, y, A, gamma, Q):
    """Explicit minimiser of eq. (6) by stacking it as one ordinary least squares."""
    W = np.linalg.cholesky(np.linalg.inv(Q)).T          # W^T W = Q^-1
    K = np.vstack([W @ A, np.sqrt(gamma) * np.eye(A.shape[1])])
    r = np.concatenate([W @ y, np.sqrt(gamma) * x_prev])
    return np.linalg.lstsq(K, r, rcond=None)[0]


def _spd(rng, M):
    B = rng.standard_normal((M, M))
    return B @ B.T + M * np.eye(M)


@pytest.mark.parametrize("M", [1, 3, 9])        # M < N, and M > N (normal-equation path)
def test_step_is_the_proximal_wls_argmin(M):
    rng = np.random.default_rng(M)
    N, gamma = 6, 0.37
    A, x, y, Q = (rng.standard_normal((M, N)), rng.standard_normal(N),
                  rng.standard_normal(M), _spd(rng, M))
    np.testing.assert_allclose(ose_step(x, y, A, gamma, Q), _argmin_lstsq(x, y, A, gamma, Q),
                               atol=1e-12)


def test_step_matches_closed_form_7_with_explicit_lambda():
    rng = np.random.default_rng(1)
    N, M, gamma = 5, 2, 2.5
    A, x, y, Q = rng.standard_normal((M, N)), rng.standard_normal(N), rng.standard_normal(M), \
        _spd(rng, M)
    Lam = gamma * np.linalg.inv(A.T @ np.linalg.inv(Q) @ A + gamma * np.eye(N))   # eq. (8)
    expected = Lam @ x + Lam @ A.T @ np.linalg.inv(Q) @ y / gamma                 # eq. (7)
    np.testing.assert_allclose(ose_step(x, y, A, gamma, Q), expected, atol=1e-12)
    np.testing.assert_allclose(lambda_matrix(A, gamma, Q), Lam, atol=1e-12)
    # eq. (11): eigenvalue 1 with multiplicity N - rank(A), others gamma/(gamma + lambda_i)
    lam_J = np.linalg.eigvalsh(A.T @ np.linalg.inv(Q) @ A)[-M:]
    expected_eig = np.sort(np.concatenate([np.ones(N - M), gamma / (gamma + lam_J)]))
    np.testing.assert_allclose(np.sort(np.linalg.eigvalsh(Lam)), expected_eig, atol=1e-12)


def test_hand_computed_scalar_case():
    # N = 1, A = [1], Q = q: x = (gamma x_prev + y / q) / (gamma + 1 / q)
    x = ose_step([2.0], [5.0], [[1.0]], gamma=0.5, Q=[[4.0]])
    assert x[0] == pytest.approx((0.5 * 2.0 + 5.0 / 4.0) / (0.5 + 0.25), abs=1e-14)


def test_affine_offset_of_remark_1():
    rng = np.random.default_rng(2)
    A, x, y, b = rng.standard_normal((2, 4)), rng.standard_normal(4), rng.standard_normal(2), \
        rng.standard_normal(2)
    np.testing.assert_allclose(ose_step(x, y, A, 1.3, b=b), ose_step(x, y - b, A, 1.3),
                               atol=1e-14)


def test_batched_equals_per_run_and_diagonal_q():
    rng = np.random.default_rng(3)
    R, N, M, gamma = 7, 5, 3, 0.8
    A = rng.standard_normal((R, M, N))
    x = rng.standard_normal((R, N))
    y = rng.standard_normal((R, M))
    q = rng.uniform(0.5, 2.0, M)
    out = ose_step(x, y, A, gamma, q)
    for r in range(R):
        np.testing.assert_allclose(out[r], _argmin_lstsq(x[r], y[r], A[r], gamma, np.diag(q)),
                                   atol=1e-12)
    # a shared A broadcasts over the batch
    shared = ose_step(x, y, A[0], gamma)
    np.testing.assert_allclose(shared[4], ose_step(x[4], y[4], A[0], gamma), atol=1e-14)


def test_empty_measurement_keeps_estimate():
    x = np.array([1.0, -2.0])
    np.testing.assert_array_equal(ose_step(x, np.zeros(0), np.zeros((0, 2)), 0.1), x)


def test_error_recursion_17_holds_exactly():
    # xi(t) = Lambda xi(t-1) - Lambda delta + (1/gamma) Lambda A^T Q^-1 n, eq. (17)
    rng = np.random.default_rng(4)
    N, M, gamma = 6, 2, 0.4
    A, Q = rng.standard_normal((M, N)), _spd(rng, M)
    x_prev, x_hat_prev = rng.standard_normal(N), rng.standard_normal(N)
    delta, n = rng.standard_normal(N), rng.standard_normal(M)
    x = x_prev + delta
    x_hat = ose_step(x_hat_prev, A @ x + n, A, gamma, Q)
    Lam = lambda_matrix(A, gamma, Q)
    xi = Lam @ (x_hat_prev - x_prev) - Lam @ delta + Lam @ A.T @ np.linalg.solve(Q, n) / gamma
    np.testing.assert_allclose(x_hat - x, xi, atol=1e-12)


def test_noise_free_constant_state_contracts_at_the_closed_form_rate():
    # A alternates between [e1; e2] and [e3; e4] (tau = 2); with Q = I each observed
    # coordinate's error is multiplied by gamma / (gamma + 1) when it is measured.
    N, gamma = 4, 0.2
    I4 = np.eye(N)
    lib = [I4[:2], I4[2:]]
    x_true = np.array([1.0, -2.0, 0.5, 3.0])
    est = OnlineStateEstimator(OSEConfig(gamma=gamma), np.zeros(N))
    for t in range(10):
        A = lib[t % 2]
        est.step(A @ x_true, A)
    np.testing.assert_allclose(est.x_hat - x_true, -(gamma / (1 + gamma)) ** 5 * x_true,
                               atol=1e-14)
    assert est.t == 10


@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf])
def test_gamma_must_be_positive(bad):
    with pytest.raises(ValueError, match="gamma"):
        ose_step(np.zeros(2), [1.0], [[1.0, 0.0]], bad)
    with pytest.raises(ValueError, match="gamma"):
        OSEConfig(gamma=bad)


def test_shape_errors_name_the_field_and_leave_state_unchanged():
    est = OnlineStateEstimator(OSEConfig(gamma=1.0), np.ones((3, 2)))
    before = est.x_hat.copy()
    cases = [
        (dict(y=np.ones((3, 1)), A=np.ones((1, 3))), "A must have N = 2"),
        (dict(y=np.ones((3, 2)), A=np.ones((1, 2))), "y must have M = 1"),
        (dict(y=np.ones((4, 1)), A=np.ones((1, 2))), "y has batch size 4"),
        (dict(y=np.ones(1), A=np.ones((1, 2)), Q=np.eye(2)), "Q must have shape"),
        (dict(y=np.ones(1), A=np.ones((1, 2)), b=np.ones(2)), "b must have M = 1"),
        (dict(y=np.ones(2), A=np.ones((2, 2)), Q=np.array([[1.0, 2.0], [2.0, 1.0]])),
         "positive definite"),
        (dict(y=np.ones(2), A=np.ones((2, 2)), Q=np.array([[1.0, 0.5], [0.0, 1.0]])),
         "symmetric"),
        (dict(y=np.ones(2), A=np.ones((2, 2)), Q=np.array([1.0, 0.0])), "positive definite"),
        (dict(y=np.array([np.nan]), A=np.ones((1, 2))), "NaN"),
    ]
    for kwargs, msg in cases:
        with pytest.raises(ValueError, match=msg):
            est.step(**kwargs)
        np.testing.assert_array_equal(est.x_hat, before)
        assert est.t == 0


def test_estimator_pickles():
    est = OnlineStateEstimator(OSEConfig(gamma=0.5), np.zeros(3))
    est.step([1.0], [[1.0, 0.0, 0.0]])
    clone = pickle.loads(pickle.dumps(est))
    np.testing.assert_array_equal(clone.x_hat, est.x_hat)
