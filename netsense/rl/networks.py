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

__all__ = ["ACTIVATIONS", "CRITICS", "activation_class", "critic_net", "mlp_actor_net"]

#: Hidden-layer activations the networks take (``PPOConfig.activation``).
ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU}


def activation_class(name: str) -> type[nn.Module]:
    if name not in ACTIVATIONS:
        raise ValueError(f"activation must be one of {tuple(ACTIVATIONS)}, got {name!r}")
    return ACTIVATIONS[name]


def mlp_actor_net(layout: ObsLayout, nvec: Sequence[int], n_agents: int, *,
                  hidden: Sequence[int] = (64, 64), activation: str = "tanh",
                  extra_inputs: int = 0, device=None) -> nn.Module:
    """TorchRL ``MultiAgentMLP``: ``(..., N, obs_dim + extra_inputs) -> (..., N,
    sum(nvec))`` logits, one set of parameters for every agent (``share_params=True``,
    decentralised)."""
    from torchrl.modules import MultiAgentMLP

    return MultiAgentMLP(n_agent_inputs=layout.size + int(extra_inputs),
                         n_agent_outputs=int(sum(nvec)),
                         n_agents=n_agents, centralised=False, share_params=True,
                         depth=len(hidden), num_cells=list(hidden),
                         activation_class=activation_class(activation), device=device)


class _StateCritic(nn.Module):
    """``V_i(o_i, s)``: the global state embedded once per member, then one MLP shared by
    the agents over ``[o_i, emb(s)]`` (the state is not copied ``N`` times into a wide
    first layer)."""

    def __init__(self, obs_dim: int, state_dim: int, hidden: Sequence[int],
                 act: type[nn.Module] = nn.Tanh, device=None) -> None:
        super().__init__()
        h = list(hidden)
        self.state_enc = nn.Sequential(nn.Linear(state_dim, h[0], device=device), act())
        layers: list[nn.Module] = []
        width = obs_dim + h[0]
        for w in h:
            layers += [nn.Linear(width, w, device=device), act()]
            width = w
        self.agent = nn.Sequential(*layers, nn.Linear(width, 1, device=device))

    def forward(self, obs: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        s = self.state_enc(state).unsqueeze(-2).expand(*obs.shape[:-1], -1)
        return self.agent(torch.cat([obs, s], -1))


class _TeamCritic(nn.Module):
    """``V(s)``: one value per member from the global state, the same for every agent
    (a team reward gives every agent the same return); ``N`` times cheaper than a
    per-agent critic."""

    def __init__(self, state_dim: int, n_agents: int, hidden: Sequence[int],
                 act: type[nn.Module] = nn.Tanh, device=None) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        width = state_dim
        for w in hidden:
            layers += [nn.Linear(width, w, device=device), act()]
            width = w
        self.net = nn.Sequential(*layers, nn.Linear(width, 1, device=device))
        self.n_agents = int(n_agents)

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        v = self.net(state).unsqueeze(-2)  # (..., 1, 1)
        return v.expand(*state.shape[:-1], self.n_agents, 1)


#: ``team`` needs a reward that every agent shares (``PPOConfig`` checks it).
CRITICS = ("team", "state", "joint", "local")


def critic_net(kind: str, obs_dim: int, state_dim: int, n_agents: int, *,
               hidden: Sequence[int] = (128, 128), activation: str = "tanh",
               device=None) -> tuple[nn.Module, list]:
    """A value network and the input keys it reads.

    ``kind``: ``"team"`` (MAPPO, ``V(s)`` of the global state once per member),
    ``"state"`` (MAPPO, ``V_i(o_i, s)``), ``"joint"`` (MAPPO, TorchRL's centralised
    ``MultiAgentMLP`` over all observations), ``"local"`` (IPPO, ``V_i(o_i)``).

    Returns
    -------
    (module, in_keys)
        ``module(*inputs) -> (..., N, 1)`` values; ``in_keys`` nested keys of the env.
    """
    from torchrl.modules import MultiAgentMLP

    act = activation_class(activation)
    obs_key, state_key = ("agents", "observation"), "state"
    if kind in ("local", "joint"):
        net = MultiAgentMLP(n_agent_inputs=obs_dim, n_agent_outputs=1, n_agents=n_agents,
                            centralised=kind == "joint", share_params=True, depth=len(hidden),
                            num_cells=list(hidden), activation_class=act, device=device)
        return net, [obs_key]
    if kind == "state":
        return _StateCritic(obs_dim, state_dim, hidden, act, device), [obs_key, state_key]
    if kind == "team":
        return _TeamCritic(state_dim, n_agents, hidden, act, device), [state_key]
    raise ValueError(f"critic must be one of {CRITICS}, got {kind!r}")
