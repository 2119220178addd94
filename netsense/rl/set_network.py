"""Training pipeline, stage *networks*: the permutation-invariant set actor.

:class:`SetPolicyNet` scores message slots as a set (DeepSets): its parameters do not
depend on ``N``, ``D``, ``M`` or ``n``, so one state dict runs at any size of its kind.

Observation tokens of :class:`SetPolicyNet` (all read from the documented layout; none has
a size that depends on ``N``, ``D``, ``M`` or ``n``):

* agent token ``g_i`` (6): ``time``, ``y_arrived``, ``z_lognorm`` and the means over
  substates of ``own_omega``, ``own_age`` and over slots of ``slot_arrived``; in the
  communication-only modes also ``silence``, ``channel_load``, ``collided``, ``agent_id``
  and the mean of ``news`` (11);
* substate token ``u_ij`` (3): ``own_omega[j]``, ``own_age[j]``, ``[j is i's own
  substate]`` (from ``layout.own``); in the communication-only modes also ``news[j]``
  (4);
* pair token ``v_idj`` (5) for slot ``d`` and substate ``j``: ``slot_arrived[d]``,
  ``slot_omega[d, j]``, ``slot_age[d, j]``, ``own_age[j] - slot_age[d, j]`` and
  ``[the message is fresher than the own index]`` (arrived, not omega, and own omega or
  a smaller age). Empty slots and slots whose message did not arrive are padding: they
  are left out of the pooling (padding mask ``slot_arrived``; their adopt choices are
  masked by the environment anyway).

Pairs are embedded by one layer shared over all ``(d, j)`` (with the substate embedding
added), pooled over slots with masked mean and max (DeepSets), and combined with the
substate and agent embeddings; one shared scoring head gives the adopt logit of every
``(substate, slot)`` pair, two heads the keep and average logits of every substate, one
head the two transmit logits from the agent embedding and the substate pool (``"full"``
and ``"transmit"``); in ``"substates"`` one head shared by the substates gives the two
send logits of substate ``j`` from its embedding and the agent's. Parameters do not
depend on the sizes: a state dict trained at one ``N`` loads into a
:class:`SetPolicyNet` built for another layout of the same kind (communication fields or
not).

Imports: torch and :mod:`netsense.engine.model` (no other stage).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from netsense.engine.model import ObsLayout

__all__ = ["ACTION_LAYOUTS", "SetPolicyNet", "action_layout"]

ACTION_LAYOUTS = ("full", "transmit", "substates")


def action_layout(nvec: Sequence[int], layout: ObsLayout) -> str:
    """``"full"`` for ``[D + 2] * M + [2]``, ``"transmit"`` for ``[2]``, ``"substates"``
    for ``[2] * M`` (with ``M > 1``); else ValueError."""
    nv = [int(v) for v in nvec]
    if nv == [layout.D + 2] * layout.M + [2]:
        return "full"
    if nv == [2]:
        return "transmit"
    if nv == [2] * layout.M:
        return "substates"
    raise ValueError(f"SetPolicyNet knows the action layouts {ACTION_LAYOUTS} "
                     f"([D + 2] * M + [2], [2] and [2] * M); got nvec {nv}. Use the MLP "
                     "network or add the layout's heads")



def _mlp(i: int, h: int, o: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(i, h), nn.Tanh(), nn.Linear(h, o))


class SetPolicyNet(nn.Module):
    """Policy logits from message-slot sets (see the module docstring for the tokens).

    Parameters
    ----------
    layout : ObsLayout
        Observation layout of the environment the net runs on (only buffers and slices
        depend on it; :meth:`bind` switches to another layout).
    nvec : sequence of int
        The core's action layout (``"full"``, ``"transmit"`` or ``"substates"``,
        :func:`action_layout`).
    hidden : int
        Width of every embedding.
    memory : int
        GRU state size over the agent's history (0: none).
    slots : bool
        Pool the (slot, substate) pair tokens (default). ``False``: the substate
        embeddings come from the substate and agent tokens alone (the pools are zero), in
        the communication-only layouts only (``"transmit"`` and ``"substates"``, where the
        fusion rule adopts and no adopt logit is scored). The pair grid, ``D`` times the
        substate tokens, dominates the network's cost. The parameters are the same either
        way.
    """

    def __init__(self, layout: ObsLayout, nvec: Sequence[int], *, hidden: int = 32,
                 memory: int = 0, slots: bool = True) -> None:
        super().__init__()
        h = int(hidden)
        self.hidden = h
        self.slots = bool(slots)
        #: whether the observation carries the communication-only fields (fixes the
        #: token sizes, so it is part of what the parameters mean)
        self.comm = layout.news is not None
        self.agent_enc = _mlp(11 if self.comm else 6, h, h)
        self.sub_enc = _mlp(4 if self.comm else 3, h, h)
        # pair embedding tanh(W v + U u): one layer on the (slot, substate) grid, the
        # substate's part added by broadcasting (the grid is the costly tensor)
        self.pair_in = nn.Linear(5, h)
        self.pair_sub = nn.Linear(h, h, bias=False)
        self.sub_mix = _mlp(4 * h, h, h)  # [u, mean-pool, max-pool, agent]
        # scoring head shared over every (substate, slot) pair: w . tanh(A e + B s) + b,
        # a layer on [e, s] with the substate's part broadcast instead of concatenated
        self.pair_a = nn.Linear(h, h)
        self.pair_b = nn.Linear(h, h, bias=False)
        self.pair_out = nn.Linear(h, 1)
        self.keep_head = nn.Linear(h, 1)
        self.avg_head = nn.Linear(h, 1)
        self.tx_head = _mlp(3 * h, h, 2)  # [agent, mean and max over substates]
        self.send_head = _mlp(2 * h, h, 2)  # per substate: [substate, agent]
        #: GRU state size over the agent's history (:mod:`netsense.rl.memory`; 0: none):
        #: the agent embedding feeds a GRU cell whose state, projected back, replaces it
        self.memory = int(memory)
        if self.memory:
            self.gru = nn.GRUCell(h, self.memory)
            self.mem_out = nn.Linear(self.memory, h)
        self.bind(layout, nvec)

    def bind(self, layout: ObsLayout, nvec: Sequence[int] | None = None) -> SetPolicyNet:
        """Run on another layout (another ``N``, ``D``, ``M``); parameters unchanged."""
        if (layout.news is not None) != self.comm:
            raise ValueError("SetPolicyNet: the layout "
                             + ("lacks" if self.comm else "has")
                             + " the communication-only fields; the network was built "
                             + ("with" if self.comm else "without") + " them")
        if nvec is None:
            nvec = {"full": [layout.D + 2] * layout.M + [2], "transmit": [2],
                    "substates": [2] * layout.M}[self.mode]
        mode = action_layout(nvec, layout)
        if not self.slots and mode == "full":
            raise ValueError("SetPolicyNet(slots=False) scores no adopt logits: it runs in "
                             "the communication-only layouts ('transmit', 'substates'), not "
                             "in full control (nvec [D + 2] * M + [2])")
        self.mode = mode
        self.layout = layout
        own = torch.zeros(layout.N, layout.M)
        src = np.flatnonzero(layout.own >= 0)
        own[src, layout.own[src]] = 1.0
        dev = next(self.parameters()).device
        self.register_buffer("is_own", own.to(dev), persistent=False)
        return self

    def tokens(self, obs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """``(g (..., N, 6), u (..., N, M, 3), v (..., N, D, M, 5), arrived (..., N, D))``;
        ``v`` is ``None`` without ``slots``."""
        L = self.layout
        D, M = L.D, L.M
        lead = obs.shape[:-1]
        own_omega = obs[..., L.own_omega]
        own_age = obs[..., L.own_age]
        arrived = obs[..., L.slot_arrived]
        s_omega = obs[..., L.slot_omega].reshape(*lead, D, M)
        s_age = obs[..., L.slot_age].reshape(*lead, D, M)
        g = [obs[..., L.time], obs[..., L.y_arrived], obs[..., L.z_lognorm],
             own_omega.mean(-1, keepdim=True), own_age.mean(-1, keepdim=True),
             arrived.mean(-1, keepdim=True) if D else obs[..., L.time] * 0]
        is_own = self.is_own.expand(*lead[:-1], L.N, M)
        u = [own_omega, own_age, is_own]
        if self.comm:
            news = obs[..., L.news]
            g += [obs[..., L.silence], obs[..., L.channel_load], obs[..., L.collided],
                  obs[..., L.agent_id], news.mean(-1, keepdim=True)]
            u.append(news)
        g = torch.cat(g, -1)
        u = torch.stack(u, -1)
        if not self.slots:
            return g, u, None, arrived
        arr = arrived.unsqueeze(-1).expand(*lead, D, M)
        oo, oa = own_omega.unsqueeze(-2), own_age.unsqueeze(-2)
        fresher = arr * (1 - s_omega) * torch.clamp(oo + (s_age < oa).float(), max=1.0)
        v = torch.stack([arr, s_omega, s_age, oa - s_age, fresher], -1)
        return g, u, v, arrived

    def forward(self, obs: torch.Tensor, h: torch.Tensor | None = None):
        """Flat logits ``(..., N, sum(nvec))``; with ``memory``, ``(logits, h')`` from the
        GRU state ``h (..., N, memory)``."""
        g, u, v, arrived = self.tokens(obs)
        ge = self.agent_enc(g)  # (..., N, h)
        if self.memory:
            if h is None:
                raise ValueError("SetPolicyNet with memory needs the recurrent state h")
            lead = ge.shape[:-1]
            h = self.gru(ge.reshape(-1, self.hidden), h.reshape(-1, self.memory))
            h = h.reshape(*lead, self.memory)
            ge = torch.tanh(self.mem_out(h))
            return self._heads(ge, u, v, arrived), h
        return self._heads(ge, u, v, arrived)

    def _heads(self, ge, u, v, arrived) -> torch.Tensor:
        ue = self.sub_enc(u)  # (..., N, M, h)
        if not self.slots:
            # substate and agent tokens only: sub_mix on [u, 0, 0, agent], its first layer
            # split so that the agent's part is computed once per agent, not per substate
            h = self.hidden
            first, act, second = self.sub_mix
            pre = (F.linear(ue, first.weight[:, :h], first.bias)
                   + F.linear(ge, first.weight[:, 3 * h:]).unsqueeze(-2))
            return self._comm_heads(ge, second(act(pre)))
        pe = torch.tanh(self.pair_in(v) + self.pair_sub(ue).unsqueeze(-3))  # (..., N, D, M, h)
        pad = arrived.unsqueeze(-1).unsqueeze(-1)  # (..., N, D, 1, 1): padding mask
        count = pad.sum(-3).clamp(min=1.0)
        mean = (pe * pad).sum(-3) / count
        mx = torch.where(pad > 0, pe, torch.full_like(pe, -1e4)).amax(-3) if pe.shape[-3] \
            else torch.zeros_like(ue)
        mx = torch.where(pad.sum(-3) > 0, mx, torch.zeros_like(mx))
        s = self.sub_mix(torch.cat([ue, mean, mx, ge.unsqueeze(-2).expand_as(ue)], -1))
        if self.mode != "full":
            return self._comm_heads(ge, s)
        tx = self.tx_head(torch.cat([ge, s.mean(-2), s.amax(-2)], -1))  # (..., N, 2)
        hid = torch.tanh(self.pair_a(pe) + self.pair_b(s).unsqueeze(-3))
        pair = self.pair_out(hid)[..., 0]  # (..., N, D, M)
        blocks = torch.cat([self.keep_head(s), pair.transpose(-1, -2), self.avg_head(s)], -1)
        return torch.cat([blocks.flatten(-2), tx], -1)  # [keep, slots, avg] * M, transmit

    def _comm_heads(self, ge, s) -> torch.Tensor:
        """Logits of the communication-only layouts from the agent embedding ``ge`` and
        the substate embeddings ``s``."""
        if self.mode == "substates":  # (..., N, M, 2) -> [send j] * M: send_head on
            # [s, agent], the agent's part of its first layer once per agent
            first, act, second = self.send_head
            pre = (F.linear(s, first.weight[:, :self.hidden], first.bias)
                   + F.linear(ge, first.weight[:, self.hidden:]).unsqueeze(-2))
            return second(act(pre)).flatten(-2)
        return self.tx_head(torch.cat([ge, s.mean(-2), s.amax(-2)], -1))  # (..., N, 2)
