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
