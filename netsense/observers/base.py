"""Shared machinery of the distributed observers: state, inputs, one step.

Subclasses only decide *what each agent propagates* for each substate
(:meth:`DistributedObserver._select`); propagation, the source correction and the
coordinate change are common and come from :mod:`netsense.kernels.update`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netsense.graphs.processes import in_neighbor_slots
from netsense.kernels import checks
from netsense.kernels import update as kernels
from netsense.observers.source import LuenbergerSource, SourceEstimator
from netsense.systems.design import ObserverDesign, design_observer


class DistributedObserver:
    """Base class: ``N`` agents each holding an estimate of the full state.

    Parameters
    ----------
    design : ObserverDesign
        Decomposition and source gains (:func:`netsense.design_observer`).
    batch_size : int, optional
        Run ``B`` independent copies at once (arrays gain a leading axis); default a
        single run, whose inputs and outputs have no batch axis.
    source_estimator : SourceEstimator, optional
        Replaces the fixed-gain source update of eq. (7).
    input_matrix : (n, m) array, optional
        The plant's ``B``, when a known input ``u`` (shared by all agents) drives it.
    """

    def __init__(self, design: ObserverDesign, *, batch_size: int | None = None,
                 source_estimator: SourceEstimator | None = None,
                 input_matrix: np.ndarray | None = None) -> None:
        if not isinstance(design, ObserverDesign):
            raise ValueError("design must be an ObserverDesign (see netsense.design_observer)")
        if batch_size is not None:
            batch_size = checks.integer("batch_size", batch_size, 1)
        self.design = design
        self.batched = batch_size is not None
        self.B = batch_size or 1
        d = design.decomposition
        self.N, self.n = d.num_agents, d.n
        self.r_max = max([C.shape[0] for C in d.C_bar] + [1])
        self.block_of = d.block_of
        self.A_diag, self.A_lower = d.A_diag, d.A_lower
        self.own_block = SourceEstimator.own_block_mask(design)
        self.source_estimator = source_estimator or LuenbergerSource()
        self.B_bar = None
        if input_matrix is not None:
            Bm = np.asarray(input_matrix, dtype=float)
            if Bm.ndim != 2 or Bm.shape[0] != self.n:
                raise ValueError(f"input_matrix must have shape ({self.n}, m), got {Bm.shape}")
            self.B_bar = d.T.T @ Bm
        self.reset()

    @classmethod
    def from_plant(cls, plant, *, rho: float = 0.5, deadbeat: bool = False, **kwargs):
        """Design gains for ``plant`` (Lemma 1 + Theorem 1 / Corollary 1) and build."""
        return cls(design_observer(plant, rho=rho, deadbeat=deadbeat), **kwargs)

    # ----------------------------------------------------------------- state
    def reset(self, x0_hat: np.ndarray | None = None, *,
              rng: np.random.Generator | None = None) -> None:
        """Reset time, estimates and freshness indices.

        ``x0_hat`` is the initial estimate in ``x`` coordinates: ``(n,)`` for every agent,
        ``(N, n)`` per agent, or ``(B, N, n)`` per batch member; default zero. Indices
        start at ``tau_j^{(j)} = 0`` and omega elsewhere.
        """
        shape = (self.B, self.N, self.n)
        if x0_hat is None:
            X = np.zeros(shape)
        else:
            X = np.asarray(x0_hat, dtype=float)
            if X.shape not in ((self.n,), (self.N, self.n), shape):
                raise ValueError(f"x0_hat must have shape ({self.n},), ({self.N}, {self.n}) "
                                 f"or {shape}, got {X.shape}")
            X = np.broadcast_to(X, shape)
        self.Z = X @ self.design.decomposition.T
        self.tau = np.full((self.B, self.N, self.N), kernels.OMEGA, dtype=np.int64)
        idx = np.arange(self.N)
        self.tau[:, idx, idx] = 0
        self.k = 0
        self.source_estimator.reset(self.design, self.B, rng)

    # ----------------------------------------------------------------- inputs
    def _batch(self, name: str, value, tail: tuple[int, ...], dtype) -> np.ndarray:
        arr = (checks.mask(name, value) if dtype is bool
               else checks.array(name, value, kind="ibf").astype(dtype, copy=False))
        if not self.batched:
            if arr.shape != tail:
                raise ValueError(f"{name} must have shape {tail}, got {arr.shape}")
            return arr[None]
        if arr.shape == tail:
            return np.broadcast_to(arr, (self.B,) + tail)
        if arr.shape != (self.B,) + tail:
            raise ValueError(f"{name} must have shape {(self.B,) + tail} or {tail}, "
                             f"got {arr.shape}")
        return arr

    def _measurements(self, y) -> np.ndarray:
        if isinstance(y, Sequence) and not isinstance(y, np.ndarray) and not self.batched:
            if len(y) != self.N:
                raise ValueError(f"y must hold {self.N} measurement vectors, got {len(y)}")
            out = np.zeros((self.N, self.r_max))
            for i, (yi, Cb) in enumerate(zip(y, self.design.decomposition.C_bar, strict=True)):
                yi = np.asarray(yi, dtype=float).reshape(-1)
                if yi.shape[0] != Cb.shape[0]:
                    raise ValueError(f"y[{i}] must have {Cb.shape[0]} entries, got {yi.shape[0]}")
                out[i, : yi.shape[0]] = yi
            y = out
        y = self._batch("y", y, (self.N, self.r_max), float)
        if not np.all(np.isfinite(y)):
            raise ValueError("y contains NaN or infinite entries")
        return y

    # ------------------------------------------------------------------ step
    def step(self, y, adjacency, *, transmit=None, arrived=None, u=None) -> None:
        """Advance every agent's estimate and indices from ``k`` to ``k + 1``.

        All inputs are validated before any state changes.

        Parameters
        ----------
        y : (N, r_max) array, list of N vectors, or (B, N, r_max)
            Measurements ``y_i[k]`` (padded layout as ``Plant.measure`` returns).
        adjacency : (N, N) or (B, N, N) bool
            ``G[k]``: ``adjacency[i, l]`` when ``l`` sends to ``i``.
        transmit : (N,) or (B, N) bool, optional
            Which agents sent their estimates this step (default all).
        arrived : (N,) or (B, N) bool, optional
            Whose measurement arrived (default all).
        u : (m,) or (B, m) array, optional
            Known input, if the plant has ``B``.
        """
        y = self._measurements(y)
        adj = self._batch("adjacency", adjacency, (self.N, self.N), bool)
        if np.any(adj[:, np.arange(self.N), np.arange(self.N)]):
            raise ValueError("adjacency must have an empty diagonal (no self-loops)")
        tx = None if transmit is None else self._batch("transmit", transmit, (self.N,), bool)
        arr = None if arrived is None else self._batch("arrived", arrived, (self.N,), bool)
        if u is not None:
            if self.B_bar is None:
                raise ValueError("u was given but the observer has no input_matrix")
            m = self.B_bar.shape[1]
            if np.shape(u)[-1:] != (m,):
                raise ValueError(f"u must have {m} entries in its last axis, got {np.shape(u)}")
        nbr, valid = in_neighbor_slots(adj, max(self.N - 1, 0))
        self._advance(y, nbr, valid, tx, arr, u)

    def _advance(self, y, nbr, valid, tx, arr, u) -> None:
        Z_sel, tau_next = self._select(self.Z, self.tau, nbr, valid, tx)
        Z_next = kernels.propagate(Z_sel, self.Z, self.A_diag, self.A_lower)
        Z_next += self.source_estimator.correction(self.k, self.Z, y, arr)
        if u is not None:
            u = np.asarray(u, dtype=float)
            Z_next += (u @ self.B_bar.T)[..., None, :] if u.ndim == 2 else u @ self.B_bar.T
        self.Z, self.tau = Z_next, tau_next
        self.k += 1

    def _select(self, Z, tau, nbr, valid, tx):
        raise NotImplementedError  # pragma: no cover

    # ---------------------------------------------------------------- outputs
    def _out(self, arr: np.ndarray) -> np.ndarray:
        return arr if self.batched else arr[0]

    @property
    def z_estimates(self) -> np.ndarray:
        """Estimates in Lemma 1 coordinates, ``(N, n)`` (or ``(B, N, n)``)."""
        return self._out(self.Z).copy()

    @property
    def estimates(self) -> np.ndarray:
        """Every agent's estimate of ``x``, ``(N, n)`` (or ``(B, N, n)``)."""
        return self._out(self.Z @ self.design.decomposition.T.T)

    @property
    def indices(self) -> np.ndarray:
        """Freshness indices ``tau_i^{(j)}`` at ``[i, j]`` (``OMEGA = -1`` for omega)."""
        return self._out(self.tau).copy()

    def errors(self, x: np.ndarray) -> np.ndarray:
        """``||x_hat_i - x||`` per agent for the true state ``x`` (``(n,)`` or ``(B, n)``)."""
        X = self.Z @ self.design.decomposition.T.T
        x = checks.array("x", x, kind="f")
        if x.shape not in ((self.n,), (self.B, self.n)):
            raise ValueError(f"x must have shape ({self.n},) or ({self.B}, {self.n}), got "
                             f"{x.shape}")
        return self._out(np.linalg.norm(X - (x[:, None, :] if x.ndim == 2 else x), axis=-1))
