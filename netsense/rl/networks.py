"""Training pipeline, stage *networks*: the MLP actor and the critics.

Every network reads the flat per-agent observation of
:class:`netsense.engine.model.ObsLayout`; actors write flat logits in the core's action
layout (``core.nvec``, read by :class:`netsense.rl.distributions.MaskedMultiCategorical`).

=======================  ===================================================================
network                  what it is
=======================  ===================================================================
:func:`mlp_actor_net`    TorchRL ``MultiAgentMLP`` (parameters shared by the agents,
                         decentralised): observation -> flat logits; any action layout
:func:`critic_net`       ``"local"`` (IPPO: ``V_i(o_i)``), ``"state"`` (MAPPO: ``V_i(o_i,
                         s)`` with the global state ``s``), ``"joint"`` (MAPPO as in
                         TorchRL's tutorial: ``MultiAgentMLP(centralised=True)`` over all
                         observations, one value for the team)
=======================  ===================================================================

The permutation-invariant actor is :class:`netsense.rl.set_network.SetPolicyNet`.

Imports: torch, TorchRL and :mod:`netsense.engine.model` (no other stage).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from netsense.engine.model import ObsLayout

__all__ = ["CRITICS", "critic_net", "mlp_actor_net"]

def mlp_actor_net(layout: ObsLayout, nvec: Sequence[int], n_agents: int, *,
                  hidden: Sequence[int] = (64, 64), device=None) -> nn.Module:
    """TorchRL ``MultiAgentMLP``: ``(..., N, obs_dim) -> (..., N, sum(nvec))`` logits,
    one set of parameters for every agent (``share_params=True``, decentralised)."""
    from torchrl.modules import MultiAgentMLP

    return MultiAgentMLP(n_agent_inputs=layout.size, n_agent_outputs=int(sum(nvec)),
                         n_agents=n_agents, centralised=False, share_params=True,
                         depth=len(hidden), num_cells=list(hidden), activation_class=nn.Tanh,
                         device=device)


class _StateCritic(nn.Module):
    """``V_i(o_i, s)``: the global state embedded once per member, then one MLP shared by
    the agents over ``[o_i, emb(s)]`` (the state is not copied ``N`` times into a wide
    first layer)."""

    def __init__(self, obs_dim: int, state_dim: int, hidden: Sequence[int],
                 device=None) -> None:
        super().__init__()
        h = list(hidden)
        self.state_enc = nn.Sequential(nn.Linear(state_dim, h[0], device=device), nn.Tanh())
        layers: list[nn.Module] = []
        width = obs_dim + h[0]
        for w in h:
            layers += [nn.Linear(width, w, device=device), nn.Tanh()]
            width = w
        self.agent = nn.Sequential(*layers, nn.Linear(width, 1, device=device))

    def forward(self, obs: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        s = self.state_enc(state).unsqueeze(-2).expand(*obs.shape[:-1], -1)
        return self.agent(torch.cat([obs, s], -1))


CRITICS = ("local", "state", "joint")


def critic_net(kind: str, obs_dim: int, state_dim: int, n_agents: int, *,
               hidden: Sequence[int] = (128, 128), device=None) -> tuple[nn.Module, list]:
    """A value network and the input keys it reads.

    Returns
    -------
    (module, in_keys)
        ``module(*inputs) -> (..., N, 1)`` values; ``in_keys`` nested keys of the env.
    """
    from torchrl.modules import MultiAgentMLP

    obs_key, state_key = ("agents", "observation"), "state"
    if kind == "local":
        net = MultiAgentMLP(n_agent_inputs=obs_dim, n_agent_outputs=1, n_agents=n_agents,
                            centralised=False, share_params=True, depth=len(hidden),
                            num_cells=list(hidden), activation_class=nn.Tanh, device=device)
        return net, [obs_key]
    if kind == "joint":
        net = MultiAgentMLP(n_agent_inputs=obs_dim, n_agent_outputs=1, n_agents=n_agents,
                            centralised=True, share_params=True, depth=len(hidden),
                            num_cells=list(hidden), activation_class=nn.Tanh, device=device)
        return net, [obs_key]
    if kind == "state":
        return _StateCritic(obs_dim, state_dim, hidden, device), [obs_key, state_key]
    raise ValueError(f"critic must be one of {CRITICS}, got {kind!r}")
