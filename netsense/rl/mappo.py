"""Former home of the batched trainer; its names now live in the pipeline's stages.

Kept so that ``from netsense.rl.mappo import PPOConfig, train_ppo, load_policy`` keeps
working (the CHANGELOG lists where each name went). New code imports from the stage:
:mod:`netsense.rl.config`, :mod:`netsense.rl.policy`, :mod:`netsense.rl.scripted`,
:mod:`netsense.rl.cloning`, :mod:`netsense.rl.evaluation`, :mod:`netsense.rl.checkpoint`,
:mod:`netsense.rl.ppo`.

Imports: the stages it re-exports (it is above all of them).
"""

from __future__ import annotations

from netsense.rl.checkpoint import (
    BatchedPolicy,
    load_policy,
    policy_config,
    policy_control,
    read_policy,
)
from netsense.rl.cloning import behaviour_clone
from netsense.rl.config import ALGOS, NETWORKS, PPOConfig, training_seeds
from netsense.rl.evaluation import evaluate
from netsense.rl.policy import actor_net, build_actor
from netsense.rl.ppo import train_ppo
from netsense.rl.scripted import scripted_actions

__all__ = ["ALGOS", "NETWORKS", "BatchedPolicy", "PPOConfig", "actor_net", "behaviour_clone",
           "build_actor", "evaluate", "load_policy", "policy_config", "policy_control",
           "read_policy", "scripted_actions", "train_ppo", "training_seeds"]
