"""Records of the benchmark: one episode's per-step curves and the job that makes them.

:class:`EpisodeRecorder` builds the :class:`EpisodeRecord` of every path (the PettingZoo
episode, the batched runs of :func:`netsense.benchmark.batched.rollout_seeds` and the oracle);
:class:`Job` names one episode to run.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

_FLOOR = 1e-3


def relative_errors(errors: np.ndarray, x_norm: np.ndarray, floor: float = _FLOOR
                    ) -> np.ndarray:
    """Relative errors ``errors[k, i] / max(x_norm[k], floor)``.

    Parameters
    ----------
    errors : (K + 1, N) array
    x_norm : (K + 1,) array
    floor : float
        Lower bound of the denominator (a state at the origin).
    """
    errors = np.asarray(errors, dtype=float)
    x_norm = np.asarray(x_norm, dtype=float)
    if errors.ndim != 2 or x_norm.shape != errors.shape[:1]:
        raise ValueError(f"errors must be (K+1, N) and x_norm (K+1,), got {errors.shape} "
                         f"and {x_norm.shape}")
    return errors / np.maximum(x_norm, floor)[:, None]


@dataclass
class EpisodeRecord:
    """Per-step curves of one episode.

    Attributes
    ----------
    errors : (K + 1, N) array
        ``||x_hat_i[k] - x[k]||`` for ``k = 0..K`` (the oracle has ``N = 1``).
    x_norm : (K + 1,) array
        ``||x[k]||``.
    messages : (K, N) bool array or None
        Whether agent ``i`` transmitted at step ``k`` (None for the oracle).
    aoi : (K + 1, N, M) int array or None
        Freshness indices ``tau_i^{(j)}[k]``, ``-1`` for omega (None when not tracked);
        ``M = N`` or, with ``substates = "sources"``, one column per source.
    rewards : (K, N) array or None
        Per-agent rewards (None for the oracle).
    floor : float
        Smallest ``||x||`` used to normalise (the scenario's ``reward.error_floor``).
    own : (N,) int array or None
        Column of ``aoi`` holding agent ``i``'s own substate (``-1``: none); None means
        the diagonal (``M = N``).
    """

    errors: np.ndarray
    x_norm: np.ndarray
    messages: np.ndarray | None = None
    aoi: np.ndarray | None = None
    rewards: np.ndarray | None = None
    floor: float = 1e-3
    own: np.ndarray | None = None

    def relative_errors(self) -> np.ndarray:
        """``e_i[k]``, ``(K + 1, N)``: errors over ``max(||x[k]||, floor)``."""
        return relative_errors(self.errors, self.x_norm, self.floor)


class EpisodeRecorder:
    """Collects the curves of :class:`EpisodeRecord` from a core's ``B`` members.

    One recorder serves the single episode through the PettingZoo env (``B = 1``, its
    ``env.core``), the batched runs of :func:`~netsense.benchmark.batched.rollout_seeds`
    and both forms
    of the oracle, so every path builds its records the same way.

    Parameters
    ----------
    floor : float
        The scenario's ``reward.error_floor`` (:attr:`EpisodeRecord.floor`).
    network : bool
        Record freshness indices, transmissions and rewards (False for the oracle).
    """

    def __init__(self, floor: float, *, network: bool = True) -> None:
        self.floor = float(floor)
        self.network = bool(network)
        self._errs: list[np.ndarray] = []
        self._xn: list[np.ndarray] = []
        self._aoi: list[np.ndarray] = []
        self._msgs: list[np.ndarray] = []
        self._rews: list[np.ndarray] = []
        self._own: np.ndarray | None = None

    def state(self, core, estimates: np.ndarray | None = None) -> None:
        """Record step ``k``: ``||x_hat_i - x||``, ``||x||`` and (network) ``tau``.

        Parameters
        ----------
        core : netsense.engine.core.BatchedCore
        estimates : (B, N', n) array, optional
            Estimates to score (default the agents' ``core.estimates``; the oracle passes
            its own, ``N' = 1``).
        """
        x = core.x
        est = core.estimates if estimates is None else estimates
        self._errs.append(np.linalg.norm(est - x[:, None, :], axis=-1))
        self._xn.append(np.linalg.norm(x, axis=-1))
        if self.network:
            self._aoi.append(core.tau.copy())
            self._own = core.own

    def step(self, transmit: np.ndarray, reward: np.ndarray | Sequence) -> None:
        """Record the transmissions ``(B, N)`` and rewards ``(B, N)`` of the last step."""
        self._msgs.append(np.array(transmit, dtype=bool))
        self._rews.append(np.array(reward, dtype=float))

    def records(self, end: Sequence[int] | None = None) -> list[EpisodeRecord]:
        """One record per member, member ``b`` cut after its last step ``end[b]``.

        Parameters
        ----------
        end : sequence of B ints, optional
            The step at which each member's episode ended (default: the last recorded).
        """
        E, X = np.stack(self._errs, 1), np.stack(self._xn, 1)
        B, K = E.shape[0], E.shape[1] - 1
        end = np.full(B, K) if end is None else np.asarray(end, dtype=np.int64)
        if end.shape != (B,) or end.min() < 0 or end.max() > K:
            raise ValueError(f"end must hold {B} steps in 0..{K}, got {end.tolist()}")
        if not self.network:
            return [EpisodeRecord(E[b, : end[b] + 1], X[b, : end[b] + 1], floor=self.floor)
                    for b in range(B)]
        A, M, R = np.stack(self._aoi, 1), np.stack(self._msgs, 1), np.stack(self._rews, 1)
        own = None if self._own.shape[0] == A.shape[-1] and np.array_equal(
            self._own, np.arange(A.shape[-1])) else self._own
        return [EpisodeRecord(E[b, : end[b] + 1], X[b, : end[b] + 1], M[b, : end[b]],
                              A[b, : end[b] + 1], R[b, : end[b]], floor=self.floor, own=own)
                for b in range(B)]


@dataclass(frozen=True)
class Job:
    """One episode to run.

    Parameters
    ----------
    scenario : str
        Scenario id (``netsense.list_scenarios()``).
    policy : str
        Policy name (see the module docstring).
    seed : int
        ``reset(seed=...)`` of the environment.
    overrides : dict
        Keyword overrides passed to ``netsense.make``.
    eps : float
        Threshold of ``steps_to_eps``.
    """

    scenario: str
    policy: str
    seed: int
    overrides: dict = field(default_factory=dict)
    eps: float = 1e-2

