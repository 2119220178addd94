"""Kalman filter (KF) and Kalman filter with intermittent observations (KFIO).

Plant (eq. (1) of the robust-estimation paper, nominal matrices ``eps = 0``)::

    x_{t+1} = A_t x_t + B_t w_t,        w_t ~ N(0, Q_t)
    y_t     = gamma_t C_t x_t + v_t,     v_t ~ N(0, R_t)

Both filters are batched over Monte Carlo runs: the estimate is ``(batch, n)`` and the
(pseudo-)covariance ``(batch, n, n)``; every run may see its own arrival sequence.

* :class:`KalmanFilter` -- the paper's "Kalman filter" baseline of section IV: every received
  ``y_t`` is regarded as a plant output measurement, so when a packet is dropped
  (``gamma_t = 0``) the filter still applies the measurement update with ``y_t = v_t``
  (pure noise), as if ``y_t = C_t x_t + v_t``. It ignores ``gamma``.
* :class:`KFIO` -- Sinopoli et al. (2004): measurement update only when ``gamma_t = 1``,
  prediction only otherwise. It equals eqs. (4)-(5) with ``mu_t = 1``.

A step advances ``(x_{t|t}, P_{t|t})`` to ``(x_{t+1|t+1}, P_{t+1|t+1})`` using ``y_{t+1}`` and
``gamma_{t+1}``; :meth:`KalmanFilter.reset` sets ``x_{0|0}`` and ``P_{0|0}`` (no measurement
is processed at ``t = 0``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["KFIO", "KalmanFilter", "StateSpaceModel"]

MatrixLike = np.ndarray | Callable[[int], np.ndarray]


def check_matrix(name: str, M: ArrayLike, shape: tuple[int | None, ...]) -> np.ndarray:
    """Return ``M`` as a finite float array of ``shape`` (``None`` = any) or raise."""
    M = np.asarray(M, dtype=float)
    bad = M.ndim != len(shape) or any(
        s is not None and s != d for s, d in zip(shape, M.shape, strict=False))
    if bad:
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name} must have shape {want}, got {M.shape}")
    if not np.all(np.isfinite(M)):
        raise ValueError(f"{name} contains NaN or infinite entries")
    return M


def check_pd(name: str, M: np.ndarray) -> np.ndarray:
    """Raise ValueError unless ``M`` (``(..., k, k)``) is symmetric positive definite."""
    scale = max(1.0, float(np.max(np.abs(M)))) if M.size else 1.0
    if not np.allclose(M, np.swapaxes(M, -1, -2), rtol=0.0, atol=1e-10 * scale):
        raise ValueError(f"{name} must be symmetric")
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        raise ValueError(f"{name} must be positive definite") from None
    return M


def _sym(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + np.swapaxes(M, -1, -2))


def _T(M: np.ndarray) -> np.ndarray:
    return np.swapaxes(M, -1, -2)


def rowmul(X: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``X @ M`` for rows ``X (..., k)`` and a matrix ``M (k, m)``, every row alone.

    ``out = sum_i X[..., i] M[i]`` summed over ``i`` ascending, element by element: a row's
    result does not depend on how many rows are stacked with it, so a member of a batch
    equals a ``batch = 1`` run bit for bit (one BLAS call on the stacked rows may sum in
    another order for another number of rows, by up to an ulp).
    """
    k = M.shape[0]
    if k == 0:
        return np.zeros(X.shape[:-1] + M.shape[1:])
    out = X[..., 0:1] * M[0]
    for i in range(1, k):
        out = out + X[..., i:i + 1] * M[i]
    return out


def bmm(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """``X @ Y`` for stacks of small matrices (either may be a plain 2-D matrix).

    numpy's stacked ``matmul`` costs about a microsecond per tiny matrix; for inner sizes up to
    8 an explicit sum of broadcast outer products over the inner index is an order of
    magnitude faster on thousands of Monte Carlo runs. The result is the same product, and
    each matrix of a stack gets the same bits whatever the stack's length.
    """
    if X.ndim == 2 and Y.ndim == 2:
        return X @ Y
    k = X.shape[-1]
    if k > 8:
        return X @ Y  # (stacked: one BLAS call per matrix, the same for any stack length)
    out = X[..., :, 0:1] * Y[..., 0:1, :]
    for i in range(1, k):
        out = out + X[..., :, i:i + 1] * Y[..., i:i + 1, :]
    return out


def spd_solve(G: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Solve ``G Z = X`` for a stack of symmetric positive definite ``G`` (division if 1x1)."""
    if G.shape[-1] == 1:
        return X / G
    return np.linalg.solve(G, X)


@dataclass(frozen=True, eq=False)
class StateSpaceModel:
    """Nominal model ``(A_t, B_t, C_t, Q_t, R_t)`` of eq. (1) at ``eps = 0``.

    Each field is either a constant matrix or a callable ``t -> matrix`` (time-varying);
    callables are validated (shape, finiteness, positive definiteness of ``Q_t``, ``R_t``)
    every time they are evaluated, constants once here.

    Parameters
    ----------
    A : (n, n) array or callable
        Nominal state matrix ``A_t(0)``.
    B : (n, p) array or callable
        Nominal noise input ``B_t(0)``.
    C : (m, n) array or callable
        Nominal output matrix ``C_t(0)``.
    Q : (p, p) array or callable
        Process-noise covariance ``Q_t`` (positive definite).
    R : (m, m) array or callable
        Measurement-noise covariance ``R_t`` (positive definite).
    """

    A: MatrixLike
    B: MatrixLike
    C: MatrixLike
    Q: MatrixLike
    R: MatrixLike

    def __post_init__(self) -> None:
        A0 = np.asarray(self.A(0) if callable(self.A) else self.A, dtype=float)
        B0 = np.asarray(self.B(0) if callable(self.B) else self.B, dtype=float)
        C0 = np.asarray(self.C(0) if callable(self.C) else self.C, dtype=float)
        if A0.ndim != 2 or A0.shape[0] != A0.shape[1] or A0.shape[0] == 0:
            raise ValueError(f"A must be a non-empty square (n, n) matrix, got {A0.shape}")
        n = A0.shape[0]
        p = check_matrix("B", B0, (n, None)).shape[1]
        m = check_matrix("C", C0, (None, n)).shape[0]
        object.__setattr__(self, "_dims", (n, p, m))
        for name in ("A", "B", "C", "Q", "R"):
            if not callable(getattr(self, name)):
                object.__setattr__(self, name, self._check(name, getattr(self, name)))
        for name in ("A", "B", "C", "Q", "R"):
            self.at(name, 0)

    @property
    def n(self) -> int:
        """State dimension."""
        return self._dims[0]

    @property
    def p(self) -> int:
        """Process-noise dimension."""
        return self._dims[1]

    @property
    def m(self) -> int:
        """Output dimension."""
        return self._dims[2]

    def _check(self, name: str, M, t: int | None = None) -> np.ndarray:
        n, p, m = self._dims
        shape = {"A": (n, n), "B": (n, p), "C": (m, n), "Q": (p, p), "R": (m, m)}[name]
        label = name if t is None else f"{name}({t})"
        M = check_matrix(label, M, shape)
        if name in ("Q", "R"):
            check_pd(label, M)
        return M

    def at(self, name: str, t: int) -> np.ndarray:
        """Matrix ``name`` (one of A, B, C, Q, R) at time ``t``, validated."""
        value = getattr(self, name)
        return self._check(name, value(t), t) if callable(value) else value


class KalmanFilter:
    """Batched Kalman filter that treats every received ``y`` as a measurement.

    This is the "Kalman filter" of section IV of the robust-estimation paper: it does not
    use ``gamma_t``; a dropped packet (``y_t = v_t``) is processed like a real measurement.

    Parameters
    ----------
    model : StateSpaceModel
        Nominal model used by the filter.

    Attributes
    ----------
    x : (batch, n) array
        Current estimate ``x_{t|t}``.
    P : (batch, n, n) array
        Current (pseudo-)covariance ``P_{t|t}``.
    t : int
        Time index of the current estimate.
    """

    uses_arrivals = False

    def __init__(self, model: StateSpaceModel) -> None:
        if not isinstance(model, StateSpaceModel):
            raise ValueError(f"model must be a StateSpaceModel, got {type(model).__name__}")
        self.model = model
        self.x: np.ndarray | None = None
        self.P: np.ndarray | None = None
        self.t = 0

    # ------------------------------------------------------------------ set-up
    def reset(self, x0: ArrayLike, P0: ArrayLike, batch: int | None = None,
              t0: int = 0) -> None:
        """Set ``x_{t0|t0}`` and ``P_{t0|t0}``.

        Parameters
        ----------
        x0 : (n,) or (batch, n) array
            Initial estimate (``E{x_0}`` in the paper).
        P0 : (n, n) or (batch, n, n) array
            Initial covariance, symmetric positive definite.
        batch : int, optional
            Number of runs; inferred from ``x0``/``P0`` when they are batched, else 1.
        t0 : int
            Time index of the initial estimate.
        """
        n = self.model.n
        x0 = np.asarray(x0, dtype=float)
        P0 = np.asarray(P0, dtype=float)
        sizes = {a.shape[0] for a, k in ((x0, 2), (P0, 3)) if a.ndim == k}
        if batch is not None:
            sizes.add(int(batch))
        if len(sizes) > 1:
            raise ValueError(f"x0, P0 and batch disagree on the batch size: {sorted(sizes)}")
        b = sizes.pop() if sizes else 1
        if b < 1:
            raise ValueError(f"batch must be >= 1, got {b}")
        x0 = check_matrix("x0", x0, (n,) if x0.ndim == 1 else (b, n))
        P0 = check_matrix("P0", P0, (n, n) if P0.ndim == 2 else (b, n, n))
        check_pd("P0", P0)
        self.x = np.broadcast_to(x0, (b, n)).copy()
        self.P = np.broadcast_to(P0, (b, n, n)).copy()
        self.t = int(t0)

    @property
    def batch(self) -> int:
        """Number of Monte Carlo runs filtered in parallel."""
        self._require_reset()
        return self.x.shape[0]

    def _require_reset(self) -> None:
        if self.x is None:
            raise RuntimeError("call reset(x0, P0) before using the filter")

    # ------------------------------------------------------------------- steps
    def _inputs(self, y, gamma) -> tuple[np.ndarray, np.ndarray]:
        self._require_reset()
        b, m = self.batch, self.model.m
        y = np.asarray(y, dtype=float)
        if y.shape == (m,) and b == 1:
            y = y[None]
        if y.shape != (b, m):
            raise ValueError(f"y must have shape (batch, m) = ({b}, {m}), got {y.shape}")
        if gamma is None:
            gamma = np.ones(b, dtype=bool)
        gamma = np.asarray(gamma)
        if gamma.shape == () and b == 1:
            gamma = gamma[None]
        if gamma.shape != (b,) or not np.all((gamma == 0) | (gamma == 1)):
            raise ValueError(f"gamma must be a 0/1 (bool) array of shape ({b},), "
                             f"got shape {gamma.shape}")
        gamma = gamma.astype(bool)
        used = np.ones(b, dtype=bool) if not self.uses_arrivals else gamma
        if not np.all(np.isfinite(y[used])):
            raise ValueError("y contains NaN or infinite entries in rows the filter uses")
        return y, gamma

    def _prior(self, t: int, x_free: np.ndarray, P_free: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        """Prediction used before a measurement update; the nominal one for KF and KFIO."""
        return x_free, P_free

    def _nominal_prior(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        A, B, Q = (self.model.at(k, t) for k in ("A", "B", "Q"))
        return rowmul(self.x, A.T), _sym(bmm(bmm(A, self.P), A.T) + B @ Q @ B.T)

    def _drive(self, u) -> np.ndarray | None:
        if u is None:
            return None
        u = np.asarray(u, dtype=float)
        shape = (self.batch, self.model.n)
        if u.shape not in (shape, shape[1:]):
            raise ValueError(f"u must have shape {shape} or {shape[1:]}, got {u.shape}")
        if not np.all(np.isfinite(u)):
            raise ValueError("u contains NaN or infinite entries")
        return u

    def step(self, y: ArrayLike, gamma: ArrayLike | None = None,
             u: ArrayLike | None = None) -> np.ndarray:
        """Advance from ``t`` to ``t + 1`` with ``y_{t+1}`` and ``gamma_{t+1}``.

        Parameters
        ----------
        y : (batch, m) array
            Received signals ``y_{t+1}``; entries of dropped rows may be NaN for filters that
            use ``gamma`` (KFIO, RSEIO).
        gamma : (batch,) bool array, optional
            Arrival indicators ``gamma_{t+1}`` (default: all arrived).
        u : (batch, n) or (n,) array, optional
            Known additive drive, ``x_{t+1} = A_t x_t + B_t w_t + u_t`` (e.g. a known input
            or couplings to states estimated elsewhere); it shifts every prediction.

        Returns
        -------
        (batch, n) array
            ``x_{t+1|t+1}`` (also stored in :attr:`x`).
        """
        y, gamma = self._inputs(y, gamma)
        u = self._drive(u)
        t = self.t
        C, R = self.model.at("C", t + 1), self.model.at("R", t + 1)
        update = gamma if self.uses_arrivals else np.ones_like(gamma)
        x_free, P_free = self._nominal_prior(t)
        x_pred, P_pred = self._prior(t, x_free, P_free)
        if u is not None:
            x_free, x_pred = x_free + u, x_pred + u
        x_upd, P_upd = self._correct(x_pred, P_pred, y, update, C, R)
        if np.all(update):
            self.x, self.P = x_upd, P_upd
        else:
            self.x = np.where(update[:, None], x_upd, x_free)
            self.P = np.where(update[:, None, None], P_upd, P_free)
        self.t = t + 1
        return self.x

    def update(self, y: ArrayLike, gamma: ArrayLike | None = None) -> np.ndarray:
        """Measurement update at the current time ``t`` only (e.g. to use ``y_0``).

        The plain Kalman update with ``C_t``, ``R_t`` on the rows that use the measurement
        (all rows for :class:`KalmanFilter`, arrived rows for KFIO and RSEIO; Theorem 1
        adjusts only a prediction, so there is no robust form of an update alone).
        """
        y, gamma = self._inputs(y, gamma)
        C, R = self.model.at("C", self.t), self.model.at("R", self.t)
        update = gamma if self.uses_arrivals else np.ones_like(gamma)
        x_upd, P_upd = self._correct(self.x, self.P, y, update, C, R)
        self.x = np.where(update[:, None], x_upd, self.x)
        self.P = np.where(update[:, None, None], P_upd, self.P)
        return self.x

    @staticmethod
    def _correct(x_pred, P_pred, y, update, C, R) -> tuple[np.ndarray, np.ndarray]:
        """Measurement update, eqs. (4)-(5): ``P_+ = (P_pred^-1 + C'R^-1 C)^-1`` and
        ``x_+ = x_pred + P_+ C' R^-1 (y - C x_pred)``, written with the gain
        ``K = P_pred C' (C P_pred C' + R)^-1 = P_+ C' R^-1`` (no explicit inverses)."""
        CP = bmm(C, P_pred)                              # (b, m, n)
        S_y = _sym(bmm(CP, C.T) + R)                     # (b, m, m)
        K = _T(spd_solve(S_y, CP))                       # (b, n, m)
        innov = np.where(update[:, None], y, 0.0) - rowmul(x_pred, C.T)
        x_upd = x_pred + np.sum(K * innov[:, None, :], axis=-1)
        I_KC = np.eye(P_pred.shape[-1]) - bmm(K, C)     # Joseph form keeps P symmetric PSD
        P_upd = _sym(bmm(bmm(I_KC, P_pred), _T(I_KC)) + bmm(bmm(K, R), _T(K)))
        return x_upd, P_upd

    def run(self, ys: ArrayLike, gammas: ArrayLike | None = None) -> np.ndarray:
        """Filter a whole sequence; returns estimates ``x_{t|t}`` of shape (T + 1, batch, n).

        ``ys`` is ``(T, batch, m)`` holding ``y_{t0+1}, ..., y_{t0+T}``; ``gammas`` is
        ``(T, batch)`` or None. Entry 0 of the result is the current estimate.
        """
        ys = np.asarray(ys, dtype=float)
        if ys.ndim != 3:
            raise ValueError(f"ys must have shape (T, batch, m), got {ys.shape}")
        if gammas is not None and np.shape(gammas)[:1] != ys.shape[:1]:
            raise ValueError(f"gammas must have shape (T, batch) = {ys.shape[:2]}, "
                             f"got {np.shape(gammas)}")
        out = [self.x.copy()]
        for k in range(ys.shape[0]):
            out.append(self.step(ys[k], None if gammas is None else gammas[k]).copy())
        return np.stack(out)


class KFIO(KalmanFilter):
    """Kalman filter with intermittent observations (Sinopoli et al., 2004).

    When ``gamma_{t+1} = 0`` only the prediction ``x_{t+1|t+1} = A_t x_{t|t}``,
    ``P_{t+1|t+1} = A_t P_{t|t} A_t' + B_t Q_t B_t'`` is made (first branches of eqs. (4),
    (5)); when ``gamma_{t+1} = 1`` the usual Kalman update follows (eqs. (4), (5) with
    ``mu_t = 1``). ``P_{t|t}`` therefore depends on each run's arrival sequence.
    """

    uses_arrivals = True
