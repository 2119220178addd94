"""The benchmark's ``kf_oracle``: a centralized Kalman filter with no network."""

from __future__ import annotations

import numpy as np


class CentralizedKF:
    """Centralized Kalman one-step predictor on the stacked ``y = C x + v`` (the oracle).

    At step ``k`` it updates with every agent's measurement ``y_i[k]`` that arrived and
    predicts ``x_hat[k+1|k] = A x_hat[k|k]`` — the same information timing as the
    distributed agents (whose estimate of ``x[k+1]`` uses measurements up to ``k``) but
    with no network in between, so its error is a lower bound. Covariances come from the
    plant's noise models; a noise-free plant gets ``jitter`` so the filter stays well
    posed (it then acts like a near-deadbeat centralized observer).

    With ``batch_size=B`` it runs ``B`` independent filters (one per member of a
    :class:`netsense.engine.core.BatchedCore`) as stacked arrays: members whose arrived
    measurements coincide share one stacked update, and every member computes exactly
    what a single filter computes on its data.

    Parameters
    ----------
    plant : netsense.systems.plants.Plant
    x0_std : float
        Prior ``x[0] ~ N(0, x0_std^2 I)`` (the scenario's initial-state law).
    jitter : float
        Covariance floor for noise-free plants.
    batch_size : int, optional
        ``B`` filters; then :attr:`x` is ``(B, n)``, :attr:`P` ``(B, n, n)`` and
        :meth:`step` takes ``(B, N, r_max)`` measurements. Default: one filter with
        unbatched shapes.
    """

    def __init__(self, plant, *, x0_std: float = 1.0, jitter: float = 1e-9,
                 batch_size: int | None = None) -> None:
        if batch_size is not None and (isinstance(batch_size, bool) or int(batch_size) < 1
                                       or int(batch_size) != batch_size):
            raise ValueError(f"batch_size must be an integer >= 1 or None, got {batch_size!r}")
        self.A = np.asarray(plant.A, dtype=float)
        W = plant.W_effective
        self.Qw = max(_noise_variance(plant.process_noise), jitter) * (W @ W.T)
        self.C_pad = plant.C_padded  # (N, r_max, n)
        self.rows = plant.output_mask  # (N, r_max)
        self.r_var = max(_noise_variance(plant.measurement_noise), jitter)
        n = self.A.shape[0]
        self.batch_size = None if batch_size is None else int(batch_size)
        B = self.batch_size or 1
        self._x = np.zeros((B, n))
        self._P = np.repeat((max(x0_std, jitter) ** 2 * np.eye(n))[None], B, axis=0)

    @property
    def x(self) -> np.ndarray:
        """Prediction of ``x[k]``: ``(n,)``, or ``(B, n)`` when batched (a view)."""
        return self._x if self.batch_size is not None else self._x[0]

    @property
    def P(self) -> np.ndarray:
        """Its covariance: ``(n, n)``, or ``(B, n, n)`` when batched (a view)."""
        return self._P if self.batch_size is not None else self._P[0]

    @property
    def estimate(self) -> np.ndarray:
        """Copy of the current prediction of ``x[k]`` (shape of :attr:`x`)."""
        return self.x.copy()

    def step(self, y_padded: np.ndarray, arrived: np.ndarray | None = None,
             members: np.ndarray | None = None) -> np.ndarray:
        """Update with ``y[k]`` (rows of the ``arrived`` agents) and predict ``x[k+1]``.

        Parameters
        ----------
        y_padded : (N, r_max) array, or (B, N, r_max) when batched
        arrived : (N,) bool, or (B, N) when batched, optional
            Agents whose ``y_i[k]`` arrived (default all).
        members : (B,) bool, optional
            Batched only: advance just these filters (the others are left as they are,
            e.g. members whose episode already ended).

        Returns
        -------
        array
            :attr:`x`, the new prediction.
        """
        B, (N, r) = self._x.shape[0], self.rows.shape
        y = np.asarray(y_padded, dtype=float)
        arr = None if arrived is None else np.asarray(arrived, dtype=bool)
        if self.batch_size is None:
            if members is not None:
                raise ValueError("members needs a batched filter (batch_size=B)")
            y = y[None]
            arr = None if arr is None else arr[None]
        if y.shape != (B, N, r) or (arr is not None and arr.shape != (B, N)):
            lead = () if self.batch_size is None else (B,)
            raise ValueError(f"y_padded must have shape {lead + (N, r)} and arrived "
                             f"{lead + (N,)}, got {np.shape(y_padded)} and "
                             f"{None if arrived is None else np.shape(arrived)}")
        use = (np.broadcast_to(self.rows, (B, N, r)) if arr is None
               else self.rows & arr[..., None])
        if members is None:
            live = np.arange(B)
        else:
            sel = np.asarray(members, dtype=bool)
            if sel.shape != (B,):
                raise ValueError(f"members must have shape ({B},), got {sel.shape}")
            live = np.flatnonzero(sel)
        if live.size == 0:
            return self.x
        # members with the same measurement rows share one stacked update
        pattern = use[live].reshape(live.size, -1)
        if (pattern == pattern[:1]).all():
            groups = [live]
        else:
            _, inv = np.unique(pattern, axis=0, return_inverse=True)
            inv = inv.reshape(-1)
            groups = [live[inv == g] for g in range(int(inv.max()) + 1)]
        for g in groups:
            self._update(g, use[g[0]], y[g])
        x, P = self._x[live], self._P[live]
        x = (self.A @ x[..., None])[..., 0]
        P = self.A @ P @ self.A.T + self.Qw
        self._x[live] = x
        self._P[live] = 0.5 * (P + np.swapaxes(P, -1, -2))
        return self.x

    def _update(self, g: np.ndarray, use: np.ndarray, y: np.ndarray) -> None:
        """Measurement update of filters ``g`` whose measurement rows are ``use``."""
        C = self.C_pad[use]  # (m, n)
        if not C.shape[0]:
            return
        x, P = self._x[g], self._P[g]
        S = C @ P @ C.T + self.r_var * np.eye(C.shape[0])
        K = np.swapaxes(np.linalg.solve(S, C @ P), -1, -2)  # (G, n, m)
        innov = y[:, use] - (C @ x[..., None])[..., 0]
        x = x + (K @ innov[..., None])[..., 0]
        I_KC = np.eye(x.shape[-1]) - K @ C
        P = I_KC @ P @ np.swapaxes(I_KC, -1, -2) + self.r_var * K @ np.swapaxes(K, -1, -2)
        self._x[g], self._P[g] = x, P


def _noise_variance(model) -> float:
    d = model.to_dict()
    if d.get("kind") == "gaussian":
        return float(d["std"]) ** 2
    if d.get("kind") == "uniform":
        return float(d["half_width"]) ** 2 / 3.0
    return 0.0
