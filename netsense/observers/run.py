"""Run a batched distributed observer on a plant over given graphs, and measure it.

:func:`run_observer` drives any :class:`~netsense.observers.base.DistributedObserver` for
``K`` steps on ``B`` graph sequences and records a :class:`Trajectory` (indices, errors
per agent and per substate, messages, adoptions); fault models act through a
:data:`StepHook` (:mod:`netsense.observers.faults`). :func:`relative_error` and
:func:`steps_to_tolerance` reduce a trajectory to the numbers that Theorem 1 and
Corollary 1 speak of (bounds in :mod:`netsense.graphs.bounds`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from netsense.observers.base import DistributedObserver
    from netsense.systems.plants import Plant

__all__ = ["StepHook", "Trajectory", "relative_error", "run_observer", "steps_to_tolerance"]


# ----------------------------------------------------------------------------- simulation
@dataclass(frozen=True, eq=False)
class Trajectory:
    """Everything a sweep measures from one batched run of ``K`` steps.

    Attributes
    ----------
    tau : (K+1, B, N, N) int
        Freshness indices ``tau_i^{(j)}[k]`` at ``[k, b, i, j]`` (``OMEGA = -1``).
    errors : (K+1, B, N) float
        ``||x_hat_i[k] - x[k]||`` per agent.
    sub_errors : (K+1, B, N, N) float
        ``||e_i^{(j)}[k]||``: agent ``i``'s error on substate ``j`` (Lemma 1 coordinates).
    state_norm : (K+1, B) float
        ``||x[k]||``.
    messages : (K, B) int
        Links ``l -> i`` present in ``G[k]`` whose sender transmitted (one message each).
    adoptions : (K, B) int
        Pairs ``(i, j)`` where agent ``i`` adopted a neighbour's estimate of substate ``j``
        (eqs. (9)-(10)); zero for observers that do not adopt (consensus).
    alive : (N,) bool
        Agents counted in :func:`relative_error` (crashed agents are excluded).
    """

    tau: np.ndarray
    errors: np.ndarray
    sub_errors: np.ndarray
    state_norm: np.ndarray
    messages: np.ndarray
    adoptions: np.ndarray
    alive: np.ndarray

    @property
    def steps(self) -> int:
        return self.messages.shape[0]


#: ``hook(k, x, y, adjacency, transmit, arrived) -> (y, adjacency, transmit, arrived)``,
#: called before every observer step; fault models use it (see :mod:`netsense.observers.faults`).
StepHook = Callable[[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
                    tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]


def run_observer(observer: DistributedObserver, plant: Plant, graphs: np.ndarray,
                 x0: np.ndarray, *,
                 x0_hat: np.ndarray | None = None, hook: StepHook | None = None,
                 alive: np.ndarray | None = None,
                 noise_rng: np.random.Generator | None = None) -> Trajectory:
    """Run a batched distributed observer on a noiseless plant and record a trajectory.

    Parameters
    ----------
    observer : DistributedObserver
        Built with ``batch_size=B``; it is reset here.
    plant : Plant
        ``x[k+1] = A x[k]``, ``y_i[k] = C_i x[k]`` (eqs. (1)-(2)), plus the plant's
        process and measurement noise when it has any (drawn from ``noise_rng``).
    graphs : (B, K, N, N) bool
        ``G[k]`` per batch member (``adjacency[i, l]``: ``l -> i``).
    x0 : (B, n)
        Initial states.
    x0_hat : (n,), (N, n) or (B, N, n), optional
        Initial estimates (default zero).
    hook : StepHook, optional
        Rewrites the step inputs (faults).
    alive : (N,) bool, optional
        Agents counted by :func:`relative_error` (default all).
    noise_rng : Generator, optional
        Required when the plant has noise.
    """
    graphs = np.asarray(graphs, dtype=bool)
    B, N, n = observer.B, observer.N, observer.n
    if graphs.ndim != 4 or graphs.shape[0] != B or graphs.shape[2:] != (N, N):
        raise ValueError(f"graphs must have shape ({B}, K, {N}, {N}), got {graphs.shape}")
    x = np.asarray(x0, dtype=float)
    if x.shape != (B, n):
        raise ValueError(f"x0 must have shape ({B}, {n}), got {x.shape}")
    K = graphs.shape[1]
    observer.reset(x0_hat)
    T = observer.design.decomposition.T
    block_of = observer.block_of
    onehot = (block_of[:, None] == np.arange(N)[None, :]).astype(float)  # (n, N)
    tau = np.empty((K + 1, B, N, N), dtype=np.int64)
    errors = np.empty((K + 1, B, N))
    sub = np.empty((K + 1, B, N, N))
    xn = np.empty((K + 1, B))
    messages = np.zeros((K, B), dtype=np.int64)
    adoptions = np.zeros((K, B), dtype=np.int64)
    own = np.arange(N)[None, :, None]

    def record(k: int) -> None:
        tau[k] = observer.tau
        ez = observer.Z - (x @ T)[:, None, :]  # (B, N, n) error in z coordinates
        sub[k] = np.sqrt((ez ** 2) @ onehot)
        errors[k] = np.linalg.norm(ez, axis=-1)  # T orthogonal: same norm in x
        xn[k] = np.linalg.norm(x, axis=-1)

    record(0)
    ones = np.ones((B, N), dtype=bool)
    for k in range(K):
        y = plant.measure(x, noise_rng)
        adj, tx, arr = graphs[:, k], ones, ones
        if hook is not None:
            y, adj, tx, arr = hook(k, x, y, adj, tx, arr)
        observer.step(y, adj, transmit=tx, arrived=arr)
        messages[k] = (adj & tx[:, None, :]).sum((-1, -2))
        src = getattr(observer, "last_source", None)
        if src is not None:
            adoptions[k] = (src != own).sum((-1, -2))
        x = plant.step(x, noise_rng)
        record(k + 1)
    alive = np.ones(N, dtype=bool) if alive is None else np.asarray(alive, dtype=bool)
    return Trajectory(tau, errors, sub, xn, messages, adoptions, alive)


def relative_error(traj: Trajectory) -> np.ndarray:
    """``max_i ||x_hat_i[k] - x[k]|| / ||x[k]||`` over the alive agents, ``(K+1, B)``."""
    err = traj.errors[:, :, traj.alive].max(-1)
    return err / np.maximum(traj.state_norm, np.finfo(float).tiny)


def steps_to_tolerance(rel_err: np.ndarray, eps: float) -> np.ndarray:
    """First step from which ``rel_err`` stays below ``eps`` to the end, ``(B,)`` int.

    ``-1`` if it is not below ``eps`` at the last step. Compare with
    :func:`netsense.graphs.bounds.corollary1_bound` (deadbeat gains) or
    :func:`netsense.graphs.bounds.theorem1_onset`.
    """
    if eps <= 0:
        raise ValueError(f"eps must be > 0, got {eps}")
    bad = ~(rel_err < eps)  # NaN counts as bad
    K1 = bad.shape[0]
    last_bad = np.where(bad.any(0), K1 - 1 - np.argmax(bad[::-1], axis=0), -1)
    return np.where(bad[-1], -1, last_bad + 1)
