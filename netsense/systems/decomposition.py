"""Multi-sensor observable decomposition (Lemma 1 of the freshness-index paper).

For an observable pair ``(A, C)`` with ``C = [C_1; ...; C_N]`` we build an orthogonal
``T`` such that, with ``x = T z``,

.. math::  \\bar A = T^{-1} A T \\text{ block lower-triangular (eq. (3))}, \\qquad
           \\bar C_i = C_i T = [C_{i1} \\cdots C_{ii} \\; 0 \\cdots 0],

and every diagonal pair ``(A_jj, C_jj)`` with ``n_j > 0`` is observable. Substate ``j``
(eq. (5)) is owned by agent ``j``, its *source node*.

Construction. Let ``U_j`` be the unobservable subspace of ``(A, [C_1; ...; C_j])`` (so
``U_0 = R^n``). These subspaces are ``A``-invariant and nested,
``U_0 ⊇ U_1 ⊇ ... ⊇ U_N = {0}`` (the last because ``(A, C)`` is observable). Block ``j``
of ``T`` is an orthonormal basis of the orthogonal complement of ``U_j`` inside
``U_{j-1}``; invariance of ``U_j`` gives the zero blocks above the diagonal, and
``U_j ⊆ ker C_j`` gives the zero blocks of ``C_bar_j``. Block ``j`` is the observable
subspace of ``A`` restricted to ``U_{j-1}`` with output ``C_j``, computed by an orthogonal
staircase (orthonormal bases and SVD rank decisions only; no powers of ``A``, no
observability matrices), with tolerances relative to ``||A||`` and ``||C_j||``.

Exact zero pattern. In floating point the staircase leaves rounding-level entries where
Lemma 1 has zeros, and it leaves more than rounding: each agent's block is computed inside
the previous complement, so an error of ``U_{j-1}`` reaches ``C_j U_{j-1}`` amplified by
``||C_j|| / ||C_jj||`` (3e-13 after six single-output agents, 2e-7 at n = 100). Such
entries are not harmless even at 1e-18: the freshness observer's error feeds through them
from later substates back into earlier ones over stale (delayed) copies, a loop whose gain
``eps * (gamma / rho)^delay`` is of order one, so the error decays more slowly than
Theorem 1's rate (``docs/theory.md``). Two steps remove them:

1. *Refinement* (:func:`refine_structure`): Newton steps on the orthogonal ``T`` that drive
   the entries above the block diagonal of ``T^T A T`` and right of block ``i`` in
   ``C_i T`` to rounding level, all pairs of blocks at once (a sparse least-squares
   problem in the rotation angles; one to three steps take 2e-7 to ~5e-16).
2. *Structure*: ``A_bar`` and ``C_bar`` are then *defined* with exact zeros in those
   positions. What was dropped is reported, relative to ``||A||`` and ``||C_i||``, as
   :attr:`Decomposition.residual_A` and :attr:`Decomposition.residual_C`: the plant in
   Lemma 1's coordinates is ``T^T A T = A_bar + E_A`` with ``||E_A|| <= residual_A ||A||``,
   a mismatch that enters the observers' error as a forcing proportional to the state
   (``docs/theory.md``), like the rounding of the plant's own simulation.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from netsense.kernels import checks

#: Default relative tolerance for the rank decisions of the decomposition.
DEFAULT_RTOL = 1e-7


@dataclass(frozen=True, eq=False)
class Decomposition:
    """Result of :func:`decompose`.

    Attributes
    ----------
    T : (n, n) array
        Orthogonal transformation, ``x = T z`` (so ``T^{-1} = T^T``).
    sizes : tuple of int
        ``n_j`` for every agent ``j`` (zero when agent ``j`` owns no substate).
    A_bar : (n, n) array
        ``T^T A T`` with the blocks above the diagonal set to exactly zero: block
        lower-triangular with blocks of ``sizes`` (eq. (3)).
    C_bar : tuple of arrays
        ``C_i T`` for every agent, set to exactly zero right of block ``i``.
    residual_A : float
        ``||T^T A T - A_bar||_2 / ||A||_2``: the relative size of what the zero pattern
        dropped (rounding level, ~1e-16, after the refinement; larger only for a plant that
        is merely close to one with the structure, within the rank tolerance).
    residual_C : float
        ``max_i ||C_i T - C_bar_i||_2 / ||C_i||_2``, likewise.
    """

    T: np.ndarray
    sizes: tuple[int, ...]
    A_bar: np.ndarray
    C_bar: tuple[np.ndarray, ...]
    residual_A: float = 0.0
    residual_C: float = 0.0

    @property
    def n(self) -> int:
        """State dimension."""
        return self.T.shape[0]

    @property
    def num_agents(self) -> int:
        """Number of agents N."""
        return len(self.sizes)

    @property
    def offsets(self) -> np.ndarray:
        """``(N + 1,)`` start offsets of the substates in ``z``."""
        return np.concatenate([[0], np.cumsum(self.sizes)]).astype(int)

    def block(self, j: int) -> slice:
        """Slice of substate ``j`` in ``z``."""
        o = self.offsets
        return slice(int(o[j]), int(o[j + 1]))

    @property
    def block_of(self) -> np.ndarray:
        """``(n,)`` array: the substate each coordinate of ``z`` belongs to."""
        return np.repeat(np.arange(self.num_agents), self.sizes)

    def A_jj(self, j: int) -> np.ndarray:
        """Diagonal block ``A_jj`` of eq. (3)."""
        b = self.block(j)
        return self.A_bar[b, b]

    def C_jj(self, j: int) -> np.ndarray:
        """Diagonal block ``C_jj`` of the source agent ``j``."""
        return self.C_bar[j][:, self.block(j)]

    @property
    def A_diag(self) -> np.ndarray:
        """Block-diagonal part ``blkdiag(A_11, ..., A_NN)`` of ``A_bar``."""
        mask = self.block_of[:, None] == self.block_of[None, :]
        return np.where(mask, self.A_bar, 0.0)

    @property
    def A_lower(self) -> np.ndarray:
        """``A_bar`` minus its block diagonal: the couplings ``A_jq``, ``q < j``, of eq. (3).

        The blocks above the diagonal are exactly zero, so no substate's estimate depends
        on an agent's estimates of later substates (the cascade of Theorem 1's proof).
        Before the refinement and the zero pattern the decomposition's error stood there
        (largest entry 5e-15 at n = 10, 7e-10 at N = 100, n = 20 and 3e-7 at N = 30,
        n = 80 in the benchmark models, against ``|A_bar| ~ 1.1``); what is dropped now is
        :attr:`residual_A`.
        """
        return self.A_bar - self.A_diag

    def to_z(self, x: np.ndarray) -> np.ndarray:
        """``z = T^T x`` along the last axis."""
        return np.asarray(x) @ self.T

    def to_x(self, z: np.ndarray) -> np.ndarray:
        """``x = T z`` along the last axis."""
        return np.asarray(z) @ self.T.T


def _complement_in(V: np.ndarray, U: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the orthogonal complement of span(U) inside span(V).

    ``U`` must span a subspace of span(V); both have orthonormal columns.
    """
    if U.shape[1] == 0:
        return V
    # Coordinates of U in the V basis; the complement is V times their orthogonal complement.
    coords = V.T @ U
    q, _ = np.linalg.qr(coords, mode="complete")
    return V @ q[:, U.shape[1]:]


def _range_basis(M: np.ndarray, tol: float) -> np.ndarray:
    """Orthonormal basis (columns) of range(M), rank decided by singular values > tol."""
    if M.size == 0:
        return np.zeros((M.shape[0], 0))
    u, s, _ = np.linalg.svd(M, full_matrices=False)
    return u[:, : int(np.sum(s > tol))]


def observable_subspace(A: np.ndarray, C: np.ndarray, tol: float) -> np.ndarray:
    """Orthonormal basis of the observable subspace (row space of the observability matrix).

    Orthogonal staircase algorithm on the dual pair ``(A^T, C^T)``: start from range(C^T)
    and repeatedly add the part of ``A^T`` times the newest block that is orthogonal to
    what is already spanned. Only orthonormal bases and SVD rank decisions are used, so no
    power of ``A`` is ever formed.
    """
    n = A.shape[0]
    if C.shape[0] == 0:
        return np.zeros((n, 0))
    R = _range_basis(C.T, tol)
    last = R
    while last.shape[1] > 0 and R.shape[1] < n:
        M = A.T @ last
        M = M - R @ (R.T @ M)
        M = M - R @ (R.T @ M)  # re-orthogonalise once (classical Gram-Schmidt twice)
        last = _range_basis(M, tol)
        R = np.hstack([R, last])
    return R


def unobservable_subspace(A, C, rtol: float = DEFAULT_RTOL) -> np.ndarray:
    """Orthonormal basis of the unobservable subspace of ``(A, C)``."""
    A = checks.array("A", A, (None, None), kind="f")
    C = checks.array("C", C, kind="f")
    A = np.asarray(A, dtype=float)
    C = np.asarray(C, dtype=float).reshape(-1, A.shape[0])
    scale = max(np.linalg.norm(A, 2), np.linalg.norm(C, 2) if C.size else 0.0, 1.0)
    O = observable_subspace(A, C, rtol * scale)
    return _complement_in(np.eye(A.shape[0]), O)


def decompose(A, Cs: Sequence, *, rtol: float = DEFAULT_RTOL,
              refine: bool = True) -> Decomposition:
    """Multi-sensor observable decomposition of Lemma 1.

    Parameters
    ----------
    A : (n, n) array_like
        System matrix.
    Cs : sequence of N array_like, each (r_i, n)
        Output matrix of each agent (``r_i = 0`` allowed).
    rtol : float
        Relative tolerance of the rank decisions; singular values below
        ``rtol * max(||A||, ||C_j||, 1)`` count as zero.
    refine : bool
        Refine ``T`` (:func:`refine_structure`) before imposing the zero pattern; without
        it the staircase's ``T`` is used as it is (its residual is reported all the same).

    Returns
    -------
    Decomposition
        ``T``, the sizes ``n_j`` and the blocks ``A_bar``, ``C_bar_i``.

    Raises
    ------
    ValueError
        If shapes are inconsistent, or if ``(A, C)`` is not observable (the message gives
        the dimension of the unobservable subspace).
    """
    A = checks.array("A", A, kind="f")
    if isinstance(Cs, (str, bytes)) or not isinstance(Cs, (Sequence, np.ndarray)):
        raise ValueError(f"Cs must be a sequence of output matrices, one per agent, got "
                         f"{type(Cs).__name__}")
    Cs = [checks.array(f"C[{i}]", Ci, kind="f") for i, Ci in enumerate(Cs)]
    checks.number("rtol", rtol, 0, 1, lo_open=True, hi_open=True)
    A = np.asarray(A, dtype=float)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or A.shape[0] == 0:
        raise ValueError(f"A must be a non-empty square matrix, got shape {A.shape}")
    n = A.shape[0]
    if not np.all(np.isfinite(A)):
        raise ValueError("A contains NaN or infinite entries")
    Cs_arr = []
    for i, Ci in enumerate(Cs):
        Ci = np.asarray(Ci, dtype=float)
        if Ci.size == 0:
            Ci = Ci.reshape(0, n)
        if Ci.ndim != 2 or Ci.shape[1] != n:
            raise ValueError(f"C[{i}] must have shape (r_{i}, {n}), got {Ci.shape}")
        if not np.all(np.isfinite(Ci)):
            raise ValueError(f"C[{i}] contains NaN or infinite entries")
        Cs_arr.append(Ci)
    if not Cs_arr:
        raise ValueError("Cs must hold at least one agent's output matrix")
    if not 0 < rtol < 1:
        raise ValueError(f"rtol must be in (0, 1), got {rtol}")
    normA = np.linalg.norm(A, 2)

    U_prev = np.eye(n)
    blocks, sizes = [], []
    for Ci in Cs_arr:
        scale = max(normA, np.linalg.norm(Ci, 2) if Ci.size else 0.0, 1.0)
        if Ci.shape[0] == 0 or U_prev.shape[1] == 0:
            Bj = np.zeros((n, 0))
        else:
            # Restrict to the A-invariant subspace U_{j-1}; the observable part of the
            # restricted pair is block j, its complement is U_j.
            A_r = U_prev.T @ A @ U_prev
            O_r = observable_subspace(A_r, Ci @ U_prev, rtol * scale)
            Bj = U_prev @ O_r
            U_prev = _complement_in(U_prev, Bj)
        blocks.append(Bj)
        sizes.append(Bj.shape[1])
    if U_prev.shape[1] > 0:
        raise ValueError(f"(A, C) is not observable: the unobservable subspace has dimension "
                         f"{U_prev.shape[1]} (of n = {n})")
    T = np.hstack(blocks)
    if refine:
        T = refine_structure(A, Cs_arr, T, sizes)[0]
    # Lemma 1's zero pattern, exactly (module docstring; what it drops is the residual).
    block_of = np.repeat(np.arange(len(sizes)), sizes)
    scale_C = [max(float(np.linalg.norm(Ci, 2)), np.finfo(float).tiny) if Ci.size else 1.0
               for Ci in Cs_arr]
    A_full, C_full, res_A, res_C = _structure_residual(
        A, Cs_arr, T, block_of, max(float(normA), np.finfo(float).tiny), scale_C)
    A_bar = np.where(block_of[:, None] >= block_of[None, :], A_full, 0.0)
    C_bar = tuple(np.where(block_of[None, :] <= i, Ci, 0.0) for i, Ci in enumerate(C_full))
    return Decomposition(T=T, sizes=tuple(int(s) for s in sizes), A_bar=A_bar, C_bar=C_bar,
                         residual_A=res_A, residual_C=res_C)


def _structure_residual(A, Cs, T, block_of, scale_A, scale_C):
    """``(T^T A T, [C_i T], residual_A, residual_C)`` for the zero pattern of ``block_of``."""
    A_full = T.T @ A @ T
    C_full = [Ci @ T for Ci in Cs]
    upper = block_of[:, None] < block_of[None, :]
    res_A = np.linalg.norm(np.where(upper, A_full, 0.0), 2) / scale_A
    res_C = 0.0
    for i, (Ci, sc) in enumerate(zip(C_full, scale_C, strict=True)):
        if Ci.size:
            right = np.where(block_of[None, :] > i, Ci, 0.0)
            res_C = max(res_C, float(np.linalg.norm(right, 2)) / sc)
    return A_full, C_full, float(res_A), res_C


#: Up to this many unknowns the Newton step is a dense least-squares solve (exact, and
#: cheap there); above it LSMR on the sparse Jacobian with unit-norm columns, started
#: from :func:`_pairwise_guess` (n = 100: 0.9 s instead of 4 s from zero; the blocks of
#: ``random_structured`` all share the spectral radius, which leaves the entry between
#: two blocks to be zeroed through the others, hence an ill-conditioned system).
_DENSE_MAX = 300


def _newton_system(A_full, C_full, block_of, scale_A, scale_C):
    """Jacobian ``J`` (sparse) and residual ``r`` of the zero pattern, and the unknowns.

    With ``T' = T exp(S)``, ``S`` skew, to first order ``A' = A_full + A_full S - S A_full``
    and ``C_i' = C_i + C_i S``. The unknowns are ``S[a, b]`` for ``block(a) > block(b)``
    (``S[b, a] = -S[a, b]``; rotations inside a block change nothing). The equations are
    the entries above the block diagonal of ``A'`` (scaled by ``1 / ||A||``) and right of
    block ``i`` in ``C_i'`` (scaled by ``1 / ||C_i||``); ``J x = -r`` zeroes them to first
    order. Every pair of blocks is solved at once: when two blocks share an eigenvalue (in
    :func:`~netsense.systems.random_structured` every block has one at the spectral
    radius) the entry between them can only be zeroed through the others.
    """
    import scipy.sparse as sps  # lazy: the make path must not import scipy.sparse
    n = A_full.shape[0]
    a, b = np.nonzero(block_of[:, None] > block_of[None, :])
    m = a.size
    upper = block_of[:, None] < block_of[None, :]
    eq = np.full((n, n), -1, dtype=np.int64)
    eq[upper] = np.arange(int(upper.sum()))
    k = np.broadcast_to(np.arange(m)[:, None], (m, n))
    r_ = np.arange(n)[None, :]
    # d(A_full S - S A_full)/dS[a, b] with S = e_a e_b^T - e_b e_a^T, entry (r, c):
    # A[r, a] [c = b] - A[r, b] [c = a] - [r = a] A[b, c] + [r = b] A[a, c]. At an entry
    # above the block diagonal the first and third terms are entries above it too (the
    # small ones being removed), so they are left out: J is the Jacobian at the nearby
    # block lower-triangular matrix, half as many non-zeros, the same Newton step to
    # first order.
    terms = [(eq[r_, a[:, None]], -A_full[r_, b[:, None]]),
             (eq[b[:, None], r_], A_full[a[:, None], r_])]
    rows = [t[0].ravel() for t in terms]
    vals = [t[1].ravel() / scale_A for t in terms]
    cols = [k.ravel()] * len(terms)
    rhs = [A_full[upper] / scale_A]
    offset = int(upper.sum())
    for i, Ci in enumerate(C_full):
        right = block_of > i
        if Ci.shape[0] == 0 or not right.any():
            continue
        ri = Ci.shape[0]
        eq_c = np.full((ri, n), -1, dtype=np.int64)
        eq_c[:, right] = offset + np.arange(ri * int(right.sum())).reshape(ri, -1)
        offset += ri * int(right.sum())
        s_ = np.arange(ri)[None, :]
        kc = np.broadcast_to(np.arange(m)[:, None], (m, ri)).ravel()
        # d(C_i S)/dS[a, b], entry (s, c): C_i[s, a] [c = b] - C_i[s, b] [c = a]
        for eqs, v in ((eq_c[s_, b[:, None]], Ci[s_, a[:, None]]),
                       (eq_c[s_, a[:, None]], -Ci[s_, b[:, None]])):
            rows.append(eqs.ravel())
            vals.append(v.ravel() / scale_C[i])
            cols.append(kc)
        rhs.append(Ci[:, right].ravel() / scale_C[i])
    rows, cols, vals = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
    keep = (rows >= 0) & (vals != 0)
    J = sps.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(offset, m))
    return J, np.concatenate(rhs), a, b


def _pairwise_guess(A_full, C_full, block_of, scale_A, scale_C) -> np.ndarray:
    """A first ``S`` from the equations of one pair of blocks at a time.

    Writing ``Y_jq = S_jq`` (``j < q``), the block ``(j, q)`` of the linearised ``A'`` and
    the blocks ``q`` of ``C_i'`` for the agents ``i`` whose last non-empty block is ``j``
    vanish when (products of two small terms dropped)

    .. math::  A_{jj} Y_{jq} - Y_{jq} A_{qq} = -A_{jq} - \\sum_{p<j} A_{jp} Y_{pq}
               + \\sum_{p>q} Y_{jp} A_{pq}, \\qquad
               C_{ij} Y_{jq} = -C_{iq} - \\sum_{p<j} C_{ip} Y_{pq},

    whose right-hand sides hold only pairs solved before when ``j`` ascends and ``q``
    descends: one small least-squares problem per pair (full column rank, ``(A_jj, C_jj)``
    being observable). Exact when every Sylvester operator is well conditioned; when two
    blocks share an eigenvalue the entry between them can only be zeroed through the
    others, which only the global step does, so this is only its starting point.
    """
    n = A_full.shape[0]
    sizes = np.bincount(block_of, minlength=len(C_full))
    offs = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    nonempty = [j for j, s in enumerate(sizes) if s > 0]
    S = np.zeros((n, n))
    for a, j in enumerate(nonempty[:-1]):
        bj = slice(offs[j], offs[j + 1])
        agents = [i for i in range(j, nonempty[a + 1]) if C_full[i].shape[0] > 0]
        for q in reversed(nonempty[a + 1:]):
            bq = slice(offs[q], offs[q + 1])
            nj, nq = int(sizes[j]), int(sizes[q])
            R = (-A_full[bj, bq] - A_full[bj, : offs[j]] @ S[: offs[j], bq]
                 + S[bj, offs[q + 1]:] @ A_full[offs[q + 1]:, bq])
            rows = [(np.kron(np.eye(nq), A_full[bj, bj])
                     - np.kron(A_full[bq, bq].T, np.eye(nj))) / scale_A]
            rhs = [R.reshape(-1, order="F") / scale_A]
            for i in agents:
                Ci = C_full[i]
                Ri = -Ci[:, bq] - Ci[:, : offs[j]] @ S[: offs[j], bq]
                rows.append(np.kron(np.eye(nq), Ci[:, bj]) / scale_C[i])
                rhs.append(Ri.reshape(-1, order="F") / scale_C[i])
            y = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
            S[bj, bq] = y.reshape(nj, nq, order="F")
            S[bq, bj] = -S[bj, bq].T
    return S


def _newton_correction(A_full, C_full, block_of, scale_A, scale_C) -> np.ndarray:
    """Skew ``S`` of the least-squares Newton step (see :func:`_newton_system`)."""
    import scipy.sparse as sps
    import scipy.sparse.linalg as spsla
    n = A_full.shape[0]
    J, r, a, b = _newton_system(A_full, C_full, block_of, scale_A, scale_C)
    if J.shape[1] <= _DENSE_MAX:
        x = np.linalg.lstsq(J.toarray(), -r, rcond=None)[0]
    else:
        norms = np.sqrt(np.asarray(J.multiply(J).sum(0)).ravel())
        norms[norms == 0] = 1.0
        Js = J @ sps.diags(1.0 / norms)
        guess = _pairwise_guess(A_full, C_full, block_of, scale_A, scale_C)[a, b] * norms
        # stop at the rounding level of the equations, relative to what the guess left
        left = float(np.linalg.norm(Js @ guess + r))
        tol = min(1e-2, max(1e-10, 0.1 * np.finfo(float).eps / max(left, 1e-300)))
        y = spsla.lsmr(Js, -r, atol=tol, btol=tol, maxiter=4 * J.shape[1], x0=guess)[0]
        x = y / norms
    S = np.zeros((n, n))
    S[a, b] = x
    S[b, a] = -x
    return S


def refine_structure(A, Cs: Sequence, T: np.ndarray, sizes: Sequence[int], *,
                     max_steps: int = 4) -> tuple[np.ndarray, float, float]:
    """Rotate the orthogonal ``T`` so that Lemma 1's zero pattern holds to rounding level.

    Newton steps ``T <- T exp(S)`` (``S`` skew, from :func:`_newton_correction`), each
    kept only if it at least halves the larger of the two relative residuals; stops at
    ``max_steps`` or at rounding level. Returns ``(T, residual_A, residual_C)`` (see
    :class:`Decomposition`). The sizes (the rank decisions) are not changed.
    """
    A = np.asarray(A, dtype=float)
    Cs = [np.asarray(Ci, dtype=float).reshape(-1, A.shape[0]) for Ci in Cs]
    sizes = [int(s) for s in sizes]
    block_of = np.repeat(np.arange(len(sizes)), sizes)
    tiny = np.finfo(float).tiny
    scale_A = max(float(np.linalg.norm(A, 2)), tiny)
    scale_C = [max(float(np.linalg.norm(Ci, 2)), tiny) if Ci.size else 1.0 for Ci in Cs]
    A_full, C_full, res_A, res_C = _structure_residual(A, Cs, T, block_of, scale_A, scale_C)
    done = 4 * np.finfo(float).eps
    for _ in range(max_steps):
        if max(res_A, res_C) <= done:
            break
        S = _newton_correction(A_full, C_full, block_of, scale_A, scale_C)
        Q, R = np.linalg.qr(T @ sla.expm(S))
        T_new = Q * np.where(np.diag(R) < 0, -1.0, 1.0)  # re-orthonormalised, same signs
        trial = _structure_residual(A, Cs, T_new, block_of, scale_A, scale_C)
        if not max(trial[2], trial[3]) <= 0.5 * max(res_A, res_C):
            break
        T, (A_full, C_full, res_A, res_C) = T_new, trial
    return T, res_A, res_C


def is_observable(A, C, rtol: float = DEFAULT_RTOL) -> bool:
    """Whether ``(A, C)`` is observable (rank decided as in :func:`decompose`)."""
    return unobservable_subspace(A, C, rtol).shape[1] == 0
