"""TorchRL adapter: a netsense scenario as a TorchRL ``PettingZooWrapper``.

This is the path BenchMARL takes for PettingZoo tasks. Every agent is in one group
(``"sensor"``, the prefix of ``sensor_i``), the observation is under
``("sensor", "observation", "observation")`` and, with ``use_mask=True``, the flat mask
under ``("sensor", "action_mask")``; TorchRL then masks its ``MultiCategorical`` action
spec, so ``env.rand_action()`` and ``env.rollout()`` only take allowed actions. Needs the
``torchrl`` extra (``pip install torch==2.13.0 && pip install -e ".[torchrl]"``).
"""

from __future__ import annotations


def make_torchrl_env(scenario: str, *, seed: int | None = 0, **overrides):
    """``PettingZooWrapper`` around ``netsense.make(scenario, **overrides)``.

    Parameters
    ----------
    scenario : str
        Scenario id.
    seed : int, optional
        Seed of the wrapper's first reset.
    **overrides
        Passed to ``netsense.make``.
    """
    from torchrl.envs.libs.pettingzoo import PettingZooWrapper

    from netsense.env.registry import make

    return PettingZooWrapper(env=make(scenario, **overrides), use_mask=True,
                             categorical_actions=True, seed=seed)
