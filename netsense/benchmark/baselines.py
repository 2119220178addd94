"""Scripted policies' returns on a training scenario: the reference lines of a training curve."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from netsense.benchmark.rollouts import NotApplicable, rollout

if TYPE_CHECKING:  # pragma: no cover
    from netsense.rl.sb3 import TrainConfig

__all__ = ["baseline_returns"]


def baseline_returns(config: TrainConfig, policies: tuple[str, ...] = ("freshness",),
                     episodes: int = 5) -> dict[str, float]:
    """Mean episode return per agent of scripted policies on the training scenario.

    Same scenario and overrides as the training run (seeds ``10_000 + e``), so the
    numbers sit on the training curve's axis. Policies that do not apply to the scenario
    (e.g. an adoption rule on a communication-only scenario) are left out.
    """
    out = {}
    for name in policies:
        try:
            rets = [np.mean(np.sum(rollout(config.scenario, name, 10_000 + e,
                                           config.overrides).rewards, axis=0))
                    for e in range(episodes)]
        except NotApplicable:
            continue
        out[name] = float(np.mean(rets))
    return out
