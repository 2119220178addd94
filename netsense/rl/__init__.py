"""Adapters from netsense's PettingZoo environment to maintained RL libraries.

Each adapter is a submodule with its own optional extra; importing :mod:`netsense.rl`
imports none of them (nor torch):

======================  =====================================================  ==========
module                  what                                                   extra
======================  =====================================================  ==========
``netsense.rl.wrappers``  flat observations with the action mask appended       (core)
``netsense.rl.sb3``       SuperSuit vector env + MaskablePPO, shared policy,     ``rl``
                          ``train`` / ``LearnedPolicy``
``netsense.rl.rllib``     RLlib multi-agent PPO, one shared masked policy        ``rllib``
``netsense.rl.torchrl``   TorchRL ``PettingZooWrapper`` (the BenchMARL path)     ``torchrl``
======================  =====================================================  ==========

Tool layer. May import every layer up to :mod:`netsense.env`, and :mod:`netsense.grid`.
"""

__all__ = ["rllib", "sb3", "torchrl", "wrappers"]
