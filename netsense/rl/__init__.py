"""Adapters from netsense's PettingZoo environment to maintained RL libraries.

Each adapter is a submodule with its own optional extra; importing :mod:`netsense.rl`
imports none of them (nor torch):

===============================  ======================================================  ==========
module                           what                                                    extra
===============================  ======================================================  ==========
``netsense.rl.wrappers``         flat observations with the action mask appended         (core)
``netsense.rl.sb3``              SuperSuit + MaskablePPO, ``train`` / ``LearnedPolicy``  ``rl``
``netsense.rl.rllib``            RLlib multi-agent PPO, one shared masked policy         ``rllib``
``netsense.rl.torchrl``          TorchRL ``PettingZooWrapper`` (the BenchMARL path)      ``torchrl``
``netsense.rl.credit``           team / per-agent / counterfactual sender rewards        (core)
``netsense.rl.torchrl_batched``  TorchRL ``EnvBase`` over ``BatchedCore``                ``torchrl``
``netsense.rl.models``           masked distribution, MLP / set policies, critics        ``torchrl``
``netsense.rl.mappo``            batched MAPPO / IPPO, BC warm start                     ``torchrl``
===============================  ======================================================  ==========

Tool layer. May import every layer up to :mod:`netsense.env`, and :mod:`netsense.grid`.
"""

__all__ = ["credit", "mappo", "models", "rllib", "sb3", "torchrl", "torchrl_batched",
           "wrappers"]
