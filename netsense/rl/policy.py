"""Training pipeline, stage *modules*: actor and critic modules built from a config.

:func:`actor_net` picks the logits network (:func:`netsense.rl.networks.mlp_actor_net` or
:class:`netsense.rl.set_network.SetPolicyNet`), :func:`build_actor` wraps it in TorchRL's
``ProbabilisticActor`` over :class:`netsense.rl.distributions.MaskedMultiCategorical`
(parameters shared by all agents), :func:`critic_module` the critic of the config.

Imports: TorchRL, the stages below (envs, distributions, networks, set network, config).
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.envs.utils import ExplorationType
from torchrl.modules import ProbabilisticActor

from netsense.rl.config import PPOConfig
from netsense.rl.distributions import MaskedMultiCategorical
from netsense.rl.envs import NetSenseBatchedEnv
from netsense.rl.memory import RecurrentActor, is_recurrent, unroll
from netsense.rl.networks import activation_class, critic_net, mlp_actor_net
from netsense.rl.set_network import SetPolicyNet

__all__ = ["AgeActor", "ClockActor", "CommFieldsActor", "NewsGateActor", "ObsNormActor",
           "OwnSubstateActor", "SequenceLogits", "actor_net", "build_actor", "critic_module"]

#: Logit given to a send choice the news gate closes: its probability is exactly 0 in
#: float32 and its log-probability finite, so the entropy stays finite (``0 * -1e9``).
GATED_LOGIT = -1e9


class ObsNormActor(nn.Module):
    """An actor whose observations are standardised first (``obs_norm``): TorchRL's
    ``RunningValueNorm`` over the observation vector (exact running mean and variance),
    updated by the collector with every observation it gathers and clipped to +-10; the
    statistics are buffers of this module, so saved policies carry them."""

    def __init__(self, net: nn.Module, obs_dim: int) -> None:
        from torchrl.modules import RunningValueNorm

        super().__init__()
        self.norm = RunningValueNorm(shape=int(obs_dim))
        self.body = net
        self.memory = int(getattr(net, "memory", 0) or 0)

    def update(self, obs: torch.Tensor) -> None:
        self.norm.update(obs)

    def forward(self, obs: torch.Tensor, *h: torch.Tensor):
        return self.body(self.norm.normalize(obs).clamp(-10.0, 10.0), *h)


class OwnSubstateActor(nn.Module):
    """An actor that also reads which substate its agent owns: a fixed one-hot of ``M + 1``
    entries per agent (the substate of Lemma 1's block the agent measures, the last entry
    for an agent that owns none) appended to every observation (``agent_features``).

    What an agent measures is known to it; the flat observation carries it only implicitly
    (the own substate's age is always 0), and a shared MLP did not find it in 5 million
    agent-steps (docs/rl.md, the diagnosis). The set network has the same token
    (:class:`netsense.rl.set_network.SetPolicyNet`)."""

    def __init__(self, net: nn.Module, own: np.ndarray, M: int) -> None:
        from torchrl.modules import MultiAgentMLP

        super().__init__()
        own = np.asarray(own)
        onehot = torch.zeros(own.size, M + 1)
        onehot[np.arange(own.size), np.where(own >= 0, own, M)] = 1.0
        self.register_buffer("onehot", onehot)
        self.body = net
        self.memory = int(getattr(net, "memory", 0) or 0)
        self._linear_first = isinstance(net, MultiAgentMLP)

    def forward(self, obs: torch.Tensor, *h: torch.Tensor):
        low = _autocast_dtype(obs.device.type) if self._linear_first else None
        if low is not None:
            # under mixed precision the MLP's first layer casts its input to ``low``:
            # casting before the concatenation gives it the same values with half the
            # bytes to copy, and no cast of the concatenation
            obs = obs.to(low)
        feat = self.onehot.to(obs.dtype).expand(*obs.shape[:-1], self.onehot.shape[-1])
        return self.body(torch.cat([obs, feat], -1), *h)


def _autocast_dtype(device_type: str) -> torch.dtype | None:
    """The type of autocast's matrix products on ``device_type`` while it is on, else
    None (also on a torch without the per-device queries, before 2.4)."""
    try:
        if not torch.is_autocast_enabled(device_type):
            return None
        return torch.get_autocast_dtype(device_type)
    except (TypeError, AttributeError):
        return None


class ClockActor(nn.Module):
    """An actor that also reads a clock (``clock``): ``sin`` and ``cos`` of ``2 pi k / p``
    for each period ``p``, appended to every observation, with the step ``k`` recovered
    from the observation's time entry ``k / H`` (rounded, as the scripted policies read
    it: :meth:`netsense.env.policies.CommPolicy.steps`).

    The time entry alone already determines every periodic rule, but a rule such as a
    time-division slot (``k mod 5``) is a function with 40 periods over a 200-step
    episode, which a small ReLU network can only build from many breakpoints; on the circle
    of period ``p`` the ``p`` phases are separable by one layer.

    ``shift``: each agent reads the clock in its own frame, the phases of ``k - i`` for
    agent ``i`` (its index, which the observation's ``agent_id`` gives; observations
    ``(..., N, O)``). One rule on the phase, shared by all agents, is then a staggered
    schedule: "send at phase 0 of period 5" lets the agents with ``i mod 5 = k mod 5``
    send, a different set at each step, where on the common clock it lets every agent
    send at once and a schedule needs a different rule per agent.

    ``clock_only``: the body sees the time entry and the clock only, every other entry of
    the observation held at 0 (the own-substate one-hot, appended after this module, stays):
    the policy is a schedule of the step and the agent, blind to the state."""

    def __init__(self, net: nn.Module, time_index: int, horizon: int,
                 periods: tuple[int, ...], shift: bool = False,
                 clock_only: bool = False) -> None:
        super().__init__()
        self.time_index = int(time_index)
        self.horizon = int(horizon)
        self.shift = bool(shift)
        self.clock_only = bool(clock_only)
        self.register_buffer("periods", torch.as_tensor([float(p) for p in periods]))
        self.body = net
        self.memory = int(getattr(net, "memory", 0) or 0)

    def forward(self, obs: torch.Tensor, *h: torch.Tensor):
        k = torch.round(obs[..., self.time_index:self.time_index + 1] * self.horizon)
        if self.shift:  # agent i's frame: k - i, i along the agents' axis (..., N, 1)
            k = k - torch.arange(obs.shape[-2], dtype=obs.dtype, device=obs.device)[:, None]
        periods = self.periods.to(obs.dtype)
        phase = 2 * torch.pi * torch.remainder(k, periods) / periods  # exact k mod p
        if self.clock_only:  # keep the time entry only
            keep = torch.zeros(obs.shape[-1], dtype=obs.dtype, device=obs.device)
            keep[self.time_index] = 1.0
            obs = obs * keep
        return self.body(torch.cat([obs, torch.sin(phase), torch.cos(phase)], -1), *h)


class AgeActor(nn.Module):
    """An actor that also reads the observation's ages on the scale of a few steps
    (``ages``): ``exp(-a / tau)`` for each scale ``tau`` and each entry ``a`` of the
    communication-only fields ``news`` (``M``) and ``silence`` (1), recovered in steps from
    their units of the horizon (``a = round(H x)``,
    :class:`netsense.engine.control.CommControl`), appended to every observation.

    The scripted rules threshold these entries at a few steps (``event:3`` sends on news
    of three steps; ``acked`` probes six steps after a lost message), where one step is
    ``1 / H = 0.005`` of the entry beside entries of order 1. On ``comm_fading-v0`` the
    rule ``acked(sources:0)`` is, for the agents it lets speak, a function of the current
    ``acks`` and ``silence`` alone, yet the feed-forward recipe learnt to stay silent for
    tens of steps where the rule probes after six (``learners.py reaction``). The decays
    separate the first steps by order-1 differences and saturate at 0 for long ages."""

    def __init__(self, net: nn.Module, news: slice, silence: slice, horizon: int,
                 scales: tuple[int, ...]) -> None:
        super().__init__()
        self.index = (int(news.start), int(news.stop), int(silence.start))
        self.horizon = int(horizon)
        self.register_buffer("scales", torch.as_tensor([float(t) for t in scales]))
        self.body = net
        self.memory = int(getattr(net, "memory", 0) or 0)

    def features(self, obs: torch.Tensor) -> torch.Tensor:
        """``(..., (M + 1) * len(scales))``: the decays, scale-major per entry."""
        lo, hi, sil = self.index
        ages = torch.cat([obs[..., lo:hi], obs[..., sil:sil + 1]], -1)
        steps = torch.round(ages * self.horizon)
        return torch.exp(-steps[..., None] / self.scales.to(obs.dtype)).flatten(-2)

    def forward(self, obs: torch.Tensor, *h: torch.Tensor):
        return self.body(torch.cat([obs, self.features(obs)], -1), *h)


class CommFieldsActor(nn.Module):
    """An actor whose body reads only the communication fields of the observation
    (``comm_fields_only``): ``news``, ``silence``, ``channel_load``, ``collided``,
    ``agent_id``, ``next_out`` and ``acks`` where the layout has them, and the time entry;
    every other entry (the measurements, the estimator's slots) is held at 0 before the
    wrappers inside it read the observation (the ages read ``news`` and ``silence``, the
    clock the time entry, which stay). A restriction of the policy class: the scripted
    rules of the communication tasks read only these fields (on ``comm_fading-v0``,
    ``acked(sources:0)`` is a function of the agent's ``acks``, ``silence`` and whether it
    owns a substate)."""

    FIELDS = ("time", "news", "silence", "channel_load", "collided", "agent_id",
              "next_out", "acks")

    def __init__(self, net: nn.Module, layout) -> None:
        super().__init__()
        keep = torch.zeros(layout.size)
        for name in self.FIELDS:
            field = getattr(layout, name)
            if field is not None:
                keep[field] = 1.0
        self.register_buffer("keep", keep)
        self.body = net
        self.memory = int(getattr(net, "memory", 0) or 0)

    def forward(self, obs: torch.Tensor, *h: torch.Tensor):
        return self.body(obs * self.keep.to(obs.dtype), *h)


class NewsGateActor(nn.Module):
    """An actor that sends only what is news (``news_gate``): the choice "send substate
    ``j``" (control mode ``"substates"``) is closed where the observation's ``news[j]`` is
    0, "transmit" (``"transmit"``) where no substate is news; everything else is the
    network's. A restriction of the policy class, not of the task: the environment's action
    space and mask are unchanged, and the gate reads only the agent's own observation
    (:class:`netsense.engine.control.CommControl`, ``news``: 0 where the agent already sent
    what it holds now). Closed choices get the logit :data:`GATED_LOGIT` (probability 0,
    no gradient, no entropy).

    ``event:1`` is the gated policy that sends every open choice; what the gated learner
    learns is which news to send (on ``comm_substates-v0``: whether to relay another
    agent's news, docs/rl.md)."""

    def __init__(self, net: nn.Module, news: slice, mode: str) -> None:
        super().__init__()
        if mode not in ("transmit", "substates"):
            raise ValueError(f"PPOConfig.news_gate gates the send choices of the "
                             f"communication-only control modes 'transmit' and 'substates'; "
                             f"the core runs in {mode!r}")
        self.body = net
        self.news = (int(news.start), int(news.stop))
        self.per_substate = mode == "substates"
        self.memory = int(getattr(net, "memory", 0) or 0)

    def update(self, obs: torch.Tensor) -> None:
        """Feed the body's observation normaliser (:class:`ObsNormActor`), if it has one."""
        self.body.update(obs)

    def forward(self, obs: torch.Tensor, *h: torch.Tensor):
        out = self.body(obs, *h)
        logits, rest = (out[0], out[1:]) if isinstance(out, tuple) else (out, None)
        fresh = obs[..., self.news[0]:self.news[1]] > 0  # (..., M)
        if not self.per_substate:
            fresh = fresh.any(-1, keepdim=True)
        send = logits[..., 1::2]  # the flat layout [no, yes] per choice
        send = torch.where(fresh, send, torch.full_like(send, GATED_LOGIT))
        logits = torch.stack([logits[..., 0::2], send], -1).flatten(-2)
        return logits if rest is None else (logits, *rest)


def actor_net(config: PPOConfig, core, device=None) -> nn.Module:
    """The actor's logits network for ``core``'s layout and action layout: the set network,
    the recurrent MLP (``config.memory > 0``) or TorchRL's ``MultiAgentMLP``; the MLPs read
    the own-substate one-hot when ``config.agent_features``, the clock of
    ``config.clock`` (:class:`ClockActor`) and the age decays of ``config.ages``
    (:class:`AgeActor`), read only the communication fields when
    ``config.comm_fields_only`` (:class:`CommFieldsActor`), and sit behind a running
    observation normaliser when ``config.obs_norm``; either network sits behind the news
    gate when ``config.news_gate`` (:class:`NewsGateActor`)."""
    if config.network == "set":
        net = SetPolicyNet(core.layout, core.nvec, hidden=config.set_hidden,
                           memory=config.memory, slots=config.set_slots)
        return _gated(config, core, net).to(device)
    if config.ages and core.layout.news is None:
        raise ValueError("PPOConfig.ages reads the news and silence fields of the "
                         "communication-only control modes; the core's observation has "
                         f"none (control mode {core.control.mode!r})")
    extra = ((core.M + 1 if config.agent_features else 0) + 2 * len(config.clock)
             + (core.M + 1) * len(config.ages))
    if config.memory:
        net = RecurrentActor(core.layout.size + extra, int(sum(core.nvec)), config.hidden,
                             config.memory, activation_class(config.activation), device=device)
    else:
        net = mlp_actor_net(core.layout, core.nvec, core.N, hidden=config.hidden,
                            activation=config.activation, extra_inputs=extra, device=device)
    if config.agent_features:
        net = OwnSubstateActor(net, core.layout.own, core.M)
    if config.clock:
        net = ClockActor(net, core.layout.time.start, core.horizon, config.clock,
                         shift=config.clock_shift, clock_only=config.clock_only)
    if config.ages:
        net = AgeActor(net, core.layout.news, core.layout.silence, core.horizon, config.ages)
    if config.comm_fields_only:
        if core.layout.news is None:
            raise ValueError("PPOConfig.comm_fields_only keeps the communication-only "
                             "fields; the core's observation has none (control mode "
                             f"{core.control.mode!r})")
        net = CommFieldsActor(net, core.layout)
    net = ObsNormActor(net, core.layout.size) if config.obs_norm else net
    return _gated(config, core, net).to(device)


def _gated(config: PPOConfig, core, net: nn.Module) -> nn.Module:
    """``net`` behind the news gate when ``config.news_gate`` (:class:`NewsGateActor`)."""
    if not config.news_gate:
        return net
    return NewsGateActor(net, core.layout.news, core.control.mode)  # refuses full control


class SequenceLogits(nn.Module):
    """A recurrent actor over the sequences of a rollout, for the loss:
    ``(obs (S, T, N, O), hidden (S, T, N, m), first (S, T)) -> logits (S, T, N, K)``,
    unrolled from the hidden state recorded before the first step
    (:func:`netsense.rl.memory.unroll`)."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, obs: torch.Tensor, hidden: torch.Tensor,
                first: torch.Tensor) -> torch.Tensor:
        return unroll(self.net, obs, hidden[:, 0], first)


def build_actor(net: nn.Module, nvec) -> ProbabilisticActor:
    """``ProbabilisticActor``: logits from ``net``, masked by ``("agents", "action_mask")``.

    A recurrent ``net`` reads sequences (batch ``[S, T]``: ``("agents", "hidden")`` and
    ``"first"`` besides the observation; :class:`SequenceLogits`)."""
    if is_recurrent(net):
        module = TensorDictModule(SequenceLogits(net), in_keys=[
            ("agents", "observation"), ("agents", "hidden"), "first"],
            out_keys=[("agents", "logits")])
    else:
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
                           hidden=config.critic_hidden, activation=config.activation,
                           device=device)
    return TensorDictModule(net, in_keys=keys, out_keys=[("agents", "state_value")])
