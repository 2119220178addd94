"""Online (asynchronous) state estimator: proximal-regularised weighted least squares.

The OSE / OASE of Cavraro, Dall'Anese, Comden and Bernstein tracks a time-varying state
``x(t)`` from measurements ``y(t) = A(t) x(t) + b(t) + n(t)`` whose number ``M_t`` may be
far below ``N``. Each step solves the strongly convex problem

.. math::  \\hat x(t) = \\arg\\min_w \\|\\tilde y(t) - A(t) w\\|^2_{Q_t^{-1}}
           + \\gamma \\|w - \\hat x(t-1)\\|^2, \\qquad \\tilde y = y - b

(eq. (6) of the time-varying paper; the offset ``b`` is Remark 1), whose minimiser is
eqs. (7)-(8):

.. math::  \\hat x(t) = \\Lambda(t) \\hat x(t-1)
           + \\tfrac{1}{\\gamma} \\Lambda(t) A(t)^\\top Q_t^{-1} \\tilde y(t), \\qquad
           \\Lambda(t) = \\gamma (A(t)^\\top Q_t^{-1} A(t) + \\gamma I)^{-1}.

No inverse is formed. When ``M_t <= N`` the step uses the algebraically identical
innovation form (matrix inversion lemma)

.. math::  \\hat x(t) = \\hat x(t-1) + A^\\top (\\gamma Q_t + A A^\\top)^{-1}
           (\\tilde y - A \\hat x(t-1)),

one Cholesky factorisation of an ``M_t x M_t`` matrix; otherwise it solves the ``N x N``
normal equations ``(A^T Q^-1 A + gamma I) w = gamma x_prev + A^T Q^-1 y~`` by Cholesky.
Everything is batched over a leading Monte Carlo axis ``R``.

A step with ``M_t = 0`` (no sensor reported) leaves the estimate unchanged, which is what
eq. (7) gives with an empty ``A(t)`` (``Lambda = I``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve

__all__ = ["OnlineStateEstimator", "OSEConfig", "lambda_matrix", "ose_step"]


# ----------------------------------------------------------------------------- checks
def _check_gamma(gamma: float) -> float:
    g = float(gamma)
    if not np.isfinite(g) or g <= 0:
        raise ValueError(f"gamma (inertia parameter) must be a finite number > 0, got {gamma!r}")
    return g


def _as_batch(name: str, arr, ndim_single: int, R: int | None) -> np.ndarray:
    """Return ``arr`` with a leading batch axis (broadcast view when it had none)."""
    a = np.asarray(arr, dtype=float)
    if a.ndim == ndim_single:
        a = a[None]
        if R is not None:
            a = np.broadcast_to(a, (R,) + a.shape[1:])
    elif a.ndim == ndim_single + 1:
        if R is not None and a.shape[0] != R:
            raise ValueError(f"{name} has batch size {a.shape[0]}, expected {R} "
                             f"(the batch size of x_prev)")
    else:
        raise ValueError(f"{name} must have {ndim_single} or {ndim_single + 1} dimensions "
                         f"(optionally batched), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or infinite entries")
    return a


def _prepare(x_prev, y, A, Q, b):
    """Validate and broadcast the inputs of one step; returns batched arrays.

    Shapes: ``x_prev`` (N,) or (R, N); ``A`` (M, N) or (R, M, N); ``y`` and ``b`` (M,) or
    (R, M); ``Q`` None (identity), (M,) diagonal variances, (M, M) or (R, M, M).
    """
    x = np.asarray(x_prev, dtype=float)
    if x.ndim not in (1, 2):
        raise ValueError(f"x_prev must have shape (N,) or (R, N), got {x.shape}")
    single = x.ndim == 1
    xb = x[None] if single else x
    R, N = xb.shape
    if not np.all(np.isfinite(xb)):
        raise ValueError("x_prev contains NaN or infinite entries")
    Ab = _as_batch("A", A, 2, R)
    M = Ab.shape[1]
    if Ab.shape[2] != N:
        raise ValueError(f"A must have N = {N} columns (the state size of x_prev), "
                         f"got shape {Ab.shape[1:]}")
    yb = _as_batch("y", y, 1, R)
    if yb.shape[1] != M:
        raise ValueError(f"y must have M = {M} entries (the rows of A), got {yb.shape[1]}")
    if b is not None:
        bb = _as_batch("b", b, 1, R)
        if bb.shape[1] != M:
            raise ValueError(f"b must have M = {M} entries (the rows of A), got {bb.shape[1]}")
        yb = yb - bb
    if Q is None:
        Qb = np.broadcast_to(np.eye(M), (R, M, M))
    else:
        Qa = np.asarray(Q, dtype=float)
        if Qa.ndim == 1:
            if Qa.shape != (M,):
                raise ValueError(f"Q given as diagonal variances must have shape ({M},), "
                                 f"got {Qa.shape}")
            if not np.all(np.isfinite(Qa)) or np.any(Qa <= 0):
                raise ValueError("Q must be positive definite: diagonal variances must be "
                                 "finite and > 0")
            Qa = np.diag(Qa)
        Qb = _as_batch("Q", Qa, 2, R)
        if Qb.shape[1:] != (M, M):
            raise ValueError(f"Q must have shape ({M}, {M}), got {Qb.shape[1:]}")
        if not np.allclose(Qb, np.swapaxes(Qb, -1, -2), rtol=1e-10, atol=1e-12):
            raise ValueError("Q must be symmetric positive definite; it is not symmetric")
        if M and np.any(np.linalg.eigvalsh(Qb)[..., 0] <= 0):
            raise ValueError("Q must be symmetric positive definite; it has an eigenvalue <= 0")
    return single, xb, yb, Ab, Qb


# ------------------------------------------------------------------------ core step
def _batched_cho_solve(S: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve ``S[r] z[r] = rhs[r]`` for SPD ``S`` (R, K, K) and ``rhs`` (R, K)."""
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:  # pragma: no cover - S is SPD by construction
        return np.linalg.solve(S, rhs[..., None])[..., 0]
    z = np.linalg.solve(L, rhs[..., None])
    return np.linalg.solve(np.swapaxes(L, -1, -2), z)[..., 0]


def ose_step(x_prev, y, A, gamma: float, Q=None, b=None) -> np.ndarray:
    """One OSE/OASE update, eqs. (7)-(8) (with Remark 1's offset ``b``), batched.

    Parameters
    ----------
    x_prev : (N,) or (R, N) array
        Previous estimate ``x_hat(t-1)``; ``R`` is the Monte Carlo batch.
    y : (M,) or (R, M) array
        Measurements that arrived at step ``t`` (``M = M_t`` may be 0).
    A : (M, N) or (R, M, N) array
        Regression matrix ``A(t)`` of the sensors that reported.
    gamma : float
        Inertia parameter ``gamma > 0`` of eq. (6).
    Q : None, (M,), (M, M) or (R, M, M) array, optional
        Positive definite weight ``Q_t`` (noise covariance); ``None`` means the identity, a
        1-D array the diagonal.
    b : (M,) or (R, M) array, optional
        Known affine offset ``b(t)`` of Remark 1 (``y = A x + b + n``).

    Returns
    -------
    ndarray
        ``x_hat(t)`` with the shape of ``x_prev``.

    Raises
    ------
    ValueError
        On shape mismatches, ``gamma <= 0``, a non-symmetric or non-PD ``Q``, or non-finite
        input; raised before any computation.
    """
    g = _check_gamma(gamma)
    single, xb, yb, Ab, Qb = _prepare(x_prev, y, A, Q, b)
    R, N = xb.shape
    M = Ab.shape[1]
    if M == 0:
        out = xb.copy()
    elif M <= N:
        # innovation form: x + A^T (gamma Q + A A^T)^{-1} (y - A x)
        S = g * Qb + Ab @ np.swapaxes(Ab, -1, -2)
        innov = yb - np.einsum("rmn,rn->rm", Ab, xb)
        z = _batched_cho_solve(S, innov)
        out = xb + np.einsum("rmn,rm->rn", Ab, z)
    else:
        # normal equations: (A^T Q^-1 A + gamma I) w = gamma x + A^T Q^-1 y
        QiA = _batched_cho_solve_matrix(Qb, Ab)            # Q^-1 A, (R, M, N)
        J = np.swapaxes(Ab, -1, -2) @ QiA                  # eq. (9): J = A^T Q^-1 A
        H = J + g * np.eye(N)
        rhs = g * xb + np.einsum("rmn,rm->rn", QiA, yb)
        out = _batched_cho_solve(H, rhs)
    return out[0] if single else out


def _batched_cho_solve_matrix(S: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Solve ``S[r] Z[r] = B[r]`` for SPD ``S`` (R, K, K) and ``B`` (R, K, P)."""
    L = np.linalg.cholesky(S)
    Z = np.linalg.solve(L, B)
    return np.linalg.solve(np.swapaxes(L, -1, -2), Z)


def lambda_matrix(A, gamma: float, Q=None) -> np.ndarray:
    """``Lambda(t) = gamma (A^T Q^-1 A + gamma I)^-1``, eq. (8), by solves.

    Parameters
    ----------
    A : (M, N) array
        Regression matrix of one step.
    gamma : float
        Inertia parameter (> 0).
    Q : None, (M,) or (M, M) array, optional
        Positive definite weight; identity when omitted.

    Returns
    -------
    (N, N) ndarray
        The symmetric positive definite ``Lambda``; eigenvalues ``gamma/(gamma+lambda_i)``
        and 1 on ``ker A`` (eq. (11)).
    """
    g = _check_gamma(gamma)
    A = np.asarray(A, dtype=float)
    if A.ndim != 2:
        raise ValueError(f"A must be a 2-D (M, N) matrix, got shape {A.shape}")
    M, N = A.shape
    if M == 0:
        return np.eye(N)
    _, _, Ab, Qb = _prepare(np.zeros(N), np.zeros(M), A, Q, None)[1:]
    J = A.T @ _batched_cho_solve_matrix(Qb, Ab)[0]
    c = cho_factor(J + g * np.eye(N))
    Lam = g * cho_solve(c, np.eye(N))
    return 0.5 * (Lam + Lam.T)


# ------------------------------------------------------------------------- stateful
@dataclass(frozen=True)
class OSEConfig:
    """Configuration of the online state estimator.

    Parameters
    ----------
    gamma : float
        Inertia parameter ``gamma > 0`` weighting ``||w - x_hat(t-1)||^2`` in eq. (6).
    """

    gamma: float

    def __post_init__(self) -> None:
        _check_gamma(self.gamma)


class OnlineStateEstimator:
    """Stateful OSE/OASE, eqs. (7)-(8), over a batch of ``R`` Monte Carlo runs.

    Parameters
    ----------
    config : OSEConfig
        Holds the inertia parameter ``gamma``.
    x0 : (N,) or (R, N) array
        Initial estimate ``x_hat(0)``.

    Examples
    --------
    >>> est = OnlineStateEstimator(OSEConfig(gamma=0.5), np.zeros(2))
    >>> est.step(y=[1.0], A=[[1.0, 0.0]]).round(3)
    array([0.667, 0.   ])
    """

    def __init__(self, config: OSEConfig, x0) -> None:
        if not isinstance(config, OSEConfig):
            raise ValueError(f"config must be an OSEConfig, got {type(config).__name__}")
        x0 = np.array(x0, dtype=float)
        if x0.ndim not in (1, 2) or x0.shape[-1] == 0:
            raise ValueError(f"x0 must have shape (N,) or (R, N) with N >= 1, got {x0.shape}")
        if not np.all(np.isfinite(x0)):
            raise ValueError("x0 contains NaN or infinite entries")
        self.config = config
        self.x_hat = x0
        self.t = 0

    @property
    def gamma(self) -> float:
        """The inertia parameter."""
        return self.config.gamma

    def step(self, y, A, Q=None, b=None) -> np.ndarray:
        """Fold in the measurements of step ``t+1``; see :func:`ose_step` for shapes.

        The estimate is only replaced after every input has been validated.
        """
        new = ose_step(self.x_hat, y, A, self.config.gamma, Q=Q, b=b)
        self.x_hat = new
        self.t += 1
        return new
