"""A transmit-only control mode as a thin wrapper of the core (a stand-in, replaceable).

:class:`FreshnessAdoptionCore` fixes the adoption to the freshness rule
(:class:`netsense.env.policies.FreshnessPolicy`, eqs. (8)-(14)) and leaves the agent one
decision per step: transmit at the next step or not. It has the array API of
:class:`netsense.engine.core.BatchedCore` that :mod:`netsense.rl.torchrl_batched` reads
(``B, N, M, D, layout, nvec, mask_size, reset, step, observe`` and the state arrays), with
``nvec = [2]``, actions ``(B, N, 1)`` and masks ``(B, N, 2)`` (the transmit block of the
core's flat mask), and reports the freshness adoptions through ``adopted_slots`` for the
counterfactual reward (:mod:`netsense.rl.credit`).

This exists only to measure and exercise the learner on a communication-only task before
the core has its own communication-only control mode; when it does, pass that core instead
(nothing in :mod:`netsense.rl` depends on this class).
"""

from __future__ import annotations

import numpy as np

from netsense.engine.core import BatchedCore, StepResult
from netsense.env.policies import FreshnessPolicy

__all__ = ["FreshnessAdoptionCore"]


class FreshnessAdoptionCore:
    """Freshness adopts, the learner transmits (see the module docstring).

    Parameters
    ----------
    core : BatchedCore
        The full-control core to drive.
    """

    def __init__(self, core: BatchedCore) -> None:
        if not isinstance(core, BatchedCore):
            raise ValueError("core must be a BatchedCore")
        self.core = core
        self.fusion = FreshnessPolicy(core.layout)
        self.nvec = np.array([2], dtype=np.int64)
        self.mask_size = 2
        self._full: np.ndarray | None = None  # full actions of the pending step

    def __getattr__(self, name: str):  # B, N, M, D, layout, x, Z, nbr, errors, ...
        if name == "core":
            raise AttributeError(name)
        return getattr(self.core, name)

    def reset(self, seed=None, members=None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`BatchedCore.reset`, with the transmit block of the mask."""
        obs, mask = self.core.reset(seed, members)
        self._full = None
        return obs, mask[..., -2:]

    def observe(self) -> tuple[np.ndarray, np.ndarray]:
        """Observations and transmit masks of the current step."""
        obs, mask = self.core.observe()
        return obs, mask[..., -2:]

    def action_mask(self) -> np.ndarray:
        """``(B, N, 2)`` int8 transmit mask."""
        return self.core.action_mask()[..., -2:]

    def full_actions(self, actions) -> np.ndarray:
        """``(B, N, M + 1)``: the freshness adoptions with the given transmit bits."""
        a = np.asarray(actions)
        B, N = self.core.B, self.core.N
        if a.shape != (B, N, 1):
            raise ValueError(f"actions must have shape (B, N, 1) = {(B, N, 1)}, got {a.shape}")
        obs, mask = self.core.observe()
        full = self.fusion.act(obs, mask)
        full[..., -1] = a[..., 0]
        self._full = full
        return full

    def adopted_slots(self, actions) -> np.ndarray:
        """``(B, N, M)``: the slot freshness adopts per substate (``-1``: keep)."""
        a = self.full_actions(actions)[..., :self.core.M]
        return np.where((a >= 1) & (a <= self.core.D), a - 1, -1)

    def step(self, actions, *, observe: bool = True) -> StepResult:
        """One core step with freshness adoptions and the learner's transmit bits."""
        full = self.full_actions(actions)
        out = self.core.step(full, observe=observe)
        mask = None if out.action_mask is None else out.action_mask[..., -2:]
        return out._replace(action_mask=mask)
