"""Training pipeline, stage *evaluation*: evaluation during training.

:func:`evaluate` runs an actor network on fresh episodes (seeds from
:data:`netsense.rl.config.EVAL_SEED`, one horizon each; monitoring only — the protocol of
:mod:`netsense.benchmark.protocol` evaluates on its own seeds), :func:`evaluate_scripted`
a scripted policy on the same episodes, :func:`mask_violations` counts masked actions.
Both score the scenario's reward whatever reward option the run trains on
(``PPOConfig.reward``), so that a curve of a run trained on a shaped reward
(``agent``, ``counterfactual``) reads on the same scale as the scripted policies and the
protocol; with the ``team`` reward the two are the same (the mean over agents of the team
mean is the mean of the scenario's rewards).

Imports: torch and the stages below (config, envs, rollout, scripted).
"""

from __future__ import annotations

import numpy as np
import torch

from netsense.rl.config import EVAL_SEED, PPOConfig
from netsense.rl.envs import NetSenseBatchedEnv, make_core
from netsense.rl.rollout import Collector
from netsense.rl.scripted import scripted_actions

__all__ = ["evaluate", "evaluate_scripted", "first_episode", "mask_violations"]


def first_episode(reward: torch.Tensor, done: torch.Tensor, error: torch.Tensor,
                  sent: torch.Tensor) -> dict:
    """Means over each member's first episode of ``T`` steps: ``reward``, ``error``,
    ``sent`` ``(T, B, N)``, ``done`` ``(T, B)``.

    Returns ``return`` (per agent, summed over the episode, mean over members),
    ``error`` and ``messages`` (per agent-step)."""
    done = done.float()
    w = (torch.cumsum(done, 0) - done == 0).float()  # steps up to and including the first end
    steps = w.sum(0).clamp(min=1)
    r, e, s = (x.float().mean(-1) for x in (reward, error, sent))  # (T, B), mean over agents
    return {"return": float((r * w).sum(0).mean()),
            "error": float(((e * w).sum(0) / steps).mean()),
            "messages": float(((s * w).sum(0) / steps).mean())}


def _core(config: PPOConfig, episodes: int | None):
    B = int(episodes or config.eval_envs)
    return make_core(config.scenario, B, control=config.control, **config.overrides)


def evaluate(net: torch.nn.Module, config: PPOConfig, *, episodes: int | None = None,
             deterministic: bool = True) -> dict:
    """Return per agent, mean error and messages per agent-step of the actor network
    ``net`` on ``episodes`` fresh episodes (seeds :data:`EVAL_SEED` + b), one horizon each,
    with the most likely allowed actions (``deterministic``) or sampled ones, scored with
    the scenario's reward (not ``config.reward``). Sampled actions come from the collector's
    own generator (seeded with :data:`EVAL_SEED`), not torch's global one, so evaluating
    does not change a training run, nor a collection running in another thread."""
    core = _core(config, episodes)
    dev = next(net.parameters()).device
    env = NetSenseBatchedEnv(core, reward="scenario", seed=EVAL_SEED)
    ro = Collector(env, net, core.horizon, device=dev, seed=EVAL_SEED).collect(
        deterministic=deterministic)
    return first_episode(ro.reward, ro.done, ro.error, ro.sent)


def evaluate_scripted(name: str, config: PPOConfig, *, episodes: int | None = None) -> dict:
    """:func:`evaluate` for a scripted policy (same seeds, the scenario's reward)."""
    core = _core(config, episodes)
    env = NetSenseBatchedEnv(core, reward="scenario", seed=EVAL_SEED)
    act = scripted_actions(name, core)
    obs, mask = env.restart()
    cols: list[list[np.ndarray]] = [[], [], [], []]
    for _ in range(core.horizon):
        obs, mask, r, term, trunc = env.advance(np.asarray(act(obs, mask)))
        for c, v in zip(cols, (r, term | trunc, core.errors.copy(), core.transmit.copy()),
                        strict=True):
            c.append(v)
    return first_episode(*(torch.as_tensor(np.stack(c)) for c in cols))


def mask_violations(mask: torch.Tensor, action: torch.Tensor, nvec) -> int:
    """Agent-steps whose action breaks its flat mask (must be 0): ``mask (..., K)`` bool,
    ``action (..., A)``."""
    offsets = torch.as_tensor(np.concatenate([[0], np.cumsum(nvec)[:-1]]),
                              device=action.device)
    ok = mask.gather(-1, action + offsets).all(-1)
    return int((~ok).sum())
