"""Analysis tools for the online state estimator (OSE/OASE).

Equation numbers refer to the time-varying paper (Cavraro et al., "Online State
Estimation for Time-Varying Systems"); the asynchronous-sensors paper repeats them with
the same numbers from (19) on.

What is computed
----------------
* :func:`smallest_tau` -- the smallest ``tau`` of Assumption 1, eq. (19): every window of
  ``tau`` consecutive ``A(t)`` has kernels intersecting only in ``{0}`` (equivalently the
  stacked window has rank ``N``).
* :func:`lambda_bar`, :func:`c_const`, :func:`psi` -- the constants of Proposition 1 and
  Theorem 1: the smallest non-zero eigenvalue of ``J(t) = A^T Q^-1 A``, ``c =
  sup ||A^T Q^-1||`` and ``psi = gamma / (gamma + lambda_bar)``.
* :func:`window_contraction` -- the quantity Proposition 1 claims is at most ``psi``:
  ``max_t ||Lambda(t+tau-1) ... Lambda(t)||``. It is computed exactly so that the claim
  can be checked (it does not hold in general, see ``docs/online.md``); passing it as
  ``psi=`` to the bound functions gives bounds that follow rigorously from the paper's
  own argument.
* :func:`bound_23`, :func:`bound_24`, :func:`gamma_star_bounded` -- Theorem 1.
* :func:`bound_34`, :func:`bound_35`, :func:`bound_36`, :func:`bound_37`,
  :func:`bound_38`, :func:`H_s_printed`, :func:`rms_bound_consistent` -- Theorem 2.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netsense.estimators.online import lambda_matrix

__all__ = [
    "H_s_printed", "bound_23", "bound_24", "bound_34", "bound_35", "bound_36", "bound_37",
    "bound_38", "c_const", "gamma_star_bounded", "gamma_star_numeric", "kron_C_const",
    "lambda_bar", "m_const", "psi", "rms_bound_consistent", "smallest_tau",
    "window_contraction",
]


# ---------------------------------------------------------------------- utilities
def _seq(name: str, A_seq: Sequence) -> list[np.ndarray]:
    mats = [np.asarray(A, dtype=float) for A in A_seq]
    if not mats:
        raise ValueError(f"{name} must hold at least one matrix")
    N = mats[0].shape[-1] if mats[0].ndim == 2 else None
    for t, A in enumerate(mats):
        if A.ndim != 2 or A.shape[1] != N:
            raise ValueError(f"{name}[{t}] must be a 2-D matrix with N = {N} columns, "
                             f"got shape {A.shape}")
    return mats


def _qseq(Q_seq, mats: list[np.ndarray]) -> list[np.ndarray]:
    if Q_seq is None:
        return [np.eye(A.shape[0]) for A in mats]
    Qs = [np.asarray(Q, dtype=float) for Q in Q_seq]
    if len(Qs) != len(mats):
        raise ValueError(f"Q_seq must have one matrix per A (len {len(mats)}), got {len(Qs)}")
    out = []
    for t, (Q, A) in enumerate(zip(Qs, mats, strict=True)):
        Q = np.diag(Q) if Q.ndim == 1 else Q
        M = A.shape[0]
        if Q.shape != (M, M):
            raise ValueError(f"Q_seq[{t}] must have shape ({M}, {M}), got {Q.shape}")
        if M and (not np.allclose(Q, Q.T) or np.linalg.eigvalsh(Q)[0] <= 0):
            raise ValueError(f"Q_seq[{t}] must be symmetric positive definite")
        out.append(Q)
    return out


def _J(A: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """``J = A^T Q^-1 A`` (eq. (9)) via a solve."""
    if A.shape[0] == 0:
        return np.zeros((A.shape[1], A.shape[1]))
    return A.T @ np.linalg.solve(Q, A)


def _gamma(gamma: float) -> float:
    g = float(gamma)
    if not np.isfinite(g) or g <= 0:
        raise ValueError(f"gamma must be a finite number > 0, got {gamma!r}")
    return g


# ------------------------------------------------------------------ Assumption 1
def smallest_tau(A_seq: Sequence, rtol: float = 1e-9) -> int | None:
    """Smallest ``tau`` such that Assumption 1, eq. (19), holds on the finite sequence.

    ``cap_{k=0}^{tau-1} ker A(t+k) = {0}`` for every window start ``t`` with the whole
    window inside the sequence, i.e. every stacked window ``[A(t); ...; A(t+tau-1)]`` has
    rank ``N``.

    Parameters
    ----------
    A_seq : sequence of (M_t, N) arrays
        The regression matrices ``A(1), ..., A(T)``.
    rtol : float
        Singular values below ``rtol * max(1, largest singular value)`` count as zero.

    Returns
    -------
    int or None
        The smallest such ``tau``, or ``None`` if even the whole sequence is rank deficient.
    """
    mats = _seq("A_seq", A_seq)
    T, N = len(mats), mats[0].shape[1]

    def full_rank(lo: int, hi: int) -> bool:
        S = np.vstack(mats[lo:hi])
        if S.shape[0] < N:
            return False
        s = np.linalg.svd(S, compute_uv=False)
        return s[-1] > rtol * max(1.0, s[0]) if s.size >= N else False

    # L[s] = minimal window length from start s reaching rank N (T + 1 if never)
    L = np.full(T, T + 1)
    for s in range(T):
        lo_len = 1 if s == 0 else max(1, L[s - 1] - 1)  # L[s] >= L[s-1] - 1
        for length in range(lo_len, T - s + 1):
            if full_rank(s, s + length):
                L[s] = length
                break
    for tau in range(1, T + 1):
        if np.all(L[: T - tau + 1] <= tau):
            return tau
    return None


# ---------------------------------------------------------------------- constants
def lambda_bar(A_seq: Sequence, Q_seq: Sequence | None = None, rtol: float = 1e-9) -> float:
    """``lambda_bar = min_t lambda_1(t)``, the smallest non-zero eigenvalue of any
    ``J(t) = A(t)^T Q_t^-1 A(t)`` (defined after eq. (12)).

    Eigenvalues below ``rtol`` times the largest eigenvalue of the same ``J(t)`` are zero.
    """
    mats = _seq("A_seq", A_seq)
    Qs = _qseq(Q_seq, mats)
    best = np.inf
    for A, Q in zip(mats, Qs, strict=True):
        ev = np.linalg.eigvalsh(_J(A, Q))
        if ev[-1] <= 0:
            continue
        nz = ev[ev > rtol * ev[-1]]
        best = min(best, float(nz[0]))
    if not np.isfinite(best):
        raise ValueError("every J(t) is zero: lambda_bar is undefined")
    return best


def c_const(A_seq: Sequence, Q_seq: Sequence | None = None) -> float:
    """``c = sup_t ||A(t)^T Q_t^-1||`` (spectral norm), Theorem 1."""
    mats = _seq("A_seq", A_seq)
    Qs = _qseq(Q_seq, mats)
    vals = [np.linalg.norm(np.linalg.solve(Q, A).T, 2) if A.shape[0] else 0.0
            for A, Q in zip(mats, Qs, strict=True)]
    return float(max(vals))


def kron_C_const(A_seq: Sequence) -> float:
    """``C = sup_t ||A(t)^T kron A(t)^T||_F = sup_t ||A(t)||_F^2``, Theorem 2."""
    mats = _seq("A_seq", A_seq)
    return float(max(np.linalg.norm(A, "fro") ** 2 for A in mats))


def m_const(N_seq: Sequence) -> float:
    """``m = sup_t ||N_t^-1||_F`` for noise covariances ``N_t``, Theorem 2."""
    vals = []
    for t, Nt in enumerate(N_seq):
        Nt = np.asarray(Nt, dtype=float)
        Nt = np.diag(Nt) if Nt.ndim == 1 else Nt
        if Nt.ndim != 2 or Nt.shape[0] != Nt.shape[1]:
            raise ValueError(f"N_seq[{t}] must be square, got shape {Nt.shape}")
        vals.append(np.linalg.norm(np.linalg.inv(Nt), "fro"))
    if not vals:
        raise ValueError("N_seq must hold at least one covariance")
    return float(max(vals))


def psi(gamma: float, lam_bar: float) -> float:
    """``psi = max_t gamma / (gamma + lambda_1(t)) = gamma / (gamma + lambda_bar)``,
    Proposition 1."""
    g = _gamma(gamma)
    if not lam_bar > 0:
        raise ValueError(f"lambda_bar must be > 0, got {lam_bar!r}")
    return g / (g + float(lam_bar))


def window_contraction(A_seq: Sequence, gamma: float, tau: int,
                       Q_seq: Sequence | None = None) -> float:
    """``max_t ||Lambda(t+tau-1) ... Lambda(t)||`` over the windows inside the sequence.

    This is the left-hand side of eq. (22). Proposition 1 states it is ``<= psi``; the
    value computed here lets the claim be checked, and is the constant for which the
    telescoping argument behind (23)/(24) is valid.
    """
    mats = _seq("A_seq", A_seq)
    Qs = _qseq(Q_seq, mats)
    if not 1 <= int(tau) <= len(mats):
        raise ValueError(f"tau must be in [1, {len(mats)}] (the sequence length), got {tau}")
    g = _gamma(gamma)
    lams = [lambda_matrix(A, g, Q) for A, Q in zip(mats, Qs, strict=True)]
    worst = 0.0
    for s in range(len(mats) - int(tau) + 1):
        P = np.eye(mats[0].shape[1])
        for k in range(int(tau)):
            P = lams[s + k] @ P
        worst = max(worst, float(np.linalg.norm(P, 2)))
    return worst


# ----------------------------------------------------------------- Theorem 1 bounds
def _decay_sum(u: np.ndarray, contraction: float, tau: int) -> np.ndarray:
    """``S(T) = sum_{t=1}^T psi^floor((T+1-t)/tau) u(t)`` for ``T = 1..len(u)``."""
    T = u.shape[0]
    w = contraction ** (np.arange(1, T + 1) // tau)       # weight for lag k = T+1-t
    return np.convolve(u, w)[:T]


def bound_23(T: int, tau: int, contraction: float, xi0_norm: float, Dx, Dn, c_t,
             gamma: float) -> np.ndarray:
    """Finite-time error bound of Theorem 1, eq. (23), for ``T = 1..T``.

    ``||xi(T)|| <= psi^floor(T/tau) ||xi(0)|| + sum_t psi^floor((T+1-t)/tau)
    (Delta_x(t) + c(t) Delta_n(t) / gamma)``.

    Parameters
    ----------
    T, tau : int
        Horizon and the ``tau`` of Assumption 1.
    contraction : float
        ``psi`` (the paper's) or the exact :func:`window_contraction`.
    xi0_norm : float
        ``||xi(0)||``.
    Dx, Dn, c_t : float or (T,) arrays
        ``Delta_x(t)``, ``Delta_n(t)`` and ``c(t)``.
    gamma : float
        Inertia parameter.
    """
    g = _gamma(gamma)
    u = (np.broadcast_to(np.asarray(Dx, float), (T,))
         + np.broadcast_to(np.asarray(c_t, float), (T,))
         * np.broadcast_to(np.asarray(Dn, float), (T,)) / g)
    Ts = np.arange(1, T + 1)
    return contraction ** (Ts // tau) * xi0_norm + _decay_sum(u, contraction, tau)


def bound_24(gamma, tau: int, Dx: float, Dn: float, c: float, lam_bar: float,
             contraction: float | None = None):
    """Asymptotic bound of Theorem 1, eq. (24): ``H_b(gamma)``.

    ``tau (Delta_x + c Delta_n / gamma) (1 + gamma / lambda_bar)``; the last factor is
    ``1 / (1 - psi)``. With ``contraction`` given, ``tau (...) / (1 - contraction)`` is
    returned instead (the same argument with the exact window contraction).
    ``gamma`` may be an array.
    """
    g = np.asarray(gamma, dtype=float)
    if np.any(g <= 0):
        raise ValueError("gamma must be > 0")
    geo = 1.0 + g / lam_bar if contraction is None else 1.0 / (1.0 - contraction)
    return tau * (Dx + c * Dn / g) * geo


def gamma_star_bounded(c: float, lam_bar: float, Dx: float, Dn: float) -> float:
    """Minimiser of eq. (24): ``gamma* = sqrt(c lambda_bar Delta_n / Delta_x)``, eq. (25)."""
    if min(c, lam_bar, Dx, Dn) <= 0:
        raise ValueError("c, lambda_bar, Delta_x and Delta_n must all be > 0")
    return float(np.sqrt(c * lam_bar * Dn / Dx))


def gamma_star_numeric(H, lo: float = 1e-4, hi: float = 1e3) -> float:
    """Minimise a bound ``H(gamma)`` over ``[lo, hi]`` (log-scale golden search)."""
    from scipy.optimize import minimize_scalar

    res = minimize_scalar(lambda s: float(H(np.exp(s))), bounds=(np.log(lo), np.log(hi)),
                          method="bounded", options={"xatol": 1e-8})
    return float(np.exp(res.x))


# ----------------------------------------------------------------- Theorem 2 bounds
def bound_34(T: int, tau: int, contraction: float, xi0_norm: float, Dx) -> np.ndarray:
    """Error-mean bound of Theorem 2, eq. (34) (eq. (23) without noise term)."""
    Ts = np.arange(1, T + 1)
    u = np.broadcast_to(np.asarray(Dx, float), (T,)).astype(float)
    return contraction ** (Ts // tau) * xi0_norm + _decay_sum(u, contraction, tau)


def bound_35(T: int, tau: int, contraction: float, Sigma0_fro: float, C_t, m_t,
             gamma: float) -> np.ndarray:
    """Error-covariance bound of Theorem 2, eq. (35), with the ``1/gamma^2`` of eq. (31).

    Printed (35) omits the ``1/gamma^2`` that multiplies ``C(t) m(t)`` in eq. (31) and
    reappears in (37); it is kept here so that (35) and (37) agree.
    """
    g = _gamma(gamma)
    Ts = np.arange(1, T + 1)
    u = (np.broadcast_to(np.asarray(C_t, float), (T,))
         * np.broadcast_to(np.asarray(m_t, float), (T,)) / g ** 2)
    return contraction ** (Ts // tau) * Sigma0_fro + _decay_sum(u, contraction, tau)


def bound_36(gamma, tau: int, Dx: float, lam_bar: float):
    """``limsup ||mu(t)|| <= tau Delta_x (1 + gamma / lambda_bar)``, eq. (36)."""
    g = np.asarray(gamma, dtype=float)
    return tau * Dx * (1.0 + g / lam_bar)


def bound_37(gamma, tau: int, C: float, m: float, lam_bar: float):
    """``limsup ||Sigma(t)||_F <= tau C m / gamma^2 (1 + gamma / lambda_bar)``, eq. (37)."""
    g = np.asarray(gamma, dtype=float)
    return tau * C * m / g ** 2 * (1.0 + g / lam_bar)


def bound_38(gamma, tau: int, C: float, m: float, Dx: float, lam_bar: float):
    """RMS-error bound as printed, eq. (38):
    ``tau sqrt(C^2 m^2 / gamma^4 + Delta_x^2) (1 + gamma / lambda_bar)``."""
    g = np.asarray(gamma, dtype=float)
    return tau * np.sqrt(C ** 2 * m ** 2 / g ** 4 + Dx ** 2) * (1.0 + g / lam_bar)


def H_s_printed(gamma, tau: int, m_bar: float, Dx: float, lam_bar: float):
    """``H_s(gamma)`` exactly as printed in Section IV/VI:
    ``tau sqrt(m_bar^2 / gamma^4 + Delta_x^2 (1 + gamma / lambda_bar))``.

    It differs from eq. (38) in where ``(1 + gamma/lambda_bar)`` sits.
    """
    g = np.asarray(gamma, dtype=float)
    return tau * np.sqrt(m_bar ** 2 / g ** 4 + Dx ** 2 * (1.0 + g / lam_bar))


def rms_bound_consistent(gamma, tau: int, N: int, C: float, m: float, Dx: float,
                         contraction) -> np.ndarray:
    """RMS bound that follows from (36)-(37) without the step ``tr Sigma = ||Sigma||_F^2``.

    ``E||xi||^2 = tr Sigma + ||mu||^2 <= sqrt(N) ||Sigma||_F + ||mu||^2``, so
    ``sqrt(E||xi||^2) <= sqrt(sqrt(N) tau C m / (gamma^2 (1-psi)) + (tau Delta_x /
    (1-psi))^2)``, with ``psi`` replaced by ``contraction`` (scalar or per-gamma array).
    """
    g = np.asarray(gamma, dtype=float)
    geo = 1.0 / (1.0 - np.asarray(contraction, dtype=float))
    return np.sqrt(np.sqrt(N) * tau * C * m / g ** 2 * geo + (tau * Dx * geo) ** 2)
