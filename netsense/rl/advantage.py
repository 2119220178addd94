"""Training pipeline, stage *advantage*: values, GAE and the loss's batch from a rollout.

After a rollout (:class:`netsense.rl.rollout.Rollout`) the critic evaluates every state of
it in one batched forward pass (its inputs — observations, the global state — were
recorded once per step, not rebuilt per minibatch), the advantages and value targets come
from TorchRL's generalised advantage estimate
(:func:`torchrl.objectives.value.functional.vec_generalized_advantage_estimate`,
Schulman et al. 2016, eqs. (16)-(18)) with every episode end terminal, and
:func:`loss_batch` lays the result out as the ``TensorDict`` TorchRL's PPO losses read.

Value normalisation (``PPOConfig.value_norm``; MAPPO's "ValueNorm", Yu et al., NeurIPS
2022): the critic's output is a *standardised* value; a running normaliser (TorchRL's
``RunningValueNorm``) tracks the mean and spread of the value targets, GAE reads the
de-normalised predictions, and the critic regresses on standardised targets. Returns of a
communication task sit near -10 per agent with a spread of about 2 between states: without
normalisation the critic spends its first hundreds of updates on the offset and explains
little of the spread (see docs/rl.md, the diagnosis).

Imports: torch, TensorDict, TorchRL and the stages below (config, rollout, memory).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict

from netsense.rl.config import loss_arithmetic
from netsense.rl.rollout import Rollout

__all__ = ["Advantages", "critic_values", "estimate", "explained_variance", "loss_batch"]


@dataclass
class Advantages:
    """GAE output for a rollout, ``(T, B, N)`` each, on the learner's device."""

    advantage: torch.Tensor
    target: torch.Tensor  #: value targets in return units
    value: torch.Tensor  #: the critic's predictions in return units (before the update)


@torch.no_grad()
def critic_values(critic, ro: Rollout, value_norm=None) -> torch.Tensor:
    """``(T + 1, B, N)`` values of every state of the rollout, in return units.

    ``critic`` is the ``TensorDictModule`` of :func:`netsense.rl.policy.critic_module`; its
    network is called on the recorded tensors (``state`` when it reads it)."""
    net = critic.module
    keys = [k if isinstance(k, str) else k[-1] for k in critic.in_keys]
    args = [ro.obs if k == "observation" else ro.state for k in keys]
    v = net(*args)[..., 0]
    return value_norm.denormalize(v.unsqueeze(-1))[..., 0] if value_norm is not None else v


def estimate(values: torch.Tensor, reward: torch.Tensor, done: torch.Tensor, gamma: float,
             lmbda: float) -> Advantages:
    """GAE over the rollout: ``values (T + 1, B, N)``, ``reward (T, B, N)``, ``done (T, B)``.

    Every episode end is terminal (no bootstrap across it); the rollout's last step
    bootstraps from ``values[T]``."""
    from torchrl.objectives.value.functional import vec_generalized_advantage_estimate

    T = reward.shape[0]
    # TorchRL's layout: [*batch, time, feature] -> (B, N, T, 1)
    to_bt = lambda x: x.permute(1, 2, 0).unsqueeze(-1)  # noqa: E731
    d = done[..., None].expand_as(reward)
    adv, target = vec_generalized_advantage_estimate(
        gamma, lmbda, to_bt(values[:T]), to_bt(values[1:]), to_bt(reward), to_bt(d),
        to_bt(d), time_dim=-2)
    back = lambda x: x[..., 0].permute(2, 0, 1)  # noqa: E731
    return Advantages(back(adv), back(target), values[:T])


def explained_variance(pred: torch.Tensor, target: torch.Tensor) -> float:
    """``1 - Var(target - pred) / Var(target)`` (1: perfect; 0: no better than the mean)."""
    var = float(target.var())
    return float("nan") if var == 0.0 else 1.0 - float((target - pred).var()) / var


def loss_batch(ro: Rollout, adv: Advantages, value_norm=None, *,
               sequences: bool = False) -> TensorDict:
    """The rollout as the batch TorchRL's PPO losses read.

    ``sequences=False``: batch ``[T * B]`` of env-steps (each holds the ``N`` agents);
    ``sequences=True`` (recurrent actors): batch ``[B, T]``, one sequence per member, with
    ``("agents", "hidden")`` and ``"first"`` for :class:`netsense.rl.policy.SequenceLogits`.
    Advantages are standardised over the whole rollout (all agents and steps: one scale
    for every agent, so the agents whose actions matter little are not amplified), value
    targets when ``value_norm`` is given (update it first).
    """
    T, B = ro.reward.shape[:2]
    target = adv.target
    if value_norm is not None:
        target = value_norm.normalize(target.unsqueeze(-1))[..., 0]
    a = adv.advantage
    a = (a - a.mean()) / (a.std() + 1e-8)  # standardised over the whole rollout
    agents = {"observation": ro.obs[:T], "action_mask": ro.mask, "action": ro.action,
              "action_log_prob": ro.log_prob, "advantage": a.unsqueeze(-1),
              "value_target": target.unsqueeze(-1)}
    if sequences:
        agents["hidden"] = ro.hidden
    root = {} if ro.state is None else {"state": ro.state[:T]}
    if sequences:
        root["first"] = ro.first
    N = ro.reward.shape[2]
    td = TensorDict({"agents": TensorDict(agents, batch_size=(T, B, N)), **root},
                    batch_size=(T, B))
    if sequences:
        return td.transpose(0, 1).contiguous()  # (B, T): one sequence per member
    return td.reshape(T * B)


@torch.no_grad()
def decouple(data: TensorDict, actor, *, precision: str = "fp32") -> TensorDict:
    """A loss batch of lagged data made ready for the decoupled clipped objective.

    The decoupled objective of Hilton et al. (2021, "Batch size-invariance for policy
    optimization", the ``delay_actor`` option of TorchRL's PPO losses) clips the ratio
    ``r = pi / pi_prox`` around a proximal policy ``pi_prox`` and weights the surrogate by
    ``w = pi_prox / pi_behav`` (the probability of the action taken under the proximal
    over the behaviour policy that collected it): ``-w min(r A, clip(r) A)``. As ``w > 0``
    does not depend on the parameters, that equals PPO's loss on the same batch with the
    recorded log-probabilities replaced by the proximal ones and the advantages ``A`` by
    ``w A``, which this function does in place (and returns ``data``). ``actor`` (the loss's
    actor) at its current parameters is the proximal policy: its log-probabilities of the
    recorded actions are computed once here, under the loss's arithmetic (``precision``),
    where ``delay_actor`` computes them again in every minibatch of every epoch (one more
    forward pass of the actor each time) from a copy of the actor's parameters that
    TorchRL's target updaters refresh, which leaves the copy's buffers as they were when
    the loss was built (an :class:`~netsense.rl.policy.ObsNormActor`'s statistics went
    stale there). Equal to TorchRL's ``delay_actor`` loss to float rounding for an actor
    without such buffers (``tests/test_rl_training.py``).
    """
    with loss_arithmetic(data["agents", "action"].device, precision):
        prox = actor.get_dist(data).log_prob(data["agents", "action"]).float()
    agents = data["agents"]
    w = (prox - agents["action_log_prob"]).exp()
    agents["advantage"] = agents["advantage"] * w.unsqueeze(-1)
    agents["action_log_prob"] = prox
    return data
