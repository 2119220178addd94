"""The batched benchmark backend against the per-episode one, and the per-member pieces it
needs (random policy generators, the batched centralized KF)."""

import math

import numpy as np
import pytest
from experiment_loader import load_experiment

from netsense import benchmark as bm
from netsense.benchmark import backends
from netsense.cli import build_parser, main

#: metrics computed from integers (transmissions, indices): equal, not just close
_EXACT = ("msgs_per_agent_step", "aoi_mean", "aoi_max", "aoi_omega_frac", "steps_to_eps")


def _assert_same_results(batched, serial):
    """Same jobs in the same order, same metrics and curves (test_vector's tolerance for
    the errors: the batch and the single env may differ in the last bits of products)."""
    assert [r["job"] for r in batched] == [r["job"] for r in serial]
    for a, b in zip(batched, serial, strict=True):
        for m in bm.METRICS:
            x, y = a["metrics"][m], b["metrics"][m]
            if m in _EXACT:
                assert x == y or (math.isnan(x) and math.isnan(y)), (a["job"], m, x, y)
            else:
                np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-12,
                                           err_msg=f"{a['job']} {m}")
        assert a["curve"].shape == b["curve"].shape, a["job"]
        np.testing.assert_allclose(a["curve"], b["curve"], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(("scenario", "policies", "overrides"), [
    # every scripted policy and the oracle; deadbeat source, periodic graphs (tree applies)
    ("fig1_scalar-v0", ["freshness", "uniform_consensus", "tree_consensus", "open_loop",
                        "random", "kf_oracle"], {"horizon": 12}),
    # random graphs: tree consensus does not apply and is skipped by both backends
    ("message_cost-v0", ["random", "kf_oracle", "tree_consensus"], {"horizon": 15}),
    # measurement drops: the members' oracles update with different measurement rows;
    # a KFIO source estimator (stateful, per member)
    ("drops_kfio-v0", ["random", "kf_oracle", "freshness"], {"horizon": 15}),
    # divergence: members end at their own step
    ("random_structured_n20_N10-v0", ["open_loop", "random", "kf_oracle"],
     {"horizon": 40, "divergence_limit": 3.0}),
    # one index column per source (M = 20 < N = 100)
    ("large_n20_N100-v2", ["freshness", "random", "kf_oracle"], {"horizon": 4}),
])
def test_batched_backend_equals_serial_per_seed(scenario, policies, overrides):
    jobs = bm.make_jobs([scenario], policies, [0, 1, 2, 5], overrides=overrides)
    batched = bm.execute(jobs, backend="batched", progress=False)
    serial = bm.execute(jobs, backend="serial", progress=False)
    _assert_same_results(batched, serial)
    ran = {r["job"]["policy"] for r in batched}
    assert ran == set(policies) - ({"tree_consensus"} if scenario != "fig1_scalar-v0" else set())
    rand = [r for r in batched if r["job"]["policy"] == "random"]
    assert len({r["metrics"]["mean_rel_error"] for r in rand}) > 1  # seeds really differ
    if "divergence_limit" in overrides:
        lengths = {r["curve"].shape[0] for r in batched if r["job"]["policy"] == "open_loop"}
        assert len(lengths) > 1 and max(lengths) == 41


def test_batched_groups_interleaved_jobs_and_keeps_their_order(monkeypatch):
    import netsense.benchmark.batched as vec

    over = {"horizon": 10}
    J = bm.Job
    jobs = [J("fig1_scalar-v0", "random", 4, over), J("message_cost-v0", "freshness", 1, over),
            J("fig1_scalar-v0", "kf_oracle", 2, over), J("fig1_scalar-v0", "random", 2, over),
            J("message_cost-v0", "freshness", 0, {"horizon": 12}),
            J("message_cost-v0", "freshness", 7, over), J("fig1_scalar-v0", "random", 9, over)]
    calls = []
    real = vec.rollout_seeds

    def spy(scenario, policy, seeds, overrides=None):
        calls.append((policy, list(seeds)))
        return real(scenario, policy, seeds, overrides)

    monkeypatch.setattr(vec, "rollout_seeds", spy)
    batched = bm.execute(jobs, backend="batched", progress=False)
    # one batch per (scenario, policy, overrides), seeds in job order
    assert calls == [("random", [4, 2, 9]), ("freshness", [1, 7]), ("kf_oracle", [2]),
                     ("freshness", [0])]
    _assert_same_results(batched, bm.execute(jobs, backend="serial", progress=False))
    assert [r["job"]["seed"] for r in batched] == [4, 1, 2, 2, 0, 7, 9]
    assert [len(r["curve"]) for r in batched] == [11, 11, 11, 11, 13, 11, 11]


def test_batched_splits_groups_beyond_the_memory_budget(monkeypatch):
    import netsense.benchmark.batched as vec

    jobs = bm.make_jobs(["message_cost-v0"], ["freshness"], range(5), overrides={"horizon": 8})
    sizes, done = [], []
    real = vec.rollout_seeds

    def spy(scenario, policy, seeds, overrides=None):
        sizes.append(len(seeds))
        return real(scenario, policy, seeds, overrides)

    monkeypatch.setattr(vec, "rollout_seeds", spy)
    monkeypatch.setattr(backends, "_members_per_batch", lambda model: 2)
    out = bm.run_batched(jobs, on_done=done.append)
    assert sizes == [2, 2, 1] and done == [2, 2, 1]
    _assert_same_results(out, bm.execute(jobs, backend="serial", progress=False))


def test_batched_runs_learned_policies_through_the_per_job_runner():
    seen = []

    def runner(job):
        seen.append(job.seed)
        return {"job": {"seed": job.seed, "policy": job.policy}, "metrics": {}, "curve": None}

    jobs = bm.make_jobs(["fig1_scalar-v0"], ["learned:runs/p.zip", "open_loop"], [3, 4],
                        overrides={"horizon": 5})
    out = bm.execute(jobs, backend="batched", progress=False, runner=runner)
    assert seen == [3, 4]  # only the learned jobs, in order
    assert [(r["job"]["policy"], r["job"]["seed"]) for r in out] == [
        ("learned:runs/p.zip", 3), ("learned:runs/p.zip", 4), ("open_loop", 3),
        ("open_loop", 4)]
    assert out[2]["metrics"]["msgs_per_agent_step"] == 0.0  # open loop ran batched


def test_backend_choices_are_checked_and_batched_is_the_default():
    with pytest.raises(ValueError, match="backend must be one of 'batched'"):
        bm.execute([], backend="threads")
    cmd = next(a for a in build_parser()._actions if a.dest == "command").choices["benchmark"]
    args = cmd.parse_args(["fig1_scalar-v0", "--out", "x"])
    assert args.backend == "batched"
    with pytest.raises(SystemExit):
        cmd.parse_args(["fig1_scalar-v0", "--out", "x", "--backend", "threads"])


def test_benchmark_command_with_batched_backend(tmp_path, capsys):
    assert main(["benchmark", "fig1_scalar-v0", "--policies", "freshness", "random",
                 "kf_oracle", "--seeds", "3", "--out", str(tmp_path), "--backend", "batched",
                 "--no-progress", "--override", "horizon=10"]) == 0
    out = capsys.readouterr().out
    assert "| fig1_scalar-v0 | random |" in out and "(3/3)" in out
    rows = (tmp_path / "episodes.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 9


# ------------------------------------------------------------------ per-member pieces
def test_random_policy_member_generators_equal_single_policies():
    from netsense.engine.core import BatchedCore
    from netsense.env.policies import make_policy
    from netsense.env.vector import load_model

    model, _ = load_model("message_cost-v0", horizon=6)
    core = BatchedCore(model, 3)
    obs, mask = core.reset([5, 6, 7])
    batch = make_policy("random", core, seed=[11, 12, 13])
    singles = [make_policy("random", core, seed=s) for s in (11, 12, 13)]
    for _ in range(4):
        a = batch.act(obs, mask)
        for b, pol in enumerate(singles):
            np.testing.assert_array_equal(a[b], pol.act(obs[b:b + 1], mask[b:b + 1])[0])
        obs, mask = core.step(a).obs, core.observe()[1]
    assert not np.array_equal(a[0], a[1])
    with pytest.raises(ValueError, match="3 member generators"):
        batch.act(obs[:2], mask[:2])
    with pytest.raises(ValueError, match="non-empty"):
        make_policy("random", core, seed=[])


def test_batched_kf_equals_one_filter_per_member():
    from netsense.sensing import GaussianNoise
    from netsense.systems.plants import Plant

    plant = Plant(A=[[1.1, 0.2], [0.0, 0.9]], C=(np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]]),
                                                 np.array([[1.0, 1.0]])),
                  measurement_noise=GaussianNoise(0.1), process_noise=GaussianNoise(0.05))
    B = 4
    kf = bm.CentralizedKF(plant, x0_std=2.0, batch_size=B)
    singles = [bm.CentralizedKF(plant, x0_std=2.0) for _ in range(B)]
    rng = np.random.default_rng(1)
    for k in range(12):
        y = rng.normal(size=(B, 3, 1))
        arrived = rng.random((B, 3)) < 0.6  # different rows per member
        live = np.arange(B) != k % B  # one member paused each step
        kf.step(y, arrived, members=live)
        for b in np.flatnonzero(live):
            singles[b].step(y[b], arrived[b])
        for b in range(B):
            np.testing.assert_allclose(kf.x[b], singles[b].x, rtol=1e-12, atol=1e-14)
            np.testing.assert_allclose(kf.P[b], singles[b].P, rtol=1e-12, atol=1e-14)
    assert kf.x.shape == (B, 2) and singles[0].estimate.shape == (2,)
    assert not np.allclose(kf.x[0], kf.x[1])
    with pytest.raises(ValueError, match="y_padded must have shape"):
        kf.step(np.zeros((3, 1)))
    with pytest.raises(ValueError, match="members needs a batched filter"):
        singles[0].step(y[0], members=np.ones(1, bool))
    with pytest.raises(ValueError, match="batch_size"):
        bm.CentralizedKF(plant, batch_size=0)


def test_backend_timing_experiment_smoke(tmp_path):
    mod = load_experiment("bench/benchmark_backends")
    out = tmp_path / "t.txt"
    report = mod.main(["--seeds", "2", "--horizon", "4", "--backends", "batched", "serial",
                       "--out", str(out)])
    assert out.read_text() == report
    assert "20 episodes" in report and "results of every backend equal" in report
    rows = [ln.split() for ln in report.splitlines() if ln.startswith(("batched", "serial"))]
    assert [r[0] for r in rows] == ["batched", "serial"] and float(rows[0][3]) == 1.0
