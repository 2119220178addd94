"""The explicit vector helpers of netsense.kernels.lanes against scalar references, bit for bit."""

import numpy as np
import pytest
from numba import njit

from netsense.kernels.lanes import (
    block_triangular_pair,
    block_triangular_row,
    copy_span,
    row_times_matrix,
    square_sums,
)


@njit(_nrt=False)
def _rows(Z_sel, Z, ADT, ALT, out):
    for b in range(Z.shape[0]):
        for i in range(Z.shape[1]):
            block_triangular_row(out, b, i, Z_sel, b, i, ADT, Z, b, i, ALT)


@njit(_nrt=False)
def _pairs(Z_sel, Z, ADT, ALT, out):  # rows (0, 1), (2, 3) of each member (N = 4)
    for b in range(Z.shape[0]):
        for i in range(0, Z.shape[1], 2):
            block_triangular_pair(out, b, i, Z_sel, b, i, ADT, Z, b, i, ALT)


def _scalar_row(z_sel, z, ADT, ALT):
    """The documented order in plain Python floats: start at 0.0, then the block
    diagonal's non-zeros for q ascending, then every ``A_lower`` entry for q ascending."""
    n = len(z)
    out = np.empty(n)
    for c in range(n):
        o = 0.0
        for q in range(n):
            if ADT[q, c] != 0:
                o = o + float(ADT[q, c]) * float(z_sel[q])
        for q in range(n):
            o = o + float(ALT[q, c]) * float(z[q])
        out[c] = o
    return out


def _block_diagonal(rng, sizes):
    n = sum(sizes)
    A = np.zeros((n, n))
    s = 0
    for k in sizes:
        A[s:s + k, s:s + k] = rng.standard_normal((k, k))
        s += k
    return A


@pytest.mark.parametrize("sizes", [[1], [2, 1, 3], [4, 2, 2, 1, 1], [3] * 7, [5] * 8 + [1],
                                   [10, 7, 9, 11, 3, 1, 2]])
def test_block_triangular_row_is_the_scalar_sum_bit_for_bit(sizes):
    # n from 1 to 43: one to four accumulators, several passes, a masked end everywhere
    rng = np.random.default_rng(len(sizes) * 100 + sum(sizes))
    n = sum(sizes)
    ADT = _block_diagonal(rng, sizes).T.copy()
    ADT[0, 0] = 0.0 if n > 1 else ADT[0, 0]  # a zero inside a block is skipped too
    ALT = np.tril(rng.standard_normal((n, n)), -1).T.copy()
    ALT[ALT != 0] *= rng.choice([1.0, 1e-16, 1e16], size=np.count_nonzero(ALT))
    B, N = 3, 4
    Z = rng.standard_normal((B, N, n)) * rng.choice([1e-300, 1.0, 1e300], size=(B, N, n))
    Z_sel = rng.standard_normal((B, N, n))
    Z[0, 1, :] = 0.0
    Z_sel[0, 1, :] = -0.0  # -0 terms: the sum starts at +0 and stays +0
    Z[1, 2] = rng.standard_normal(n)  # moderate values: no overflow in this row
    Z_sel[1, 2, n - 1] = np.inf  # reaches only the last block's columns
    Z[2, 3, 0] = np.nan  # reaches every column A_lower couples to it
    out = np.full((B, N, n), 7.0)
    pairs = np.full((B, N, n), 7.0)
    _rows(Z_sel, Z, ADT, ALT, out)
    _pairs(Z_sel, Z, ADT, ALT, pairs)  # two rows in one loop: each the same bits
    for b in range(B):
        for i in range(N):
            ref = _scalar_row(Z_sel[b, i], Z[b, i], ADT, ALT)
            np.testing.assert_array_equal(out[b, i].view(np.int64), ref.view(np.int64),
                                          err_msg=f"row {b, i}")
            np.testing.assert_array_equal(pairs[b, i].view(np.int64), ref.view(np.int64),
                                          err_msg=f"pair row {b, i}")
    assert np.isfinite(out[1, 2, :n - sizes[-1]]).all()  # the inf stayed in its block


@njit(_nrt=False)
def _copy(dst, d0, src, s0, count):
    copy_span(dst, d0, src, s0, count)


@pytest.mark.parametrize("dtype", [np.int8, np.bool_, np.int16, np.float32, np.int64,
                                   np.float64])
def test_copy_span_copies_exactly_the_span(dtype):
    rng = np.random.default_rng(1)
    for count in (0, 1, 5, 7, 8, 15, 16, 17, 63, 64, 65, 130):
        src = rng.integers(0, 2 if dtype is np.bool_ else 100, size=count + 9).astype(dtype)
        dst = np.zeros(count + 20, dtype=dtype)
        before = dst.copy()
        _copy(dst, 6, src, 3, count)
        expect = before.copy()
        expect[6:6 + count] = src[3:3 + count]
        np.testing.assert_array_equal(dst, expect, err_msg=f"count {count}")


def test_copy_span_counts_flat_positions_of_any_c_array():
    src = np.arange(2 * 3 * 5, dtype=np.int8).reshape(2, 3, 5)
    dst = np.zeros((4, 3, 5), dtype=np.int8)
    _copy(dst, 15 + 2, src, 4, 20)  # into member 1 from its third entry, across rows
    expect = np.zeros(60, dtype=np.int8)
    expect[17:37] = src.reshape(-1)[4:24]
    np.testing.assert_array_equal(dst.reshape(-1), expect)


@njit(_nrt=False)
def _products(x, A, out):
    for b in range(x.shape[0]):
        row_times_matrix(out, b, x, b, A)


@pytest.mark.parametrize("p, m", [(1, 1), (10, 10), (3, 17), (20, 9), (7, 33), (40, 65)])
def test_row_times_matrix_is_the_scalar_sum_bit_for_bit(p, m):
    # m from 1 to 65: one to four accumulators, two passes, a masked end; p != m
    rng = np.random.default_rng(p * 100 + m)
    A = rng.standard_normal((p, m)) * rng.choice([1e-16, 1.0, 1e16], size=(p, m))
    A[:, 0] = 0.0  # zero entries are added (0 * inf = nan reaches the column)
    x = rng.standard_normal((4, p)) * rng.choice([1e-300, 1.0, 1e300], size=(4, p))
    x[1] = -0.0  # -0 terms: every column stays +0
    x[2, p - 1] = np.inf
    x[3, 0] = np.nan
    out = np.full((4, m), 7.0)
    _products(x, A, out)
    for b in range(4):
        ref = np.empty(m)
        for c in range(m):
            o = 0.0
            for q in range(p):
                o = o + float(x[b, q]) * float(A[q, c])
            ref[c] = o
        np.testing.assert_array_equal(out[b].view(np.int64), ref.view(np.int64),
                                      err_msg=f"row {b}")
    assert np.isnan(out[2, 0]) and np.isnan(out[3]).all()
    assert not np.signbit(out[1]).any() and not out[1].any()


@njit(_nrt=False)
def _square_sums(out, Z, t):
    for b in range(Z.shape[0]):
        square_sums(out, b, Z, b, t, b)


@njit(_nrt=False)
def _plain_square_sums(out, Z):
    for b in range(Z.shape[0]):
        square_sums(out, b, Z, b, None, 0)


@pytest.mark.parametrize("N, n", [(1, 1), (10, 10), (3, 17), (30, 20), (17, 1), (4, 8),
                                  (5, 9)])
def test_square_sums_are_the_scalar_sums_bit_for_bit(N, n):
    # rows of 1 to 20 columns: a full vector, a masked end, both; with and without t
    rng = np.random.default_rng(N * 100 + n)
    B = 3
    Z = rng.standard_normal((B, N, n)) * rng.choice([1e-200, 1.0, 1e150], size=(B, N, n))
    t = rng.standard_normal((B, n))
    Z[0, 0, 0] = np.nan
    Z[1, N - 1, n - 1] = np.inf
    Z[2, 0] = t[2]  # a row equal to t: exactly +0
    for centred in (True, False):
        out = np.full((B, N + 1), 7.0)
        if centred:
            _square_sums(out, Z, t)
        else:
            _plain_square_sums(out, Z)
        for b in range(B):
            for i in range(N):
                o = 0.0
                for c in range(n):
                    e = float(Z[b, i, c]) - (float(t[b, c]) if centred else 0.0)
                    o = o + e * e
                assert out[b, i].tobytes() == np.float64(o).tobytes(), (centred, b, i)
            assert out[b, N] == 7.0  # nothing written past the N rows
        assert np.isnan(out[0, 0]) and np.isinf(out[1, N - 1])
        assert (out[2, 0] == 0.0) == centred
