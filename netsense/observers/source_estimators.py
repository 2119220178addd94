"""KFIO and RSEIO as source-node estimators of the distributed observers.

The fixed gain of eq. (7) of the freshness paper, ``L_j (y_j - C_bar_j z_j)``
(:class:`~netsense.observers.source.LuenbergerSource`), is replaced by a Kalman-type update
of source ``j``'s own substate ``z^{(j)}`` (Lemma 1 coordinates, ``x = T z``) that knows
whether its measurement arrived:

* :class:`KFIOSource` -- Kalman filter with intermittent observations on the block;
* :class:`RSEIOSource` -- Theorem 1 of the robust-estimation paper (eqs. (4), (5)) on the
  block, with the parameter derivatives mapped into Lemma 1 coordinates.

Block model of source ``j`` (predictor form, as the observers hold ``z[k]`` based on
measurements up to ``k - 1``)::

    z^{(j)}[k+1] = A_jj z^{(j)}[k] + u_j[k] + (T' W)_j w[k],   u_j = sum_{q<j} A_jq z^{(q)}
    y_j[k] - sum_{q<j} C_jq z^{(q)}[k] = C_jj z^{(j)}[k] + v_j[k]

The couplings ``u_j`` and the ``C_jq`` terms use the source's own current estimates of the
upstream substates and are treated as known (their errors are not modelled, so ``P`` is the
block's covariance only under that approximation). At the first step the block filter starts
from the observer's initial estimate with covariance ``(T' P0 T)_jj`` and makes a plain
measurement update; afterwards each step is a KFIO/RSEIO step driven by ``u_j``. The new
own-block estimate is ``A_jj x_hat_{k|k} + u_j[k]``, i.e. the correction returned to the
observer is ``A_jj (x_hat_{k|k} - z^{(j)}[k])``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from netsense.estimators.kalman import KFIO, StateSpaceModel, check_matrix, rowmul
from netsense.estimators.robust import RSEIO
from netsense.observers.source import Rngs, SourceEstimator
from netsense.systems.design import ObserverDesign

__all__ = ["KFIOSource", "RSEIOSource"]


class KFIOSource(SourceEstimator):
    """Source update by a Kalman filter with intermittent observations on each own block.

    Parameters
    ----------
    Q : (p, p) array or float
        Process-noise covariance of ``w`` (a float ``q`` means ``q I_p``).
    R : float or sequence of N arrays (r_i, r_i)
        Measurement-noise covariance per agent (a float ``r`` means ``r I`` for all).
    W : (n, p) array, optional
        Process-noise input in ``x`` coordinates (default the identity, ``p = n``).
    P0 : (n, n) array or float, default 1.0
        Initial error covariance of the observers' initial estimate, in ``x`` coordinates.
    """

    def __init__(self, Q: ArrayLike, R: float | Sequence[ArrayLike],
                 W: ArrayLike | None = None, P0: ArrayLike = 1.0) -> None:
        self.Q, self.R, self.W, self.P0 = Q, R, W, P0

    # ------------------------------------------------------------------ set-up
    def _matrices(self, design: ObserverDesign) -> dict:
        d = design.decomposition
        n = d.n
        W = np.eye(n) if self.W is None else check_matrix("W", self.W, (n, None))
        p = W.shape[1]
        Q = (float(self.Q) * np.eye(p) if np.ndim(self.Q) == 0
             else check_matrix("Q", self.Q, (p, p)))
        P0 = (float(self.P0) * np.eye(n) if np.ndim(self.P0) == 0
              else check_matrix("P0", self.P0, (n, n)))
        if np.ndim(self.R) == 0:
            R = [float(self.R) * np.eye(C.shape[0]) for C in d.C_bar]
        else:
            if len(self.R) != d.num_agents:
                raise ValueError(f"R must hold {d.num_agents} per-agent covariances, "
                                 f"got {len(self.R)}")
            R = [check_matrix(f"R[{i}]", Ri, (C.shape[0], C.shape[0]))
                 for i, (Ri, C) in enumerate(zip(self.R, d.C_bar, strict=True))]
        return {"W_z": d.T.T @ W, "Q": Q, "R": R, "P0_z": d.T.T @ P0 @ d.T}

    def _filter(self, j: int, model: StateSpaceModel, design: ObserverDesign) -> KFIO:
        return KFIO(model)

    def reset(self, design: ObserverDesign, batch_size: int,
              rng: Rngs = None) -> None:
        super().reset(design, batch_size, rng)
        d = design.decomposition
        mats = self._matrices(design)
        self.sources = []
        for j in range(d.num_agents):
            b = d.block(j)
            if b.stop == b.start or d.C_bar[j].shape[0] == 0:
                continue
            model = StateSpaceModel(d.A_jj(j), mats["W_z"][b], d.C_jj(j), mats["Q"],
                                    mats["R"][j])       # raises if Q or R_j is not PD
            P0_j = mats["P0_z"][b, b]
            f = self._filter(j, model, design)
            f.reset(np.zeros(model.n), P0_j, batch=batch_size)
            self.sources.append((j, b, f, P0_j))
        self._first = np.ones(batch_size, dtype=bool)

    def reset_members(self, members: np.ndarray, rng: Rngs = None) -> None:
        """Restart the selected members: their next step re-initialises their filters."""
        members = np.asarray(members, dtype=bool)
        if members.shape != self._first.shape:
            raise ValueError(f"members must have shape {self._first.shape}, "
                             f"got {members.shape}")
        self._first = self._first | members

    def take(self, members: np.ndarray, rng: Rngs = None) -> KFIOSource:
        """The selected members' filters (estimates, covariances, first-step flags);
        the filters draw nothing, so ``rng`` is unused."""
        import copy

        members = np.asarray(members, dtype=np.int64)
        out = copy.copy(self)
        out.batch_size = len(members)
        out.sources = []
        for j, b, f, P0_j in self.sources:
            g = copy.copy(f)
            g.x, g.P = f.x[members].copy(), f.P[members].copy()
            out.sources.append((j, b, g, P0_j))
        out._first = self._first[members].copy()
        return out

    # ------------------------------------------------------------------- steps
    def correction(self, k: int | np.ndarray, Z: np.ndarray, y: np.ndarray,
                   arrived: np.ndarray | None) -> np.ndarray:
        """One KFIO (or RSEIO) step per source block and member.

        A member at its first step (after :meth:`reset` or :meth:`reset_members`) starts
        its filter from its current own-block estimate with covariance ``(T' P0 T)_jj``
        and makes a measurement update only; the other members make a full step. The
        block models are time-invariant, so ``k`` is not needed.
        """
        d = self.design.decomposition
        out = np.zeros_like(Z)
        first = self._first
        for j, b, f, P0_j in self.sources:
            C_bar = d.C_bar[j]
            z_own = Z[:, j, b]
            # (rowmul: each member's products alone, so a member equals a B = 1 run)
            y_loc = (y[:, j, : C_bar.shape[0]] - rowmul(Z[:, j], C_bar.T)
                     + rowmul(z_own, f.model.C.T))       # C_jj z^{(j)} + v_j
            gamma = np.ones(Z.shape[0], bool) if arrived is None else arrived[:, j]
            if not first.all():
                f.step(y_loc, gamma, u=z_own - rowmul(f.x, f.model.A.T))
            if first.any():
                f.x[first], f.P[first] = z_own[first], P0_j
                f.update(y_loc, gamma & first)
            out[:, j, b] = rowmul(f.x - z_own, f.model.A.T)
        self._first = np.zeros_like(first)
        return out

    def covariances(self) -> dict[int, np.ndarray]:
        """Current ``P_{k|k}`` of every source's block, ``{j: (B, n_j, n_j)}``."""
        return {j: f.P.copy() for j, _, f, _ in self.sources if f.P is not None}


class RSEIOSource(KFIOSource):
    """Source update by RSEIO (Theorem 1) on each own block.

    Parameters
    ----------
    Q, R, W, P0 : see :class:`KFIOSource`.
    mu : float
        Design parameter ``mu`` in (0, 1] (1 gives :class:`KFIOSource`).
    dA : (n_e, n, n) array, optional
        ``dA/deps_k`` in ``x`` coordinates; mapped to ``(T' dA T)_jj``.
    dW : (n_e, n, p) array, optional
        Derivatives of the noise input ``W`` (the paper's ``dB``); mapped to ``(T' dW)_j``.
    dC : sequence of N arrays (n_e, r_i, n), optional
        Derivatives of each agent's ``C_i``; mapped to ``(dC_j T)`` restricted to block j.
    """

    def __init__(self, Q: ArrayLike, R: float | Sequence[ArrayLike], mu: float,
                 W: ArrayLike | None = None, P0: ArrayLike = 1.0, dA: ArrayLike | None = None,
                 dW: ArrayLike | None = None, dC: Sequence[ArrayLike] | None = None) -> None:
        super().__init__(Q, R, W, P0)
        if isinstance(mu, bool) or not np.isscalar(mu) or not 0.0 < float(mu) <= 1.0:
            raise ValueError(f"mu must lie in (0, 1], got {mu!r}")
        self.mu, self.dA, self.dW, self.dC = mu, dA, dW, dC

    def _filter(self, j: int, model: StateSpaceModel, design: ObserverDesign) -> RSEIO:
        d = design.decomposition
        T, b = d.T, d.block(j)
        n = d.n
        dA = None if self.dA is None else check_matrix("dA", self.dA, (None, n, n))
        dW = None if self.dW is None else check_matrix("dW", self.dW, (None, n, model.p))
        dC = None
        if self.dC is not None:
            if len(self.dC) != d.num_agents:
                raise ValueError(f"dC must hold {d.num_agents} per-agent derivatives, "
                                 f"got {len(self.dC)}")
            dC = check_matrix(f"dC[{j}]", self.dC[j], (None, model.m, n)) @ T
        n_e = {a.shape[0] for a in (dA, dW, dC) if a is not None} or {0}
        if len(n_e) > 1:
            raise ValueError(f"dA, dW and dC disagree on the number of parameters: {n_e}")
        return RSEIO(model, self.mu,
                     dA=None if dA is None else (T.T @ dA @ T)[:, b, b],
                     dB=None if dW is None else (T.T @ dW)[:, b],
                     dC=None if dC is None else dC[:, :, b], n_e=n_e.pop())
