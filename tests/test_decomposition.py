"""Lemma 1: properties of the decomposition on hundreds of random systems."""

import numpy as np
import pytest

from netsense import decompose, random_structured
from netsense.systems.decomposition import refine_structure


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


def check_structure(A, Cs, dec):
    """Orthogonal T, Lemma 1's zero pattern exactly, and the residuals as reported."""
    n = A.shape[0]
    scale = max(1.0, np.linalg.norm(A, 2))
    T = dec.T
    assert np.allclose(T.T @ T, np.eye(n), atol=1e-12)
    assert np.allclose(dec.A_bar, T.T @ A @ T, atol=1e-12 * scale)
    assert sum(dec.sizes) == n
    o = dec.offsets
    for j in range(len(Cs)):
        # block lower-triangular (eq. (3)) and C_bar_j zero right of block j, exactly
        assert not np.any(dec.A_bar[o[j]:o[j + 1], o[j + 1]:])
        assert not np.any(dec.C_bar[j][:, o[j + 1]:])
        assert np.allclose(dec.C_bar[j], Cs[j] @ T, atol=1e-6 * max(
            1.0, np.linalg.norm(Cs[j], 2) if Cs[j].size else 1.0))
    # what the zero pattern dropped is what is reported
    assert np.linalg.norm(T.T @ A @ T - dec.A_bar, 2) == pytest.approx(
        dec.residual_A * np.linalg.norm(A, 2), rel=1e-6, abs=1e-300)
    res_C = max([np.linalg.norm(Ci @ T - Cb, 2) / np.linalg.norm(Ci, 2)
                 for Ci, Cb in zip(Cs, dec.C_bar, strict=True) if Ci.size] + [0.0])
    assert res_C == pytest.approx(dec.residual_C, rel=1e-6, abs=1e-300)


def check_properties(A, Cs, dec):
    check_structure(A, Cs, dec)
    n = A.shape[0]
    for j in range(len(Cs)):
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


@pytest.mark.parametrize("seed", range(40))
def test_structure_holds_to_rounding_after_refinement(seed):
    """Many single-output sources: the staircase's own error grows along the cascade (to
    1e-13 - 1e-7); the refined T leaves only rounding, on A and on every C_i."""
    rng = np.random.default_rng(seed)
    N = int(rng.integers(4, 11))
    plant = random_structured(int(rng.integers(N, 31)), N, num_sources=N,
                              outputs_per_source=int(rng.integers(1, 3)),
                              spectral_radius=float(rng.uniform(0.9, 1.1)), rng=seed)
    dec = decompose(plant.A, plant.C)
    assert max(dec.residual_A, dec.residual_C) <= 2e-15
    check_structure(plant.A, list(plant.C), dec)


def test_issue_plant_refinement():
    """The issue's plant: 3.3e-13 above the diagonal without the refinement, rounding
    with it; the sizes (rank decisions) are the same."""
    plant = random_structured(8, 7, num_sources=7, outputs_per_source=1,
                              spectral_radius=1.05, rng=65)
    raw = decompose(plant.A, plant.C, refine=False)
    dec = decompose(plant.A, plant.C)
    assert raw.sizes == dec.sizes
    assert raw.residual_A > 1e-13
    assert dec.residual_A < 1e-15 and dec.residual_C < 1e-15


def test_refine_structure_is_orthogonal_and_keeps_blocks():
    plant = random_structured(20, 8, num_sources=6, outputs_per_source=1, rng=4)
    raw = decompose(plant.A, plant.C, refine=False)
    T, res_A, res_C = refine_structure(plant.A, plant.C, raw.T, raw.sizes)
    assert np.allclose(T.T @ T, np.eye(20), atol=1e-14)
    assert max(res_A, res_C) < max(raw.residual_A, raw.residual_C)
    # each block still spans (nearly) the same subspace: a small rotation of T
    for j in range(8):
        b = raw.block(j)
        if raw.sizes[j]:
            s = np.linalg.svd(raw.T[:, b].T @ T[:, b], compute_uv=False)
            assert s.min() > 1 - 1e-6
