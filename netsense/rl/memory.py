"""Training pipeline, stage *networks*: recurrent actors (memory over an agent's own history).

A communication policy often needs more than the current observation: whether its last
messages got through, how long the estimates have been converging, what it sent recently.
:class:`RecurrentActor` gives the MLP actor a GRU over the agent's own observation
sequence (decentralised: one hidden state per agent, parameters shared by the agents);
:class:`netsense.rl.set_network.SetPolicyNet` takes the same memory (``memory=m``) on its
agent embedding. The hidden state of agent ``i`` in member ``b`` starts at zero at every
episode start (``first``) and is carried across steps within the episode, also through the
partial resets of the batched core (only the restarted members are zeroed).

Contract of a recurrent actor ``net`` (``net.memory > 0``):

* ``net(obs (..., N, O), h (..., N, m)) -> (logits (..., N, K), h' (..., N, m))``;
* :func:`unroll` runs it over a sequence with resets, for the PPO update, with gradients
  through the whole sequence (truncated at the start of the rollout, whose hidden state
  was recorded during collection).

Imports: torch only (no other stage).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

__all__ = ["RecurrentActor", "is_recurrent", "unroll"]


def is_recurrent(net: nn.Module) -> bool:
    """Whether ``net`` follows the recurrent contract of this module."""
    return int(getattr(net, "memory", 0) or 0) > 0


class RecurrentActor(nn.Module):
    """``obs -> MLP (tanh) -> GRU cell -> linear logits``, shared by the agents.

    Parameters
    ----------
    obs_dim : int
        Length of the flat per-agent observation.
    n_out : int
        Logits per agent (``sum(nvec)``).
    hidden : sequence of int
        Widths of the MLP encoder's layers.
    memory : int
        Size ``m`` of the GRU's hidden state.
    act : module class
        Activation of the encoder's layers.
    """

    def __init__(self, obs_dim: int, n_out: int, hidden: Sequence[int] = (64, 64),
                 memory: int = 64, act: type[nn.Module] = nn.Tanh, device=None) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        width = int(obs_dim)
        for w in hidden:
            layers += [nn.Linear(width, int(w), device=device), act()]
            width = int(w)
        self.encoder = nn.Sequential(*layers)
        self.memory = int(memory)
        self.gru = nn.GRUCell(width, self.memory, device=device)
        self.head = nn.Linear(self.memory, int(n_out), device=device)

    def forward(self, obs: torch.Tensor, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        lead = obs.shape[:-1]
        e = self.encoder(obs).reshape(-1, self.gru.input_size)
        h_new = self.gru(e, h.reshape(-1, self.memory)).reshape(*lead, self.memory)
        return self.head(h_new), h_new


def unroll(net: nn.Module, obs: torch.Tensor, h0: torch.Tensor,
           first: torch.Tensor) -> torch.Tensor:
    """Logits of a recurrent actor over a sequence, with resets.

    Parameters
    ----------
    net : recurrent actor (:func:`is_recurrent`)
    obs : (S, T, N, O) tensor
        ``S`` sequences of ``T`` steps (batch first).
    h0 : (S, N, m) tensor
        Hidden state before the first step.
    first : (S, T) bool tensor
        ``True`` where step ``t`` starts an episode: the hidden state is zeroed before it.

    Returns
    -------
    (S, T, N, K) tensor
    """
    h = h0
    keep = (~first).to(obs.dtype)[..., None, None]  # (S, T, 1, 1)
    out = []
    for t in range(obs.shape[1]):
        logits, h = net(obs[:, t], h * keep[:, t])
        out.append(logits)
    return torch.stack(out, 1)
