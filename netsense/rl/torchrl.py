"""TorchRL adapter: a netsense scenario as a TorchRL ``PettingZooWrapper``.

This is the path BenchMARL takes for PettingZoo tasks. Every agent is in one group
(``"sensor"``, the prefix of ``sensor_i``), the observation is under
``("sensor", "observation", "observation")`` and, with ``use_mask=True``, the flat mask
under ``("sensor", "action_mask")``; TorchRL then masks its ``MultiCategorical`` action
spec, so ``env.rand_action()`` and ``env.rollout()`` only take allowed actions. Needs the
``torchrl`` extra (``pip install torch==2.13.0 && pip install -e ".[torchrl]"``).
"""

from __future__ import annotations

import numpy as np
from pettingzoo import ParallelEnv


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

    env = make(scenario, **overrides)
    nvec = env.core.nvec
    if nvec.size > 1 and (nvec == nvec[0]).all():  # e.g. per-substate bits [2] * M
        env = _MaskGrid(env)
    return PettingZooWrapper(env=env, use_mask=True, categorical_actions=True, seed=seed)


class _MaskGrid(ParallelEnv):
    """The env with its flat action mask as ``(len(nvec), n)``: TorchRL's ``MultiCategorical``
    of a ``MultiDiscrete`` whose sizes are all ``n`` (the per-substate bits of the
    communication-only mode ``"substates"``) takes its mask in that shape; a flat mask is
    kept for mixed sizes (full control)."""

    def __init__(self, env) -> None:
        from gymnasium import spaces

        self.env = env
        self.possible_agents = env.possible_agents
        self.metadata = env.metadata
        self.render_mode = env.render_mode
        nvec = env.core.nvec
        self._shape = (int(nvec.size), int(nvec[0]))
        inner = env.observation_space(env.possible_agents[0])
        self._obs_space = spaces.Dict({"observation": inner["observation"],
                                       "action_mask": spaces.Box(0, 1, self._shape,
                                                                 dtype=np.int8)})

    @property
    def agents(self) -> list[str]:
        return self.env.agents

    def observation_space(self, agent):
        return self._obs_space

    def action_space(self, agent):
        return self.env.action_space(agent)

    def state(self):
        return self.env.state()

    def render(self):
        return self.env.render()

    def close(self) -> None:
        self.env.close()

    def _grid(self, obs: dict) -> dict:
        return {a: {"observation": o["observation"],
                    "action_mask": o["action_mask"].reshape(self._shape)}
                for a, o in obs.items()}

    def reset(self, seed=None, options=None):
        obs, infos = self.env.reset(seed=seed, options=options)
        return self._grid(obs), infos

    def step(self, actions):
        obs, *rest = self.env.step(actions)
        return (self._grid(obs), *rest)

    def __getattr__(self, name):
        if name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)
