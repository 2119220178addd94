"""The certified upper bounds (:mod:`netsense.benchmark.upper_bound`): the engine's own
ages and errors are what the relaxation assumes, the bound is at least the exact optimum
on instances small enough to enumerate, and no evaluated policy of any kind scores above
it on any episode of the committed results."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linprog

from netsense.benchmark.protocol import frontier_overrides
from netsense.benchmark.upper_bound import (
    _dual_bound,
    age_recursion,
    episode_data,
    exhaustive_optimum,
    upper_bound,
)
from netsense.engine.core import BatchedCore
from netsense.env.registry import build_model, load_file
from netsense.env.vector import load_model

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests/data/tiny"
RESULTS = ROOT / "experiments/results/rl"


def _tiny(name: str):
    return build_model(load_file(TINY / f"{name}.toml"))


@pytest.mark.parametrize("task", ["comm_channel_k2-v0", "comm_fading-v0", "comm_substates-v0"])
def test_age_recursion_is_the_engines(task):
    """The recursion the relaxation encodes reproduces the engine's freshness indices
    under random bits (links, drops and collisions from the recorded realisation)."""
    model, _ = load_model(task, **frontier_overrides(task))
    data = episode_data(task, [1_000_000, 1_000_001])
    core = BatchedCore(model, 2)
    _, mask = core.reset([1_000_000, 1_000_001])
    rng = np.random.default_rng(0)
    width = mask.shape[2] // 2
    for k in range(40):
        tau, tx = core.tau.copy(), core.transmit.copy()
        bits = (rng.random((2, core.N, width)) < 0.4).astype(np.int64)
        bits &= mask[..., 1::2].astype(np.int64)
        sent_sub = core.comm.sent.copy() if core.comm.per_substate else None
        out = core.step(bits)
        mask = out.action_mask
        for b in range(2):
            deliver = tx[b].copy()
            if data[b].capacity is not None and tx[b].sum() > data[b].capacity:
                deliver[:] = False
            sent = deliver[:, None] & (np.ones((core.N, core.M), bool) if sent_sub is None
                                       else sent_sub[b])
            want = age_recursion(tau[b], data[b].nbr[k], data[b].arrive[k], sent,
                                 data[b].own)
            np.testing.assert_array_equal(core.tau[b], want, err_msg=f"step {k}")


def test_errors_are_a_function_of_the_ages():
    """On a plant whose Lemma-1 form is block diagonal every substate is exact, and the
    engine's error of every agent equals the one the tables give at the engine's ages."""
    task = "comm_process_noise-v0"
    model, _ = load_model(task, **frontier_overrides(task))
    (data,) = episode_data(task, [1_000_003])
    assert data.exact.all()
    core = BatchedCore(model, 1)
    _, mask = core.reset([1_000_003])
    rng = np.random.default_rng(1)
    for k in range(1, 60):
        core.step((rng.random((1, core.N, 1)) < 0.3).astype(np.int64))
        tau = core.tau[0]
        d = np.empty((core.N, core.M))
        for i in range(core.N):
            for j in range(core.M):
                d[i, j] = (data.dist_omega[i, j, k] if tau[i, j] < 0
                           else data.dist[j, k, tau[i, j]])
        want = np.minimum(np.linalg.norm(d, axis=1) / data.scale[k], data.error_clip)
        np.testing.assert_allclose(core.errors[0], want, rtol=1e-9, atol=1e-12)


def test_dual_bound_is_weak_duality():
    """Any non-negative multipliers give a value at least the LP optimum (random LPs,
    against HiGHS's optimum)."""
    rng = np.random.default_rng(2)
    for _ in range(5):
        A = rng.normal(size=(6, 8))
        b = rng.random(6) + 0.5
        c = rng.normal(size=8)
        lo, hi = np.zeros(8), np.ones(8)
        res = linprog(-c, A_ub=A, b_ub=b, bounds=np.stack([lo, hi], 1), method="highs")
        opt = -res.fun
        assert _dual_bound(A, b, c, lo, hi, -res.ineqlin.marginals) == pytest.approx(opt)
        for _ in range(5):
            assert _dual_bound(A, b, c, lo, hi, rng.random(6) * 3) >= opt - 1e-12


@pytest.mark.slow  # 20-50 s each: the enumeration of every joint policy
@pytest.mark.parametrize("name", ["base", "channel", "fading", "schedule", "coupled",
                                  "substates"])
def test_bound_holds_the_enumerated_optimum(name):
    """N = 3 agents, every transmit sequence enumerated (2^15; per-substate bits 2^12):
    the bound is at least the best return any sequence reaches."""
    model = _tiny(name)
    for seed in (1, 2):
        best, count = exhaustive_optimum(model, seed)
        assert count >= 1 << 12
        (data,) = episode_data(model, [seed])
        ub = upper_bound(data, window=5, rounds=2)
        assert ub.value >= best - 1e-9, (name, seed, ub.value, best)
        if data.exact.all():  # tight where every substate is exact (a few hundredths)
            assert ub.value - best < 0.05 * abs(best), (name, seed, ub.value, best)


def test_bound_is_above_live_policies():
    """One episode of a task with drops: the bound is above scripted and privileged
    policies evaluated now (not only the committed files)."""
    from netsense.benchmark.protocol import evaluate

    task, seeds = "comm_fading-v0", [1_000_050]
    (data,) = episode_data(task, seeds)
    ub = upper_bound(data, window=8, rounds=1)
    for policy in ("always", "never", "event:1", "acked(sources:0)", "oracle(event:1)"):
        assert evaluate(task, policy, seeds)["reward"][0] <= ub.value + 1e-9, policy


def test_bad_arguments_are_refused():
    (data,) = episode_data(_tiny("base"), [1])
    with pytest.raises(ValueError, match="window"):
        upper_bound(data, window=1)
    with pytest.raises(ValueError, match="rounds"):
        upper_bound(data, rounds=0)
    with pytest.raises(ValueError, match="time_limit"):
        upper_bound(data, time_limit=0)
    with pytest.raises(ValueError, match="seeds"):
        episode_data(_tiny("base"), [])


def _rows(path: Path) -> list[dict]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


def test_no_committed_policy_beats_the_bound():
    """Every evaluated policy of every kind, on every episode that has a bound: scripted
    (decentralised, informed, centralised), privileged, the lookahead references and the
    committed learned policies."""
    bounds = {(r["scenario"], int(r["seed"])): float(r["upper_bound"])
              for r in _rows(RESULTS / "upper_bounds/episodes.csv")}
    tasks = {t for t, _ in bounds}
    assert len(tasks) == 9 and all(sum(t == u for u, _ in bounds) >= 20 for t in tasks)
    checked = 0
    sources = [(r["scenario"], r["policy"], int(r["seed"]), float(r["reward"]))
               for r in _rows(RESULTS / "upper_bounds/policies.csv")]
    sources += [(r["scenario"], r["policy"], int(r["seed"]), float(r["reward"]))
                for r in _rows(RESULTS / "comm_bounds/episodes.csv")]
    sources += [(r["task"], r["learner"], int(r["episode_seed"]), float(r["return"]))
                for r in _rows(RESULTS / "suite_scores/episodes.csv")]
    for path in sorted((RESULTS / "learners").glob("**/episodes.csv")):  # every learner
        sources += [(r["task"], "learned", 1_000_000 + int(r["episode"]), float(r["reward"]))
                    for r in _rows(path) if r["evaluation"] in ("greedy", "sampled",
                                                                "best-validated")]
    kinds = set()
    for task, policy, seed, ret in sources:
        if (task, seed) in bounds:
            assert ret <= bounds[task, seed] + 1e-9, (task, policy, seed, ret)
            checked += 1
            kinds.add(policy.split("(")[0].split(":")[0])
    assert checked > 10_000
    assert {"reference", "oracle", "gated", "acked", "phased", "whittle", "learned"} <= kinds
