"""Policy names and single episodes: scripted or learned policies through the env, the oracle.

:func:`netsense.benchmark.batched.rollout_seeds` is the batched counterpart of :func:`rollout` and
:func:`rollout_oracle` (the same record per seed).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense.benchmark.records import EpisodeRecord, EpisodeRecorder
from netsense.env.comm_policies import COMM_POLICIES, spec_family
from netsense.env.policies import SCRIPTED_POLICIES
from netsense.estimators.oracle import CentralizedKF

#: Communication baselines (communication-only scenarios; ``name[:knob]``, e.g.
#: ``periodic:4``), see :mod:`netsense.env.comm_policies`.
COMM_BASELINES = tuple(COMM_POLICIES)
#: Every policy name the harness knows (``learned`` and ``learned_sampled`` carry
#: ``:PATH``: greedy and sampled actions of one policy).
POLICY_NAMES = SCRIPTED_POLICIES + COMM_BASELINES + ("kf_oracle", "learned",
                                                     "learned_sampled")
#: Default policy set of ``netsense benchmark``.
DEFAULT_POLICIES = ("freshness", "uniform_consensus", "open_loop", "random", "kf_oracle")


class NotApplicable(ValueError):
    """A policy that does not apply to a scenario (e.g. tree consensus on random graphs)."""


def is_batched_policy(path: str | Path) -> bool:
    """``.pt`` files are policies of the batched TorchRL trainer (:mod:`netsense.rl.ppo`);
    anything else is read as a MaskablePPO ``policy.zip``."""
    return str(path).endswith(".pt")


def learned_overrides(scenario: str, path: str | Path, overrides: dict | None) -> dict:
    """The overrides a learned policy is evaluated with: ``overrides``, and for a ``.pt``
    policy the ``[control]`` mode and fusion rule it acted in during training (so a
    communication policy runs in its communication-only mode on any scenario)."""
    over = dict(overrides or {})
    if not is_batched_policy(path):
        return over
    from netsense.env.registry import control_overrides
    from netsense.rl.checkpoint import policy_control, read_policy

    return control_overrides(scenario, policy_control(read_policy(path)), over)


def _make_env(scenario: str, overrides: dict | None):
    from netsense.env.registry import make

    return make(scenario, **dict(overrides or {}))


#: Benchmark policy name -> name in :mod:`netsense.env.policies`.
_SCRIPTED = {"freshness": "freshness", "uniform_consensus": "uniform",
             "tree_consensus": "tree", "open_loop": "open_loop", "random": "random"}


def scripted_policy(name: str, env, seed: int | Sequence[int]):
    """The scripted policy ``name`` (a benchmark name) of :mod:`netsense.env.policies`.

    Parameters
    ----------
    name : str
        One of :data:`SCRIPTED_POLICIES`.
    env : netsense.env.pettingzoo_env.NetSenseEnv or netsense.engine.core.BatchedCore
    seed : int or sequence of int
        Seeds ``random`` (a sequence: one generator per batch member, see
        :class:`netsense.env.policies.RandomPolicy`); unused by the other policies.

    Raises
    ------
    NotApplicable
        ``tree_consensus`` on a scenario without a periodic graph schedule; a
        communication baseline on a full-control scenario; an adoption rule other than
        the scenario's fusion rule on a communication-only scenario.
    """
    from netsense.env.comm_policies import make_comm_policy
    from netsense.env.policies import make_policy

    if spec_family(name) in COMM_POLICIES:
        try:
            return make_comm_policy(name, env, seed)
        except ValueError as exc:
            if getattr(getattr(env, "core", env), "comm", None) is None:
                raise NotApplicable(str(exc)) from exc
            raise
    if name not in _SCRIPTED:
        raise ValueError(f"unknown scripted policy {name!r}; choose from "
                         f"{', '.join(SCRIPTED_POLICIES)}")
    kwargs = {"seed": seed} if name == "random" else {}
    try:
        return make_policy(_SCRIPTED[name], env, **kwargs)
    except ValueError as exc:
        comm = getattr(getattr(env, "core", env), "comm", None) is not None
        if name == "tree_consensus" or comm:  # a periodic schedule / its own adoption
            raise NotApplicable(str(exc)) from exc
        raise


def rollout(scenario: str, policy: str, seed: int, overrides: dict | None = None
            ) -> EpisodeRecord:
    """One episode of ``scenario`` under ``policy`` through the PettingZoo API.

    The true state, every estimate and the freshness indices are read from the
    environment's core after each step (``env.core``); transmissions are the transmit
    bits the agents chose. :func:`netsense.benchmark.batched.rollout_seeds` is the batched
    counterpart (one run for many seeds, the same record per seed).
    """
    learned = policy.startswith("learned")
    path = policy.split(":", 1)[1] if learned and ":" in policy else None
    if learned and not path:
        raise ValueError("the learned policy needs a path: learned:PATH")
    if learned:
        overrides = learned_overrides(scenario, path, overrides)
    env = _make_env(scenario, overrides)
    core = env.core
    if learned and is_batched_policy(path):
        import torch

        from netsense.rl.checkpoint import load_policy

        agent_env = env
        sampled = policy.startswith("learned_sampled")
        batched = load_policy(path, core, deterministic=not sampled)
        if sampled:  # reproducible draws: torch seeded with the episode's seed
            torch.manual_seed(int(seed))

        def act(o, i):  # the env's observations are the core's rows
            a = batched.act(*core.observe())[0]
            return {ag: a[j] for j, ag in enumerate(env.possible_agents) if ag in env.agents}
    elif learned:
        from netsense.rl.sb3_policy import LearnedPolicy
        from netsense.rl.wrappers import MaskedFlatObs

        agent_env = MaskedFlatObs(env)
        sampled = policy.startswith("learned_sampled")
        model = LearnedPolicy(path, deterministic=not sampled)
        if sampled:  # reproducible draws: torch seeded with the episode's seed
            import torch

            torch.manual_seed(int(seed))

        def act(o, i):
            return model.act(o, agent_env)
    else:
        agent_env = env
        pol = scripted_policy(policy, env, seed)

        def act(o, i):
            return pol.act_dict(env, o, i)
    obs, infos = agent_env.reset(seed=seed)
    rec = EpisodeRecorder(env.model.reward.error_floor)
    rec.state(core)
    while env.agents:
        actions = act(obs, infos)
        obs, rew, term, trunc, infos = agent_env.step(actions)
        rec.state(core)
        rec.step(core.transmit, [[rew[a] for a in env.possible_agents]])
    return rec.records()[0]


def rollout_oracle(scenario: str, seed: int, overrides: dict | None = None) -> EpisodeRecord:
    """The centralized KF on the same realisation (same seed) as the policies see.

    The environment is stepped with the always-valid "keep everything, stay silent"
    action just to advance the plant and draw the measurements; only ``x[k]`` and
    ``y[k]`` are used. ``rollout_seeds(scenario, "kf_oracle", seeds)`` of
    :mod:`netsense.env.vector` runs many seeds as one batch with the same records.
    """
    env = _make_env(scenario, overrides)
    core = env.core
    kf = CentralizedKF(env.model.plant, x0_std=env.model.x0_std, batch_size=1)
    env.reset(seed=seed)
    idle = {a: np.zeros(core.nvec.size, dtype=np.int64) for a in env.possible_agents}
    rec = EpisodeRecorder(env.model.reward.error_floor, network=False)
    while True:
        rec.state(core, kf.x[:, None, :])
        if not env.agents:
            break
        kf.step(core.y, core.y_arrived)
        env.step(idle)
    return rec.records()[0]
