"""Training pipeline, stage *modules*: actor and critic modules built from a config.

:func:`actor_net` picks the logits network (:func:`netsense.rl.networks.mlp_actor_net` or
:class:`netsense.rl.set_network.SetPolicyNet`), :func:`build_actor` wraps it in TorchRL's
``ProbabilisticActor`` over :class:`netsense.rl.distributions.MaskedMultiCategorical`
(parameters shared by all agents), :func:`critic_module` the critic of the config.

Imports: TorchRL, the stages below (envs, distributions, networks, set network, config).
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule
from torchrl.envs.utils import ExplorationType
from torchrl.modules import ProbabilisticActor

from netsense.rl.config import PPOConfig
from netsense.rl.distributions import MaskedMultiCategorical
from netsense.rl.envs import NetSenseBatchedEnv
from netsense.rl.networks import critic_net, mlp_actor_net
from netsense.rl.set_network import SetPolicyNet

__all__ = ["actor_net", "build_actor", "critic_module"]


def actor_net(config: PPOConfig, core, device=None) -> torch.nn.Module:
    """The actor's logits network for ``core``'s layout and action layout."""
    if config.network == "set":
        return SetPolicyNet(core.layout, core.nvec, hidden=config.set_hidden).to(device)
    return mlp_actor_net(core.layout, core.nvec, core.N, hidden=config.hidden, device=device)


def build_actor(net: torch.nn.Module, nvec) -> ProbabilisticActor:
    """``ProbabilisticActor``: logits from ``net``, masked by ``("agents", "action_mask")``."""
    module = TensorDictModule(net, in_keys=[("agents", "observation")],
                              out_keys=[("agents", "logits")])
    return ProbabilisticActor(
        module, in_keys={"logits": ("agents", "logits"), "mask": ("agents", "action_mask")},
        out_keys=[("agents", "action")], distribution_class=MaskedMultiCategorical,
        distribution_kwargs={"nvec": tuple(int(v) for v in nvec)}, return_log_prob=True,
        log_prob_key=("agents", "action_log_prob"),
        default_interaction_type=ExplorationType.RANDOM)


def critic_module(config: PPOConfig, env: NetSenseBatchedEnv, device) -> TensorDictModule:
    """The critic of ``config`` as a ``TensorDictModule`` writing ``("agents", "state_value")``."""
    net, keys = critic_net(config.critic_kind, env.layout.size, env.state_dim, env.n_agents,
                           hidden=config.critic_hidden, device=device)
    return TensorDictModule(net, in_keys=keys, out_keys=[("agents", "state_value")])
