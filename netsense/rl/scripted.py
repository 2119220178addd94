"""Training pipeline, stage *scripted data*: scripted policies as data sources.

:func:`scripted_actions` gives any scripted policy of netsense (communication baselines,
observers) in a core's action layout; :func:`collect_scripted` drives a batched core with
one and returns observations, masks and actions (behaviour cloning reads them).

Imports: numpy, torch, :mod:`netsense.env` (the policies) and the stages below.
"""

from __future__ import annotations

import numpy as np
import torch

from netsense.rl.config import PPOConfig
from netsense.rl.envs import make_core

__all__ = ["collect_scripted", "scripted_actions"]


def scripted_actions(name: str, core, seed: int = 0):
    """``(obs, mask) -> actions`` of a scripted policy in ``core``'s action layout.

    ``name``: a communication baseline of :mod:`netsense.env.comm_policies`
    (``event:2``, ``sources:0``, a wrapping rule such as ``gated(sources:0)``, ...;
    communication-only modes) or a policy of
    :data:`netsense.env.policies.POLICIES` (in a communication-only mode the fusion
    rule's name means "always transmit", ``open_loop`` "never"). ``seed`` seeds the
    randomised ones.
    """
    from netsense.env.comm_policies import COMM_POLICIES, make_comm_policy, spec_family
    from netsense.env.policies import make_policy

    if spec_family(name) in COMM_POLICIES:
        return make_comm_policy(name, core, seed=seed).act
    return make_policy(name, core, **({"seed": seed} if name == "random" else {})).act


def collect_scripted(config: PPOConfig, name: str, steps: int, seed: int, *,
                     progress: bool = False):
    """Observations, masks and scripted actions of about ``steps`` env-steps (``num_envs``
    members, ``ceil(steps / num_envs)`` steps each), as tensors ``(rows, N, ...)``;
    ``progress``: a tqdm bar over the steps."""
    from tqdm.auto import tqdm

    core = make_core(config.scenario, config.num_envs, control=config.control,
                     **config.overrides)
    act = scripted_actions(name, core, seed)
    obs, mask = core.reset(seed)
    rng = np.random.default_rng(seed)
    O, Mk, A = [], [], []
    for _ in tqdm(range(-(-int(steps) // core.B)), desc=f"scripted data ({name})",
                  unit="env-step", disable=not progress):
        a = act(obs, mask)
        O.append(obs.copy())
        Mk.append(mask.astype(bool))
        A.append(np.asarray(a, dtype=np.int64))
        out = core.step(a)
        obs, mask = out.obs, out.action_mask
        done = out.terminated | out.truncated
        if done.any():
            obs, mask = core.reset([int(s) for s in rng.integers(0, 2**62, core.B)],
                                   members=done)
    cat = lambda xs: torch.as_tensor(np.concatenate(xs))  # noqa: E731
    return cat(O), cat(Mk), cat(A)
