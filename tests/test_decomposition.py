"""Lemma 1: properties of the decomposition on hundreds of random systems."""

import numpy as np
import pytest

from netsense import decompose, random_structured


def obs_rank(A, C):
    """Rank of the observability matrix, computed independently with numpy."""
    n = A.shape[0]
    if C.shape[0] == 0:
        return 0
    O = np.vstack([C @ np.linalg.matrix_power(A, k) for k in range(n)])
    return np.linalg.matrix_rank(O, tol=1e-8 * max(1.0, np.linalg.norm(O, 2)))


def random_system(rng):
    n = int(rng.integers(1, 7))
    N = int(rng.integers(1, 5))
    A = rng.standard_normal((n, n))
    Cs = [rng.standard_normal((int(rng.integers(0, 3)), n)) for _ in range(N)]
    return A, Cs


def check_properties(A, Cs, dec):
    n = A.shape[0]
    scale = max(1.0, np.linalg.norm(A, 2))
    T = dec.T
    assert np.allclose(T.T @ T, np.eye(n), atol=1e-12)
    assert np.allclose(dec.A_bar, T.T @ A @ T, atol=1e-12 * scale)
    assert sum(dec.sizes) == n
    o = dec.offsets
    for j in range(len(Cs)):
        # block lower-triangular (eq. (3)) and C_bar_j zero right of block j
        assert np.abs(dec.A_bar[o[j]:o[j + 1], o[j + 1]:]).max(initial=0) <= 1e-6 * scale
        assert np.abs(dec.C_bar[j][:, o[j + 1]:]).max(initial=0) <= 1e-6 * max(
            1.0, np.linalg.norm(Cs[j], 2) if Cs[j].size else 1.0)
        if dec.sizes[j]:
            assert obs_rank(dec.A_jj(j), dec.C_jj(j)) == dec.sizes[j]
    # sizes agree with the rank increments of the stacked observability matrices
    ranks = [0] + [obs_rank(A, np.vstack([np.zeros((0, n))] + list(Cs[: j + 1])))
                   for j in range(len(Cs))]
    assert list(dec.sizes) == list(np.diff(ranks))


def test_random_generic_systems():
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(400):
        A, Cs = random_system(rng)
        rank = obs_rank(A, np.vstack([np.zeros((0, A.shape[0]))] + Cs))
        if rank < A.shape[0]:
            with pytest.raises(ValueError, match=f"dimension {A.shape[0] - rank}"):
                decompose(A, Cs)
            continue
        check_properties(A, Cs, decompose(A, Cs))
        checked += 1
    assert checked > 150


@pytest.mark.parametrize("seed", range(60))
def test_random_structured_systems(seed):
    plant = random_structured(12, 6, rng=seed, num_sources=3)
    dec = decompose(plant.A, plant.C)
    check_properties(plant.A, list(plant.C), dec)
    assert sum(s > 0 for s in dec.sizes) == 3  # several agents own substates


def test_unobservable_reports_dimension():
    A = np.diag([1.0, 2.0, 3.0])
    Cs = [np.array([[1.0, 0.0, 0.0]]), np.zeros((0, 3))]
    with pytest.raises(ValueError, match="dimension 2"):
        decompose(A, Cs)


def test_bad_shapes():
    with pytest.raises(ValueError, match="square"):
        decompose(np.ones((2, 3)), [np.ones((1, 3))])
    with pytest.raises(ValueError, match=r"C\[1\]"):
        decompose(np.eye(2), [np.ones((1, 2)), np.ones((1, 3))])


def test_scaled_system_same_structure():
    """Tolerances are relative: scaling A and C by 1e6 keeps the decomposition."""
    plant = random_structured(8, 4, rng=3, num_sources=2)
    d1 = decompose(plant.A, plant.C)
    d2 = decompose(plant.A * 1e6, [C * 1e6 for C in plant.C])
    assert d1.sizes == d2.sizes
