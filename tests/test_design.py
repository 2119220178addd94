"""Theorem 1 / Corollary 1 gain design."""

import numpy as np
import pytest

from netsense import deadbeat_gain, design_observer, random_structured, rate_gain


@pytest.mark.parametrize("seed", range(10))
def test_rate_design(seed):
    plant = random_structured(10, 5, rng=seed, num_sources=3)
    des = design_observer(plant, rho=0.7)
    active = [j for j, s in enumerate(des.decomposition.sizes) if s]
    rates = [des.rates[j] for j in active]
    assert all(0 < a < b <= 0.7 for a, b in zip(rates, rates[1:] + [0.7], strict=True))
    assert rates[-1] < 0.7
    for j in active:
        eig = np.linalg.eigvals(des.closed_loop(j))
        assert np.allclose(eig.imag, 0, atol=1e-8)  # real
        assert np.isclose(np.abs(eig).max(), des.rates[j], atol=1e-8)  # spectral radius rho_j
        assert len(np.unique(np.round(eig.real, 6))) == eig.size  # distinct


def test_deadbeat_multi_output_non_cyclic():
    """A = 2 I with two outputs is not cyclic: place_poles cannot do it, Heymann can."""
    A = 2 * np.eye(3)
    C = np.array([[1.0, 0, 0], [0, 1.0, 1.0], [0, 0, 1.0]])
    L = deadbeat_gain(A, C)
    M = A - L @ C
    assert np.linalg.norm(np.linalg.matrix_power(M, 3)) < 1e-9
    assert np.allclose(np.linalg.eigvals(M), 0, atol=1e-4)


def test_deadbeat_mimo_block():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((5, 5))
    C = rng.standard_normal((2, 5))
    L = deadbeat_gain(A, C)
    assert np.linalg.norm(np.linalg.matrix_power(A - L @ C, 5)) < 1e-8 * np.linalg.norm(A) ** 5


def test_errors():
    plant = random_structured(6, 3, rng=0, num_sources=2)
    with pytest.raises(ValueError, match="rho"):
        design_observer(plant, rho=1.5)
    with pytest.raises(ValueError, match="rates"):
        design_observer(plant, rho=0.5, rates=[0.4, 0.3, 0.2])
    with pytest.raises(ValueError, match="observable"):
        deadbeat_gain(np.eye(2), np.array([[1.0, 0.0]]))
    with pytest.raises(ValueError, match="rho_j"):
        rate_gain(np.eye(1), np.ones((1, 1)), 0.0)


def test_deadbeat_one_state_is_minimum_norm():
    """The issue's block: Heymann's feedback gave ||L|| = 840 (rng=298); a c^T / ||c||^2."""
    A, C = np.array([[1.1]]), np.array([[1.0], [0.5], [-0.8]])
    L = deadbeat_gain(A, C, rng=298)
    assert np.allclose(L, 1.1 * C.T / (C.T @ C), rtol=1e-14)
    assert np.array_equal(L, deadbeat_gain(A, C, rng=1))  # deterministic, rng ignored


def test_deadbeat_full_output_is_A():
    """With C = I the minimum-norm deadbeat gain is A itself (A - L C = 0)."""
    A = np.array([[1.05, 0.3], [-0.2, 0.9]])
    L = deadbeat_gain(A, np.eye(2))
    assert np.allclose(L, A, atol=1e-15)


@pytest.mark.parametrize("seed", range(20))
def test_deadbeat_random_blocks(seed):
    """Nilpotent to rounding; the gain is never far above the best of many Heymann draws
    (the old design, which is the minimum-norm gain for one output)."""
    rng = np.random.default_rng(seed)
    n, r = int(rng.integers(2, 8)), int(rng.integers(1, 4))
    A, C = rng.standard_normal((n, n)), rng.standard_normal((r, n))
    L = deadbeat_gain(A, C)
    M = A - L @ C
    s = max(np.linalg.norm(A, 2), np.linalg.norm(L, 2) * np.linalg.norm(C, 2))
    assert np.linalg.norm(np.linalg.matrix_power(M / s, n), 2) < 1e-13
    # eigenvalues of a nilpotent matrix known to ~eps s lie within ~(n eps)^(1/n) s of 0
    assert np.abs(np.linalg.eigvals(M)).max() < 10 * (n * np.finfo(float).eps) ** (1 / n) * s


def test_design_reports_gain_norms_and_nilpotency():
    plant = random_structured(9, 4, num_sources=4, outputs_per_source=3,
                              spectral_radius=1.086, rng=13)
    db = design_observer(plant, deadbeat=True, rng=13)
    d = db.decomposition
    for j, size in enumerate(d.sizes):
        if size == 0:
            assert np.isnan(db.gain_norms[j]) and np.isnan(db.nilpotency_residuals[j])
            continue
        assert db.gain_norms[j] == pytest.approx(np.linalg.norm(db.gains[j], 2))
        assert db.nilpotency_residuals[j] < 1e-14
        if size == 1:  # the 1-state block had 2.0e4; the minimum is 0.92
            assert db.gain_norms[j] == pytest.approx(
                abs(d.A_jj(j)[0, 0]) / np.linalg.norm(d.C_jj(j)), rel=1e-12)
    rate = design_observer(plant, rho=0.5, decomposition=d)
    assert all(np.isnan(rate.nilpotency_residuals))
    assert all(g > 0 for g, s in zip(rate.gain_norms, d.sizes, strict=True) if s)
