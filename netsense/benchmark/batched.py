"""Benchmark episodes of many seeds as one batched run (one core member per seed).

:func:`rollout_seeds` runs the scripted policies and the centralized KF oracle
(:data:`BATCHABLE_POLICIES`) on :class:`netsense.engine.core.BatchedCore`; member ``b``'s
record equals the single episode of ``seeds[b]`` (:func:`netsense.benchmark.rollouts.rollout`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netsense.engine.core import BatchedCore, CoreModel
from netsense.env.comm_policies import COMM_POLICIES, spec_family
from netsense.env.policies import SCRIPTED_POLICIES
from netsense.env.vector import load_model

__all__ = ["BATCHABLE_POLICIES", "rollout_seeds"]

# ---------------------------------------------------------------------------- benchmark
#: Benchmark policies that :func:`rollout_seeds` runs as one batch: the scripted ones
#: (``random`` with one generator per member), the communication baselines (``name[:knob]``;
#: ``bernoulli`` with one generator per member) and the centralized KF oracle. Learned
#: policies act through the PettingZoo env episode by episode (:func:`netsense.benchmark.
#: rollout`).
BATCHABLE_POLICIES = SCRIPTED_POLICIES + tuple(COMM_POLICIES) + ("kf_oracle",)


def rollout_seeds(scenario: str | CoreModel, policy: str, seeds: Sequence[int],
                  overrides: dict | None = None) -> list:
    """Episodes of several seeds as **one** batched run; one record per seed.

    The batched counterpart of :func:`netsense.benchmark.rollout` (and, for
    ``"kf_oracle"``, of :func:`netsense.benchmark.rollout_oracle`) for the policies in
    :data:`BATCHABLE_POLICIES`: member ``b`` is seeded with ``seeds[b]``, so its record
    equals ``rollout(scenario, policy, seeds[b], overrides)`` (same errors up to matmul
    rounding, identical indices, transmissions and rewards). ``random`` draws member
    ``b``'s choices from its own generator seeded with ``seeds[b]``, as the single
    episode does; ``kf_oracle`` steps the members with the idle action (keep every
    estimate, stay silent) and runs one centralized filter per member
    (:class:`netsense.benchmark.CentralizedKF` with ``batch_size=B``). Members that end
    early (``divergence_limit``) are cut at their last step, like the single episode.

    Parameters
    ----------
    scenario : str or CoreModel
    policy : str
        One of :data:`BATCHABLE_POLICIES`.
    seeds : sequence of int
        One batch member per seed.
    overrides : dict, optional
        Scenario overrides (with a scenario id only).

    Returns
    -------
    list of netsense.benchmark.EpisodeRecord

    Raises
    ------
    netsense.benchmark.NotApplicable
        ``tree_consensus`` on a scenario without a periodic graph schedule.
    """
    from netsense.benchmark.records import EpisodeRecorder
    from netsense.benchmark.rollouts import scripted_policy
    from netsense.estimators.oracle import CentralizedKF

    if spec_family(policy) not in BATCHABLE_POLICIES:
        raise ValueError(f"policy {policy!r} cannot run batched; choose one of "
                         f"{', '.join(BATCHABLE_POLICIES)} (learned policies run episode by "
                         "episode in netsense.benchmark)")
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds must be non-empty")
    model, _ = load_model(scenario, **dict(overrides or {}))
    B = len(seeds)
    core = BatchedCore(model, B)
    oracle = policy == "kf_oracle"
    if oracle:
        kf = CentralizedKF(model.plant, x0_std=model.x0_std, batch_size=B)
        idle = np.zeros((B, core.N, core.nvec.size), dtype=np.int64)
    else:
        pol = scripted_policy(policy, core, seeds)
    obs, mask = core.reset(seeds)
    rec = EpisodeRecorder(model.reward.error_floor, network=not oracle)
    rec.state(core, kf.x[:, None, :] if oracle else None)
    end = np.full(B, -1)
    k = 0
    while (end < 0).any():
        if oracle:
            kf.step(core.y, core.y_arrived, members=end < 0)
            out = core.step(idle, observe=False)
            rec.state(core, kf.x[:, None, :])
        else:
            out = core.step(pol.act(obs, mask))
            obs, mask = out.obs, out.action_mask
            rec.state(core)
            rec.step(core.transmit, out.reward)
        k += 1
        end[(out.terminated | out.truncated) & (end < 0)] = k
    return rec.records(end)
