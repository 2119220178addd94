"""RSEIO: sensitivity-penalised robust state estimation with random measurement droppings.

Theorem 1 of T. Zhou, "Robust recursive state estimation with random measurements
droppings". For the plant of eq. (1) with parameter errors ``eps``, the estimate minimises
the cost (2), which adds to the Kalman least-squares cost -- only when ``gamma_{t+1} = 1`` --
a penalty ``(1 - mu_t)/mu_t`` on the first-order sensitivity of the innovation to ``eps``.
The result, eqs. (4) and (5), is

* ``gamma_{t+1} = 0``: ``x_{t+1|t+1} = A_t x_{t|t}``, ``P_{t+1|t+1} = A_t P A_t' + B_t Q_t B_t'``;
* ``gamma_{t+1} = 1``: a Kalman update from the adjusted prior
  ``x_pred = A_hat x_{t|t}``, ``P_pred = A_t P_hat A_t' + B_hat Q_hat B_hat'``, with
  ``lambda_t = (1 - mu_t) / mu_t`` and::

      P_hat = (P^-1 + lambda S'S)^-1
      Q_hat = [Q^-1 + lambda T' (I + lambda S P S')^-1 T]^-1
      B_hat = B - lambda A P_hat S' T
      A_hat = (A - lambda B_hat Q_hat T' S)(I - lambda P_hat S'S)

  where ``S_t``, ``T_t`` stack ``C_{t+1} dA_t/deps_k``, ``dC_{t+1}/deps_k A_t`` and
  ``C_{t+1} dB_t/deps_k``, ``dC_{t+1}/deps_k B_t`` over ``k = 1..n_e``.

Two typos of the printed Theorem 1 are corrected here (see ``docs/robust.md``): ``Q_hat``
needs the inverse of ``(I + lambda S P S')`` and ``A_hat`` needs the factor ``lambda`` in
front of ``B_hat Q_hat T' S``; both follow from the proof (eqs. (a.9)-(a.12)) and are the
only forms that minimise the cost (2). They matter only when ``T_t != 0``.
With ``mu_t = 1`` (or ``S_t = T_t = 0``) RSEIO is exactly KFIO.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from netsense.estimators.kalman import (
    _T,
    KFIO,
    StateSpaceModel,
    _sym,
    bmm,
    check_matrix,
    spd_solve,
)

__all__ = ["RSEIO", "sensitivity_matrices"]

DerivLike = np.ndarray | Callable[[int], np.ndarray] | None


def sensitivity_matrices(A: np.ndarray, B: np.ndarray, C_next: np.ndarray,
                         dA: np.ndarray, dB: np.ndarray, dC_next: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """``S_t`` and ``T_t`` of Theorem 1 from nominal matrices and derivatives.

    Parameters
    ----------
    A, B : (n, n), (n, p) arrays
        ``A_t(0)``, ``B_t(0)``.
    C_next : (m, n) array
        ``C_{t+1}(0)``.
    dA, dB : (n_e, n, n), (n_e, n, p) arrays
        ``dA_t/deps_{t,k}`` and ``dB_t/deps_{t,k}`` at ``eps = 0``.
    dC_next : (n_e, m, n) array
        ``dC_{t+1}/deps_{t+1,k}`` at ``eps = 0``.

    Returns
    -------
    S : (2 n_e m, n) array
        ``col{[C_{t+1} dA_k ; dC_k A_t]}_k``.
    T : (2 n_e m, p) array
        ``col{[C_{t+1} dB_k ; dC_k B_t]}_k``.
    """
    S = np.concatenate([C_next @ dA, dC_next @ A], axis=1).reshape(-1, A.shape[1])
    T = np.concatenate([C_next @ dB, dC_next @ B], axis=1).reshape(-1, B.shape[1])
    return S, T


class RSEIO(KFIO):
    """Robust state estimator with intermittent observations, Theorem 1 (eqs. (4), (5)).

    Parameters
    ----------
    model : StateSpaceModel
        Nominal model ``A_t(0), B_t(0), C_t(0), Q_t, R_t``.
    mu : float or callable ``t -> float``
        Design parameter ``mu_t`` in (0, 1]; ``mu = 1`` gives KFIO.
    dA : (n_e, n, n) array, callable ``t -> array``, or None
        Derivatives ``dA_t(eps)/deps_{t,k}`` at ``eps = 0``, one matrix per parameter
        (None = zero).
    dB : (n_e, n, p) array, callable, or None
        Derivatives of ``B_t``.
    dC : (n_e, m, n) array, callable, or None
        Derivatives of ``C_t`` (evaluated at ``t + 1`` for the step ``t -> t + 1``).
    n_e : int, optional
        Number of uncertain parameters; needed only when every derivative is a callable or
        None.

    Notes
    -----
    ``P_hat`` and ``Q_hat`` are computed with the matrix-inversion lemma,
    ``P_hat = P - lambda P S' (I + lambda S P S')^-1 S P`` and
    ``Q_hat = Q - lambda Q T' (I + lambda S P S' + lambda T Q T')^-1 T Q``,
    so neither ``P`` nor ``Q`` is inverted.
    """

    def __init__(self, model: StateSpaceModel, mu: float | Callable[[int], float],
                 dA: DerivLike = None, dB: DerivLike = None, dC: DerivLike = None,
                 n_e: int | None = None) -> None:
        super().__init__(model)
        n, p, m = model.n, model.p, model.m
        self._deriv_shapes = {"dA": (n, n), "dB": (n, p), "dC": (m, n)}
        sizes = set()
        for name, value in (("dA", dA), ("dB", dB), ("dC", dC)):
            if value is not None and not callable(value):
                arr = np.asarray(value, dtype=float)
                if arr.ndim == 2:
                    arr = arr[None]
                sizes.add(check_matrix(name, arr, (None, *self._deriv_shapes[name])).shape[0])
        if n_e is not None:
            sizes.add(int(n_e))
        if len(sizes) > 1:
            raise ValueError(f"dA, dB, dC and n_e disagree on the number of parameters n_e: "
                             f"{sorted(sizes)}")
        if not sizes:
            if any(callable(d) for d in (dA, dB, dC)):
                raise ValueError("n_e must be given when every derivative is a callable")
            sizes.add(0)
        self.n_e = sizes.pop()
        self._derivs = {}
        for name, value in (("dA", dA), ("dB", dB), ("dC", dC)):
            if value is None:
                value = np.zeros((self.n_e, *self._deriv_shapes[name]))
            elif not callable(value):
                value = np.asarray(value, dtype=float).reshape(self.n_e,
                                                               *self._deriv_shapes[name])
            self._derivs[name] = value
        self.mu = mu
        self.mu_at(0)
        self.sensitivities(0)

    def mu_at(self, t: int) -> float:
        """``mu_t``, validated to lie in (0, 1]."""
        mu = self.mu(t) if callable(self.mu) else self.mu
        if isinstance(mu, bool) or not np.isscalar(mu) or not (0.0 < float(mu) <= 1.0):
            raise ValueError(f"mu must lie in (0, 1], got {mu!r}"
                             + ("" if not callable(self.mu) else f" at t = {t}"))
        return float(mu)

    def _deriv(self, name: str, t: int) -> np.ndarray:
        value = self._derivs[name]
        if not callable(value):
            return value
        arr = np.asarray(value(t), dtype=float)
        if arr.ndim == 2 and self.n_e == 1:
            arr = arr[None]
        return check_matrix(f"{name}({t})", arr, (self.n_e, *self._deriv_shapes[name]))

    def sensitivities(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """``S_t`` and ``T_t`` of Theorem 1 for the step ``t -> t + 1``."""
        at = self.model.at
        return sensitivity_matrices(at("A", t), at("B", t), at("C", t + 1),
                                    self._deriv("dA", t), self._deriv("dB", t),
                                    self._deriv("dC", t + 1))

    def adjusted(self, t: int, P: np.ndarray) -> dict[str, np.ndarray]:
        """Adjusted matrices of Theorem 1 for ``P = P_{t|t}`` of shape (batch, n, n).

        Returns a dict with ``P_hat`` (b, n, n), ``Q_hat`` (b, p, p), ``B_hat`` (b, n, p),
        ``A_hat`` (b, n, n) and the prior ``P_pred = A P_hat A' + B_hat Q_hat B_hat'``.
        """
        mu = self.mu_at(t)
        lam = (1.0 - mu) / mu
        A, B, Q = (self.model.at(k, t) for k in ("A", "B", "Q"))
        S, T = self.sensitivities(t)
        # Rows that are zero in both S and T change nothing (exactly); dropping them keeps the
        # systems below as small as possible (1x1 for the section IV plant).
        keep = np.any(S != 0, axis=1) | np.any(T != 0, axis=1)
        if not keep.any():                    # nothing to penalise: one zero row
            S, T = np.zeros((1, S.shape[1])), np.zeros((1, T.shape[1]))
        else:
            S, T = S[keep], T[keep]
        SP = bmm(S, P)                                            # (b, q, n)
        G = _sym(np.eye(S.shape[0]) + lam * bmm(SP, S.T))         # I + lam S P S'
        P_hat = _sym(P - lam * bmm(_T(SP), spd_solve(G, SP)))
        TQ = T @ Q                                                # (q, p)
        H = _sym(G + lam * TQ @ T.T)                              # G + lam T Q T'
        TQb = np.broadcast_to(TQ, H.shape[:-2] + TQ.shape)
        Q_hat = _sym(Q - lam * bmm(TQ.T, spd_solve(H, TQb)))
        B_hat = B - lam * bmm(bmm(A, P_hat), S.T @ T)
        A_hat = bmm(A - lam * bmm(bmm(B_hat, Q_hat), T.T @ S),
                    np.eye(self.model.n) - lam * bmm(P_hat, S.T @ S))
        P_pred = _sym(bmm(bmm(A, P_hat), A.T) + bmm(bmm(B_hat, Q_hat), _T(B_hat)))
        return {"P_hat": P_hat, "Q_hat": Q_hat, "B_hat": B_hat, "A_hat": A_hat,
                "P_pred": P_pred}

    def _prior(self, t: int, x_free: np.ndarray, P_free: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        adj = self.adjusted(t, self.P)
        return np.sum(adj["A_hat"] * self.x[:, None, :], axis=-1), adj["P_pred"]
