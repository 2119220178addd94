"""Training pipeline, stage *evaluation*: evaluation during training.

:func:`evaluate` runs an actor on fresh episodes (seeds from
:data:`netsense.rl.config.EVAL_SEED`, one horizon each; monitoring only — the protocol of
:mod:`netsense.benchmark.protocol` evaluates on its own seeds), :func:`evaluate_scripted`
a scripted policy on the same episodes, :func:`mask_violations` counts masked actions.

Imports: torch, TorchRL and the stages below.
"""

from __future__ import annotations

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from netsense.rl.config import EVAL_SEED, PPOConfig
from netsense.rl.envs import NetSenseBatchedEnv, make_core
from netsense.rl.scripted import scripted_actions

__all__ = ["evaluate", "evaluate_scripted", "first_episode", "mask_violations"]


def first_episode(td) -> dict:
    """Means over each member's first episode of a rollout ``td (B, T)``."""
    done = td["next", "done"][..., 0].float()  # (B, T)
    before = torch.cumsum(done, 1) - done == 0  # steps up to and including the first done
    w = before.float()
    steps = w.sum(1).clamp(min=1)
    r = td["next", "agents", "reward"][..., 0].mean(-1)  # (B, T), mean over agents
    e = td["next", "agents", "error"].mean(-1)
    s = td["next", "agents", "sent"].mean(-1)
    return {"return": float((r * w).sum(1).mean()),
            "error": float(((e * w).sum(1) / steps).mean()),
            "messages": float(((s * w).sum(1) / steps).mean())}


def evaluate(actor, config: PPOConfig, *, episodes: int | None = None,
             deterministic: bool = True) -> dict:
    """Return per agent, mean error and messages per agent-step of ``actor`` on
    ``episodes`` fresh episodes (seeds :data:`EVAL_SEED` + b), one horizon each."""
    B = int(episodes or config.eval_envs)
    core = make_core(config.scenario, B, control=config.control, **config.overrides)
    dev = next(actor.parameters()).device
    env = NetSenseBatchedEnv(core, reward=config.reward, seed=EVAL_SEED, device=dev)
    kind = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    with torch.no_grad(), set_exploration_type(kind):
        td = env.rollout(core.horizon, actor, break_when_any_done=False)
    return first_episode(td)


def evaluate_scripted(name: str, config: PPOConfig, *, episodes: int | None = None) -> dict:
    """:func:`evaluate` for a scripted policy (same seeds, same reward option)."""
    B = int(episodes or config.eval_envs)
    core = make_core(config.scenario, B, control=config.control, **config.overrides)
    env = NetSenseBatchedEnv(core, reward=config.reward, seed=EVAL_SEED)
    act = scripted_actions(name, core)

    def policy(td):
        obs = td["agents", "observation"].numpy()
        mask = td["agents", "action_mask"].numpy().astype(np.int8)
        td["agents", "action"] = torch.as_tensor(act(obs, mask))
        return td

    td = env.rollout(core.horizon, policy, break_when_any_done=False)
    return first_episode(td)


def mask_violations(td, nvec) -> int:
    """Agent-steps of ``td`` whose action breaks its mask (must be 0)."""
    offsets = torch.as_tensor(np.concatenate([[0], np.cumsum(nvec)[:-1]]))
    a = td["agents", "action"]
    m = td["agents", "action_mask"]
    ok = m.gather(-1, a + offsets.to(a.device)).all(-1)
    return int((~ok).sum())
