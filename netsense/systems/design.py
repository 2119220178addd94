"""Observer gain design for the source nodes (Theorem 1 and Corollary 1).

Each source node ``j`` owns substate ``j`` and runs the local Luenberger update eq. (7)
with gain ``L_j``. Theorem 1's design picks rates ``0 < rho_1 < ... < rho_N < rho`` and
places the eigenvalues of ``A_jj - L_j C_jj`` at distinct real values with spectral radius
exactly ``rho_j`` (so ``||(A_jj - L_j C_jj)^k|| <= alpha_j rho_j^k``, eq. (18)).
Corollary 1's deadbeat design places every eigenvalue at 0, which makes the error of
every node vanish after at most ``n + 2N(N-1)T`` steps.

Pole placement uses :func:`scipy.signal.place_poles` on the dual pair.

Deadbeat gains (:func:`deadbeat_gain`) come from an orthogonal construction of a nilpotent
``A - L C`` in the dual pair ``(F, G) = (A^T, C^T)``, ``K = L^T``: the states that
``F - G K`` must send to zero in ``i`` steps form a flag ``0 = S_0 < S_1 < ... < S_m = R^n``
with ``F S_i <= im G + S_{i-1}``; on the orthonormal complement ``W_i`` of ``S_{i-1}`` in
``S_i`` the gain is the minimum-norm solution of ``F W_i - G K W_i in S_{i-1}``, i.e.
``K W_i = (P_i G)^+ P_i F W_i`` with ``P_i`` the projector onto ``S_{i-1}^perp``. Only
orthonormal bases and SVD rank decisions are used (no powers of ``A``, no observability
matrix, no random draw), and ``||K||_F^2`` is the sum of the per-level minimum norms. Two
flags are built: the largest one (minimum time: the nilpotency index is the observability
index of the block) and a greedy one that adds, per level, only the direction that needs
the least gain (index ``n_j``); the gain of smaller 2-norm is kept. For a 1-state block both
give ``a c^T / ||c||^2``, the minimum-norm deadbeat gain. Measured against the random
Heymann feedback used before (``a`` random output feedback making ``A - K_0 C`` cyclic, then
Ackermann on a random output combination): ``deadbeat_gain([[1.1]], [[1.0], [0.5], [-0.8]])``
has norm 0.80 (was 840 with ``rng=298``); on random multi-output blocks the kept gain is
within a factor 1-3 of the smallest of 60 Heymann draws, often below it.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from netsense.kernels import checks
from netsense.systems.decomposition import Decomposition, decompose, observable_subspace


@dataclass(frozen=True, eq=False)
class ObserverDesign:
    """A decomposition plus the source gains: everything a distributed observer needs.

    Attributes
    ----------
    decomposition : Decomposition
        Lemma 1's coordinates and blocks.
    gains : tuple of arrays
        ``L_j`` of shape ``(n_j, r_j)`` for each agent (empty when ``n_j = 0``).
    rates : tuple of float
        Spectral radius of ``A_jj - L_j C_jj`` per agent (``nan`` for ``n_j = 0``).
    deadbeat : bool
        Whether all closed-loop eigenvalues were placed at 0 (Corollary 1).

    See also :attr:`gain_norms` and :attr:`nilpotency_residuals`.
    """

    decomposition: Decomposition
    gains: tuple[np.ndarray, ...]
    rates: tuple[float, ...]
    deadbeat: bool

    @property
    def num_agents(self) -> int:
        return self.decomposition.num_agents

    @property
    def n(self) -> int:
        return self.decomposition.n

    @property
    def gain_norms(self) -> tuple[float, ...]:
        """``||L_j||_2`` per agent (``nan`` when ``n_j = 0``)."""
        return tuple(float(np.linalg.norm(L, 2)) if L.size else float("nan")
                     for L in self.gains)

    @property
    def nilpotency_residuals(self) -> tuple[float, ...]:
        """``||M_j^{n_j}||_2 / s_j^{n_j}`` per agent, ``M_j = A_jj - L_j C_jj`` and
        ``s_j = max(||A_jj||_2, ||L_j||_2 ||C_jj||_2)``.

        Zero for an exactly nilpotent ``M_j`` (Corollary 1); of the order of ``n_j eps``
        or below when it is nilpotent to working precision (``M_j`` itself is known only
        to ``~eps s_j``); ``nan`` for a design that is not deadbeat or an empty substate.
        """
        d = self.decomposition
        return tuple(
            _nilpotency_residual(d.A_jj(j), self.gains[j], d.C_jj(j))
            if self.deadbeat and size else float("nan")
            for j, size in enumerate(d.sizes))

    def closed_loop(self, j: int) -> np.ndarray:
        """``A_jj - L_j C_jj`` of source ``j``."""
        d = self.decomposition
        return d.A_jj(j) - self.gains[j] @ d.C_jj(j)

    def gain_padded(self, max_outputs: int) -> np.ndarray:
        """``(N, n, r_max)`` array: ``L_j`` in the rows of block ``j`` of agent ``j``.

        Multiplying by agent ``j``'s innovation ``y_j - C_bar_j z_j`` gives the output
        injection term of eq. (7) in full ``z`` coordinates (zero outside block ``j``).
        """
        d = self.decomposition
        out = np.zeros((d.num_agents, d.n, max_outputs))
        for j, L in enumerate(self.gains):
            if L.size:
                out[j, d.block(j), : L.shape[1]] = L
        return out


def _nilpotency_residual(A: np.ndarray, L: np.ndarray, C: np.ndarray) -> float:
    """``||(A - L C)^n||_2 / s^n`` with ``s = max(||A||_2, ||L||_2 ||C||_2)`` (0 if ``s = 0``).

    ``s`` is the size of the two terms whose difference is ``M = A - L C``, so rounding
    alone leaves ``M`` uncertain by ``~eps s``: the residual is of the order of
    ``n eps`` for a nilpotent ``M`` (and far smaller when ``M`` is zero up to rounding).
    """
    s = max(float(np.linalg.norm(A, 2)), float(np.linalg.norm(L, 2) * np.linalg.norm(C, 2)))
    if s == 0.0:
        return 0.0
    P = np.linalg.matrix_power((A - L @ C) / s, A.shape[0])
    return float(np.linalg.norm(P, 2))


def _complement(Q: np.ndarray, n: int) -> np.ndarray:
    """Orthonormal basis of the orthogonal complement of the orthonormal columns ``Q``."""
    if Q.shape[1] == 0:
        return np.eye(n)
    q, _ = np.linalg.qr(Q, mode="complete")
    return q[:, Q.shape[1]:]


def _flag_deadbeat(F: np.ndarray, G: np.ndarray, greedy: bool) -> np.ndarray | None:
    """``K`` with ``F - G K`` nilpotent, from the flag of the module docstring.

    ``greedy``: add one direction per level (the one needing the least gain) instead of
    every direction the level allows. ``None`` if the flag stalls (``(F, G)`` not
    controllable to working precision).
    """
    n, r = G.shape
    eps = np.finfo(float).eps
    scale = max(np.linalg.norm(F, 2), np.linalg.norm(G, 2), 1.0)
    tol_null = 8 * n * eps * scale
    S = np.zeros((n, 0))
    K = np.zeros((r, n))
    while S.shape[1] < n:
        P = np.eye(n) - S @ S.T
        PF = P @ F
        ug, sg, vgt = np.linalg.svd(P @ G, full_matrices=False)
        N = _complement(S, n)
        found = None
        # Directions of P G below the first threshold would need huge gains; use them
        # only if nothing else makes progress.
        for tol_g in (1e-10 * scale, 1e3 * eps * scale, 0.0):
            k = int(np.sum(sg > tol_g))
            Qp = _complement(np.hstack([S, ug[:, :k]]), n)
            if Qp.shape[1] == 0:
                V = np.eye(N.shape[1])
            else:
                _, sv, vt = np.linalg.svd(Qp.T @ F @ N)
                s_full = np.zeros(N.shape[1])
                s_full[: sv.size] = sv
                V = vt.T[:, s_full <= tol_null]
            if V.shape[1]:
                found = (k, V)
                break
        if found is None:
            return None
        k, V = found
        W = N @ V
        # minimum-norm K W with P F W - P G K W = 0 (P F W lies in the kept range of P G)
        U = vgt[:k].T @ ((ug[:, :k].T @ (PF @ W)) / sg[:k, None])
        if greedy and W.shape[1] > 1:
            _, su, vu = np.linalg.svd(U)
            cost = np.zeros(W.shape[1])
            cost[: su.size] = su
            v = vu.T[:, [int(np.argmin(cost))]]
            W, U = W @ v, U @ v
        K += U @ W.T
        S, _ = np.linalg.qr(np.hstack([S, W]))
    return K


def deadbeat_gain(A, C, *, rng: np.random.Generator | int | None = None,
                  max_tries: int | None = None, rtol: float = 1e-8) -> np.ndarray:
    """Gain ``L`` of small norm with every eigenvalue of ``A - L C`` at 0 (Corollary 1).

    Works for any number of outputs, cyclic or not (the orthogonal flag construction of
    the module docstring; the smaller of the minimum-time and the greedy gain). For a
    1-state block it is the minimum-norm gain ``a c^T / ||c||^2``.

    Parameters
    ----------
    A : (n, n) array_like
    C : (r, n) array_like
    rng, max_tries
        Ignored; kept so that calls written for the earlier randomised design still work
        (the construction is deterministic).
    rtol : float
        The design is accepted when ``||(A - L C)^n||_2 <= rtol s^n``,
        ``s = max(||A||_2, ||L||_2 ||C||_2)`` (see ``ObserverDesign.nilpotency_residuals``).

    Raises
    ------
    ValueError
        If ``(A, C)`` is not observable or no accurate deadbeat gain was found.
    """
    del rng, max_tries  # deterministic construction
    A = np.asarray(A, dtype=float)
    C = np.asarray(C, dtype=float)
    n = A.shape[0]
    if C.ndim != 2 or C.shape[1] != n:
        raise ValueError(f"C must have shape (r, {n}), got {C.shape}")
    scale = max(np.linalg.norm(A, 2), np.linalg.norm(C, 2), 1.0)
    if observable_subspace(A, C, 1e-9 * scale).shape[1] < n:
        raise ValueError("deadbeat design needs an observable (A_jj, C_jj) pair")
    best, best_norm, best_res = None, np.inf, np.inf
    for greedy in (False, True):
        K = _flag_deadbeat(A.T, C.T, greedy)
        if K is None:
            continue
        L = K.T
        res = _nilpotency_residual(A, L, C)
        norm = float(np.linalg.norm(L, 2))
        if res <= rtol and norm < best_norm:
            best, best_norm, best_res = L, norm, res
        elif best is None and res < best_res:
            best_res = res
    if best is None:
        raise ValueError(f"no accurate deadbeat gain found (best ||(A-LC)^n|| / s^n "
                         f"= {best_res:.3g}); the block is numerically close to unobservable")
    return best


def rate_gain(A, C, rho_j: float) -> np.ndarray:
    """Gain ``L`` such that ``A - L C`` has distinct real eigenvalues, spectral radius ``rho_j``.

    The eigenvalues are ``rho_j * (n - k) / n`` for ``k = 0..n-1`` (distinct, positive,
    largest exactly ``rho_j``).
    """
    A = np.asarray(A, dtype=float)
    C = np.asarray(C, dtype=float)
    n = A.shape[0]
    if not 0 < rho_j < 1:
        raise ValueError(f"rho_j must be in (0, 1), got {rho_j}")
    poles = rho_j * (n - np.arange(n)) / n
    if n == 1:
        c = C.reshape(-1)
        if np.allclose(c, 0):
            raise ValueError("rate design needs an observable (A_jj, C_jj) pair")
        # Minimum-norm gain for the scalar block: a - l.c = rho_j.
        return ((A[0, 0] - rho_j) * c / (c @ c)).reshape(1, -1)
    try:
        with warnings.catch_warnings():
            # YT's robustness iteration may stop early; the poles are still placed, which
            # is checked below.
            warnings.simplefilter("ignore", UserWarning)
            from scipy.signal import place_poles  # 0.5 s to import: only when used

            res = place_poles(A.T, C.T, poles, method="YT", maxiter=10)
    except ValueError as exc:
        raise ValueError(f"pole placement failed for a block of size {n}: {exc}") from exc
    L = res.gain_matrix.T
    got = np.sort(np.real(sla.eigvals(A - L @ C)))
    if np.max(np.abs(got - np.sort(poles))) > 1e-6 * max(1.0, np.linalg.norm(A, 2)):
        raise ValueError(f"pole placement for a block of size {n} is inaccurate: asked for "
                         f"{np.sort(poles)}, got {got}")
    return L


def design_observer(A, Cs: Sequence | None = None, *, rho: float | None = 0.5,
                    rates: Sequence[float] | None = None, deadbeat: bool = False,
                    decomposition: Decomposition | None = None,
                    rng: np.random.Generator | int | None = 0) -> ObserverDesign:
    """Decompose ``(A, C)`` (Lemma 1) and design every source gain.

    Parameters
    ----------
    A : (n, n) array_like or Plant
        System matrix, or a :class:`~netsense.systems.plants.Plant` (then ``Cs`` is taken from it).
    Cs : sequence of (r_i, n) arrays
        Output matrices (omit when ``A`` is a Plant).
    rho : float in (0, 1)
        Target convergence rate of Theorem 1; the default rates are
        ``rho_j = rho * k / (m + 1)`` for the ``k``-th of the ``m`` non-empty substates,
        so ``0 < rho_1 < ... < rho_N < rho``.
    rates : sequence of float, optional
        Explicit ``rho_j`` per agent (entries for empty substates are ignored); they must
        be strictly increasing over the non-empty substates and below ``rho``.
    deadbeat : bool
        Place every eigenvalue at 0 (Corollary 1) instead.
    decomposition : Decomposition, optional
        Reuse a decomposition computed earlier.
    rng : Generator or int
        Ignored (the deadbeat design is deterministic); kept for compatibility.

    Raises
    ------
    ValueError
        If ``rho`` or ``rates`` are out of range or not increasing, or a block's design is
        impossible (the message names the agent).
    """
    deadbeat = checks.boolean("deadbeat", deadbeat)  # ("false" is not False)
    if rho is not None and not deadbeat:
        checks.number("rho", rho, 0, 1, lo_open=True, hi_open=True)
    if rng is not None and not isinstance(rng, np.random.Generator):
        checks.seed_value("rng", rng)
    if rates is not None:
        rates = checks.array("rates", rates, (None,), kind="f")
    if Cs is None:
        from netsense.systems.plants import Plant

        if not isinstance(A, Plant):
            raise ValueError("give either a Plant or both A and Cs")
        A, Cs = A.A, A.C
    dec = decomposition if decomposition is not None else decompose(A, Cs)
    active = [j for j, s in enumerate(dec.sizes) if s > 0]
    if not deadbeat:
        if rho is None or not 0 < rho < 1:
            raise ValueError(f"rho must be in (0, 1), got {rho}")
        if rates is None:
            m = len(active)
            rate_of = {j: rho * (k + 1) / (m + 1) for k, j in enumerate(active)}
        else:
            if len(rates) != dec.num_agents:
                raise ValueError(f"rates must have one entry per agent ({dec.num_agents}), "
                                 f"got {len(rates)}")
            rate_of = {j: float(rates[j]) for j in active}
            seq = [rate_of[j] for j in active]
            increasing = all(b > a for a, b in zip(seq, seq[1:], strict=False))
            if any(not 0 < r < rho for r in seq) or not increasing:
                raise ValueError(f"rates of the non-empty substates must satisfy "
                                 f"0 < rho_1 < ... < rho_N < rho = {rho}, got {seq}")
    gains, rates_out = [], []
    for j in range(dec.num_agents):
        if dec.sizes[j] == 0:
            gains.append(np.zeros((0, dec.C_bar[j].shape[0])))
            rates_out.append(float("nan"))
            continue
        Ajj, Cjj = dec.A_jj(j), dec.C_jj(j)
        try:
            if deadbeat:
                L = deadbeat_gain(Ajj, Cjj, rng=rng)
                rates_out.append(0.0)
            else:
                L = rate_gain(Ajj, Cjj, rate_of[j])
                rates_out.append(rate_of[j])
        except ValueError as exc:
            raise ValueError(f"gain design for agent {j} (block size {dec.sizes[j]}): {exc}") \
                from exc
        gains.append(L)
    return ObserverDesign(decomposition=dec, gains=tuple(gains), rates=tuple(rates_out),
                          deadbeat=deadbeat)


def spectral_radius(M: np.ndarray) -> float:
    """Largest eigenvalue modulus of a square matrix (0 for an empty one)."""
    return float(np.max(np.abs(sla.eigvals(M)))) if M.size else 0.0
