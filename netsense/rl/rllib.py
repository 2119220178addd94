"""Ray RLlib adapter: multi-agent PPO with one shared, action-masked policy.

RLlib's new API stack runs the PettingZoo parallel env through
``ray.rllib.env.wrappers.pettingzoo_env.ParallelPettingZooEnv``; every ``sensor_i`` maps
to the policy ``"shared"`` (parameter sharing). Masks reach the policy through RLlib's
``ActionMaskingTorchRLModule`` (shipped in ``ray.rllib.examples``), which adds
``log(mask)`` to the action logits: for ``MultiDiscrete`` actions the logits are the
concatenation over action dimensions, exactly the layout of netsense's flat mask, so
the module works unchanged. :class:`RLlibMaskedObs` only renames the observation keys
to what that module reads (``"observations"``, ``"action_mask"`` as float).

Local use::

    from netsense.rl.rllib import ppo_config
    algo = ppo_config("fig1_scalar-v0").build_algo()
    result = algo.train()

On a cluster, start Ray (``ray start --head`` on the head node, ``ray start
--address=HEAD:6379`` on the workers), then run the same script on the head node with
``ray.init(address="auto")`` (``experiments/rl/rllib_example.py --address auto``) and raise
``num_env_runners`` to the number of worker CPUs you want sampling. Needs the ``rllib``
extra (``pip install torch==2.13.0 && pip install -e ".[rllib]"``).
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from pettingzoo.utils.env import ParallelEnv

ENV_NAME = "netsense"
POLICY_ID = "shared"


class RLlibMaskedObs(ParallelEnv):
    """Observations as ``{"observations": Box, "action_mask": Box(0, 1)}`` (RLlib's keys).

    Parameters
    ----------
    env : netsense.env.pettingzoo_env.NetSenseEnv
        Built with the default ``action_mask_in="observation"``.
    """

    def __init__(self, env: ParallelEnv) -> None:
        self.env = env
        self.possible_agents = list(env.possible_agents)
        self.agents = list(env.agents)
        self.metadata = dict(env.metadata)
        self.render_mode = env.render_mode
        inner = env.observation_space(self.possible_agents[0])
        if not isinstance(inner, gymnasium.spaces.Dict) or "action_mask" not in inner.spaces:
            raise ValueError("RLlibMaskedObs needs Dict observations with an 'action_mask' "
                             "(netsense.make(..., action_mask_in='observation'))")
        m = int(np.prod(inner["action_mask"].shape))
        self._space = gymnasium.spaces.Dict({
            "observations": inner["observation"],
            "action_mask": gymnasium.spaces.Box(0.0, 1.0, (m,), np.float32),
        })

    def observation_space(self, agent: str) -> gymnasium.Space:
        """The renamed ``Dict`` space (same for every agent)."""
        return self._space

    def action_space(self, agent: str) -> gymnasium.Space:
        """The wrapped env's ``MultiDiscrete`` space."""
        return self.env.action_space(agent)

    @staticmethod
    def _convert(obs: dict) -> dict:
        return {a: {"observations": o["observation"],
                    "action_mask": np.asarray(o["action_mask"], dtype=np.float32)}
                for a, o in obs.items()}

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset the wrapped env."""
        obs, infos = self.env.reset(seed=seed, options=options)
        self.agents = list(self.env.agents)
        return self._convert(obs), infos

    def step(self, actions: dict):
        """Step the wrapped env (actions are checked against the masks there)."""
        obs, rew, term, trunc, infos = self.env.step(
            {a: np.asarray(v, dtype=np.int64) for a, v in actions.items()})
        self.agents = list(self.env.agents)
        return self._convert(obs), rew, term, trunc, infos

    def render(self):
        """Render the wrapped env."""
        return self.env.render()

    def close(self) -> None:
        """Close the wrapped env."""
        self.env.close()

    def state(self) -> np.ndarray:
        """The wrapped env's global state."""
        return self.env.state()

    @property
    def unwrapped(self) -> ParallelEnv:
        """The netsense environment."""
        return self.env


def env_creator(env_config: dict[str, Any]):
    """RLlib env factory: ``{"scenario": id, "overrides": {...}}`` -> MultiAgentEnv."""
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    from netsense.env.registry import make

    cfg = dict(env_config)
    scenario = cfg.get("scenario")
    if not scenario:
        raise ValueError("env_config needs 'scenario' (a netsense scenario id)")
    env = make(scenario, **dict(cfg.get("overrides") or {}))
    return ParallelPettingZooEnv(RLlibMaskedObs(env))


def register(name: str = ENV_NAME) -> str:
    """Register :func:`env_creator` with Ray's registry under ``name``."""
    from ray.tune.registry import register_env

    register_env(name, env_creator)
    return name


def ppo_config(scenario: str, *, overrides: dict | None = None, num_env_runners: int = 0,
               train_batch_size: int = 2000, minibatch_size: int = 256, num_epochs: int = 5,
               lr: float = 3e-4, gamma: float = 0.95, hidden: tuple[int, ...] = (64, 64),
               seed: int | None = 0):
    """``PPOConfig`` for ``scenario``: one shared masked policy for every agent.

    Parameters
    ----------
    scenario : str
        netsense scenario id.
    overrides : dict, optional
        Keyword overrides for ``netsense.make``.
    num_env_runners : int
        Sampling workers (0 = sample in the driver, as in the smoke test).
    train_batch_size, minibatch_size, num_epochs, lr, gamma : PPO settings
        ``train_batch_size`` counts agent-steps.
    hidden : tuple of int
        Hidden layers of the policy/value MLPs.
    seed : int, optional
        Seed of the RLlib run.
    """
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec
    from ray.rllib.examples.rl_modules.classes.action_masking_rlm import (
        ActionMaskingTorchRLModule,
    )

    name = register()
    module = RLModuleSpec(module_class=ActionMaskingTorchRLModule,
                          model_config={"fcnet_hiddens": list(hidden),
                                        "head_fcnet_hiddens": []})
    return (
        PPOConfig()
        # RLlib's env pre-check steps unmasked random actions, which netsense rejects.
        .environment(name, env_config={"scenario": scenario, "overrides": overrides or {}},
                     disable_env_checking=True)
        .framework("torch")
        .env_runners(num_env_runners=num_env_runners)
        .multi_agent(policies={POLICY_ID},
                     policy_mapping_fn=lambda agent_id, episode, **kw: POLICY_ID)
        .rl_module(rl_module_spec=MultiRLModuleSpec(rl_module_specs={POLICY_ID: module}))
        .training(train_batch_size_per_learner=train_batch_size,
                  minibatch_size=minibatch_size, num_epochs=num_epochs, lr=lr, gamma=gamma)
        .debugging(seed=seed)
    )


def train(config, iterations: int = 1) -> list[dict]:
    """Build the algorithm from ``config`` and run ``iterations`` training iterations.

    Returns one summary dict per iteration (``iteration``, ``env_steps``,
    ``episode_return_mean``).
    """
    algo = config.build_algo()
    out = []
    try:
        for it in range(iterations):
            res = algo.train()
            runners = res.get("env_runners", {})
            out.append({"iteration": it + 1,
                        "env_steps": runners.get("num_env_steps_sampled_lifetime"),
                        "episode_return_mean": runners.get("episode_return_mean")})
    finally:
        algo.stop()
    return out
