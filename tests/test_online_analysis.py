"""Analysis helpers: tau of Assumption 1, constants, bounds (23)-(25), (34)-(38)."""

from __future__ import annotations

import numpy as np
import pytest

from netsense.estimators import online_analysis as oa
from netsense.estimators.online import ose_step

E = np.eye(3)


def test_smallest_tau_on_hand_built_sequences():
    # one coordinate per step, cycling: every window of 3 sees e1, e2, e3
    assert oa.smallest_tau([E[[i % 3]] for i in range(12)]) == 3
    # e1, e2, e1, e2, e3 ...: the window [e2, e1, e2] misses e3, tau grows
    seq = [E[[0]], E[[1]], E[[0]], E[[1]], E[[2]], E[[0]], E[[1]], E[[2]]]
    assert oa.smallest_tau(seq) == 5      # window starting at index 1: e2 e1 e2 e3 e1
    # full-rank every step
    assert oa.smallest_tau([np.eye(3)] * 4) == 1
    # never observable
    assert oa.smallest_tau([E[[0]], E[[1]]] * 3) is None
    # time-varying M_t and an empty step
    seq = [E[:2], np.zeros((0, 3)), E[[2]], E[:2], np.zeros((0, 3)), E[[2]]]
    assert oa.smallest_tau(seq) == 3
    # kernels: a rotated basis (not axis aligned) works the same way
    T = np.linalg.qr(np.random.default_rng(0).standard_normal((3, 3)))[0]
    assert oa.smallest_tau([E[[i % 3]] @ T for i in range(9)]) == 3


def test_lambda_bar_c_and_gamma_star_closed_forms():
    A1 = np.diag([2.0, 0.5, 0.0])            # J = diag(4, 0.25, 0): lambda_1 = 0.25
    A2 = np.array([[0.0, 0.0, 3.0]])         # J has eigenvalue 9
    Q = [np.eye(3), np.array([[2.0]])]       # Q^-1 halves J(2): 4.5
    assert oa.lambda_bar([A1, A2], Q) == pytest.approx(0.25)
    assert oa.c_const([A1, A2], Q) == pytest.approx(2.0)       # ||A1|| = 2, ||A2/2|| = 1.5
    assert oa.psi(0.5, 0.25) == pytest.approx(0.5 / 0.75)
    assert oa.gamma_star_bounded(2.0, 0.25, 1.0, 0.5) == pytest.approx(0.5)
    assert oa.kron_C_const([A1, A2]) == pytest.approx(9.0)     # ||A||_F^2
    assert oa.m_const([np.diag([0.25, 0.25])]) == pytest.approx(4 * np.sqrt(2))


def test_gamma_star_minimises_bound_24():
    c, lb, Dx, Dn, tau = 0.8, 0.12, 1.0, 0.9, 5
    gs = oa.gamma_star_bounded(c, lb, Dx, Dn)
    num = oa.gamma_star_numeric(lambda g: oa.bound_24(g, tau, Dx, Dn, c, lb))
    assert num == pytest.approx(gs, rel=1e-5)
    # bound (24) equals tau (..)/(1 - psi) with the paper's psi
    g = 0.3
    assert oa.bound_24(g, tau, Dx, Dn, c, lb) == pytest.approx(
        oa.bound_24(g, tau, Dx, Dn, c, lb, contraction=oa.psi(g, lb)))


def test_window_contraction_matches_hand_computation_and_psi_when_aligned():
    gamma = 0.5
    seq = [E[[i % 3]] for i in range(6)]        # Lambda(t) = I - e_i e_i^T / (1 + gamma)
    # product over a window of 3 is diag(gamma/(1+gamma)) -> norm = psi exactly
    assert oa.window_contraction(seq, gamma, 3) == pytest.approx(gamma / (1 + gamma))
    assert oa.window_contraction(seq, gamma, 2) == pytest.approx(1.0)
    # non-aligned kernels: the product norm exceeds psi = gamma/(gamma + lambda_bar),
    # the counterexample to Proposition 1's "<= psi" (see docs/online.md)
    th = 0.1
    seq2 = [np.array([[1.0, 0.0]]), np.array([[np.cos(th), np.sin(th)]])]
    rho = oa.window_contraction(seq2, gamma, 2)
    p = oa.psi(gamma, oa.lambda_bar(seq2))
    assert rho > p + 0.2
    assert rho < 1.0


def _simulate(lib_idx, lib, gamma, Dx, Dn, rng, R, T, gauss=False):
    N = lib[0].shape[1]
    x = np.zeros((R, N))
    x_hat = np.zeros((R, N))
    err = np.empty((T, R))
    for t in range(T):
        A = lib[lib_idx[t]]
        x = x + rng.uniform(-Dx / 2, Dx / 2, (R, N)) / np.sqrt(N)   # ||delta|| <= Dx/2
        n = (rng.standard_normal((R, A.shape[0])) * np.sqrt(Dn) if gauss
             else rng.uniform(-Dn / 2, Dn / 2, (R, A.shape[0])) / np.sqrt(A.shape[0]))
        x_hat = ose_step(x_hat, x @ A.T + n, A, gamma, None if not gauss else Dn * np.ones(
            A.shape[0]))
        err[t] = np.linalg.norm(x_hat - x, axis=1)
    return err


def test_bound_23_with_exact_contraction_bounds_the_simulated_error():
    rng = np.random.default_rng(7)
    N, M, tau = 4, 2, 2
    lib = [rng.standard_normal((M, N)) for _ in range(2)]
    lib = [A / np.linalg.norm(A) for A in lib]
    T, R, Dx, Dn = 60, 200, 1.0, 1.0
    idx = [t % 2 for t in range(T)]
    seq = [lib[i] for i in idx]
    assert oa.smallest_tau(seq) == tau
    for gamma in (0.05, 0.5, 5.0):
        rho = oa.window_contraction(seq, gamma, tau)
        assert rho < 1
        err = _simulate(idx, lib, gamma, Dx, Dn, rng, R, T)
        c_t = [oa.c_const([A]) for A in seq]
        # Delta_x(t), Delta_n(t): sup norms of the draws in _simulate (Dx/2, Dn/2)
        b = oa.bound_23(T, tau, rho, 0.0, Dx / 2, Dn / 2, c_t, gamma)
        assert np.all(err.max(axis=1) <= b + 1e-12)


def test_covariance_recursion_and_bound_37_with_exact_contraction():
    # Sigma(t) = Lambda Sigma Lambda + Lambda J Lambda / gamma^2 (eq. (29)): compare the
    # recursion with the Monte Carlo covariance, then check (37) with rho bounds it.
    rng = np.random.default_rng(8)
    N, gamma, sig2 = 3, 0.7, 0.25
    seq = [E[[i % 3]] for i in range(30)]
    R = 20000
    x_hat = np.zeros((R, N))
    Sigma = np.zeros((N, N))
    for A in seq:
        n = rng.standard_normal((R, 1)) * np.sqrt(sig2)
        x_hat = ose_step(x_hat, n, A, gamma, [sig2])          # true state is 0
        Lam = np.eye(N) - A.T @ A / (1 + gamma * sig2)        # gamma (A^T A/s2 + gamma)^-1
        J = A.T @ A / sig2
        Sigma = Lam @ Sigma @ Lam + Lam @ J @ Lam / gamma ** 2
    np.testing.assert_allclose(np.cov(x_hat.T), Sigma, atol=0.03 * np.abs(Sigma).max())
    rho = oa.window_contraction(seq, gamma, 3, [np.array([[sig2]])] * len(seq))
    C, m = oa.kron_C_const(seq), oa.m_const([[sig2]])
    lb = oa.lambda_bar(seq, [np.array([[sig2]])] * len(seq))
    # with aligned kernels rho equals psi, so (37) as printed is valid here
    assert rho == pytest.approx(oa.psi(gamma, lb))
    assert np.linalg.norm(Sigma, "fro") <= oa.bound_37(gamma, 3, C, m, lb)
    assert np.sqrt(np.trace(Sigma)) <= oa.rms_bound_consistent(gamma, 3, N, C, m, 0.0, rho)


def test_printed_bound_38_and_H_s_differ():
    g, tau, C, m, Dx, lb = 0.4, 5, 1.0, 4 * np.sqrt(3), 1.0, 0.1
    assert oa.bound_38(g, tau, C, m, Dx, lb) == pytest.approx(
        tau * np.sqrt(C ** 2 * m ** 2 / g ** 4 + Dx ** 2) * (1 + g / lb))
    assert oa.H_s_printed(g, tau, C * m, Dx, lb) == pytest.approx(
        tau * np.sqrt(m ** 2 / g ** 4 + Dx ** 2 * (1 + g / lb)))


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="columns"):
        oa.smallest_tau([np.ones((1, 2)), np.ones((1, 3))])
    with pytest.raises(ValueError, match="Q_seq"):
        oa.lambda_bar([np.ones((2, 2))], [np.eye(3)])
    with pytest.raises(ValueError, match="positive definite"):
        oa.c_const([np.ones((1, 2))], [np.array([[-1.0]])])
    with pytest.raises(ValueError, match="gamma"):
        oa.psi(0.0, 1.0)
    with pytest.raises(ValueError, match="tau"):
        oa.window_contraction([np.ones((1, 2))], 1.0, 3)
