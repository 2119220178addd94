"""Benchmark harness: metrics on hand-made curves, the centralized KF oracle against a
hand-written scalar Kalman recursion, and short end-to-end runs with scripted policies."""

import csv
import math

import numpy as np
import pytest

from netsense import benchmark as bm
from netsense.cli import main
from netsense.systems.plants import Plant


# ----------------------------------------------------------------------------- metrics
def test_relative_errors_use_the_floor():
    rel = bm.relative_errors(np.array([[1.0, 2.0], [1.0, 0.0]]), np.array([2.0, 0.0]),
                             floor=0.5)
    np.testing.assert_array_equal(rel, [[0.5, 1.0], [2.0, 0.0]])


@pytest.mark.parametrize(("worst", "expected"), [
    ([1.0, 0.5, 0.001, 0.001], 2.0),      # below from k = 2 on
    ([1.0, 0.001, 0.5, 0.001], 3.0),      # dips then rises: only the last entry counts
    ([0.001, 0.001], 0.0),                 # below from the start
    ([1.0, 0.001, 0.5], math.nan),         # above at the end: never reached
    ([1.0, np.nan, 0.001], 2.0),           # NaN counts as above
])
def test_steps_to_epsilon(worst, expected):
    rel = np.column_stack([np.array(worst), np.zeros(len(worst))])  # max over agents
    got = bm.steps_to_epsilon(rel, 0.01)
    assert (math.isnan(got) and math.isnan(expected)) or got == expected


def test_steps_to_epsilon_rejects_bad_eps():
    with pytest.raises(ValueError, match="eps"):
        bm.steps_to_epsilon(np.zeros((3, 1)), 0.0)


def test_aoi_statistics_ignore_diagonal_and_omega():
    tau = np.array([[[0, -1], [3, 0]], [[0, 1], [-1, 0]]])  # (K+1=2, N=2, N=2)
    s = bm.aoi_statistics(tau)
    assert s == {"aoi_mean": 2.0, "aoi_max": 3.0, "aoi_omega_frac": 0.5}
    assert all(math.isnan(v) for v in bm.aoi_statistics(None).values())


def test_aoi_statistics_with_source_columns():
    # N = 3 agents, M = 2 substates (sources 0 and 2): agent 0 owns column 0, agent 2
    # column 1, agent 1 none; the own entries (always 0 here) do not count
    tau = np.array([[[0, -1], [4, 2], [-1, 0]]])  # (K+1=1, N=3, M=2)
    s = bm.aoi_statistics(tau, own=np.array([0, -1, 1]))
    assert s == {"aoi_mean": 3.0, "aoi_max": 4.0, "aoi_omega_frac": 0.5}
    with pytest.raises(ValueError, match="pass own"):
        bm.aoi_statistics(tau)
    with pytest.raises(ValueError, match="own must hold"):
        bm.aoi_statistics(tau, own=np.array([0, 2, 1]))


def test_episode_metrics_by_hand():
    rec = bm.EpisodeRecord(
        errors=np.array([[1.0, 1.0], [0.5, 0.1], [0.0, 0.0]]), x_norm=np.array([1.0, 1.0, 2.0]),
        messages=np.array([[1, 0], [1, 1]], bool), aoi=None,
        rewards=np.array([[-1.0, -2.0], [0.0, -1.0]]))
    m = bm.episode_metrics(rec, eps=0.01)
    assert m["mean_rel_error"] == pytest.approx((0.5 + 0.1) / 4)
    assert m["final_rel_error"] == 0.0
    assert m["steps_to_eps"] == 2.0
    assert m["msgs_per_agent_step"] == 0.75
    assert m["reward"] == pytest.approx(-2.0)  # returns -1 and -3, mean over agents
    assert list(m) == list(bm.METRICS)


def test_make_jobs_validates_and_expands_learned_paths():
    jobs = bm.make_jobs(["a-v0", "b-v0"], ["freshness", "learned:runs/{scenario}/p.zip"],
                        [0, 1])
    assert len(jobs) == 8
    assert jobs[2].policy == "learned:runs/a-v0/p.zip"
    with pytest.raises(ValueError, match="unknown policy"):
        bm.make_jobs(["a-v0"], ["freshnes"], [0])
    with pytest.raises(ValueError, match="backend"):
        bm.execute([], backend="threads")


@pytest.mark.parametrize("backend, workers, msg", [
    ("batched", 2, "does not take it"), ("serial", 1, "does not take it"),
    ("process", 0, "workers must be >= 1"), ("process", -2, "workers must be >= 1"),
    ("process", 2.0, "positive integer"), ("process", True, "positive integer")])
def test_execute_refuses_workers_it_would_ignore_or_misread(backend, workers, msg):
    ran = []
    jobs = bm.make_jobs(["fig1_scalar-v0"], ["freshness"], [0])
    with pytest.raises(ValueError, match=msg):
        bm.execute(jobs, backend=backend, workers=workers, progress=False,
                   runner=lambda job: ran.append(job))
    assert ran == []  # refused before any job ran


def test_benchmark_command_refuses_workers_without_the_process_backend(tmp_path, capsys):
    from netsense.cli import main

    assert main(["benchmark", "fig1_scalar-v0", "--out", str(tmp_path / "o"),
                 "--workers", "2", "--no-progress"]) == 2  # a usage error, one line
    assert "needs --backend process" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_markdown_table_shows_mean_std_and_reach_counts():
    results = [{"job": {"scenario": "s", "policy": "p", "seed": k},
                "metrics": {**dict.fromkeys(bm.METRICS, 1.0 + k),
                            "steps_to_eps": [3.0, math.nan][k]}} for k in range(2)]
    rows = bm.aggregate(results)
    assert rows[0]["mean_rel_error_mean"] == 1.5 and rows[0]["reached_eps"] == 1
    table = bm.markdown_table(rows)
    assert "| s | p | 1.5 ± 0.5 |" in table and "3 (1/2)" in table


# ----------------------------------------------------------------------------- oracle
def test_centralized_kf_matches_scalar_riccati_recursion():
    a, sigma, s0 = 1.5, 0.3, 2.0
    from netsense.sensing import GaussianNoise

    plant = Plant(A=[[a]], C=(np.ones((1, 1)), np.zeros((0, 1))),
                  measurement_noise=GaussianNoise(sigma))
    kf = bm.CentralizedKF(plant, x0_std=s0, jitter=1e-300)
    rng = np.random.default_rng(0)
    xh, P = 0.0, s0**2  # hand-written predictor form: update with y[k], predict x[k+1]
    for _ in range(20):
        y = rng.normal(size=1)
        K = P / (P + sigma**2)
        xh, P = a * (xh + K * (y[0] - xh)), a * a * (1 - K) * P
        kf.step(np.array([[y[0]], [0.0]]))
        assert kf.estimate[0] == pytest.approx(xh, rel=1e-12)
        assert kf.P[0, 0] == pytest.approx(P, rel=1e-10)


def test_centralized_kf_skips_missing_measurements():
    plant = Plant(A=[[2.0]], C=(np.ones((1, 1)),))
    kf = bm.CentralizedKF(plant)
    kf.step(np.array([[5.0]]), arrived=np.array([False]))
    assert kf.estimate[0] == 0.0  # nothing arrived: pure prediction of the zero prior
    kf.step(np.array([[5.0]]))
    assert kf.estimate[0] == pytest.approx(10.0, rel=1e-6)  # noise-free: y trusted


# ------------------------------------------------------------------------ end-to-end
def test_fig1_benchmark_orders_policies_and_writes_outputs(tmp_path):
    policies = ["freshness", "uniform_consensus", "tree_consensus", "open_loop", "random",
                "kf_oracle"]
    results, rows = bm.run_benchmark(["fig1_scalar-v0"], policies, [0, 1], out=tmp_path,
                                     backend="serial", progress=False)
    by = {r["policy"]: r for r in rows}
    assert set(by) == set(policies)
    fresh, oracle, open_loop = by["freshness"], by["kf_oracle"], by["open_loop"]
    # deadbeat source + freshness: exact after a few steps; open loop never converges
    assert fresh["final_rel_error_mean"] < 1e-9 and fresh["reached_eps"] == 2
    assert open_loop["reached_eps"] == 0 and open_loop["msgs_per_agent_step_mean"] == 0
    assert fresh["msgs_per_agent_step_mean"] == 1.0
    # the oracle sees every measurement: no policy has a smaller mean error
    assert all(oracle["mean_rel_error_mean"] <= r["mean_rel_error_mean"] for r in rows)
    assert fresh["reward_mean"] > open_loop["reward_mean"]
    for name in ("episodes.csv", "summary.csv", "summary.md", "errors_fig1_scalar-v0.png",
                 "reward_vs_messages.png"):
        assert (tmp_path / name).stat().st_size > 0
    with (tmp_path / "episodes.csv").open() as fh:
        assert len(list(csv.DictReader(fh))) == 12


def test_same_seed_same_numbers_across_processes(tmp_path):
    jobs = bm.make_jobs(["message_cost-v0"], ["random", "freshness"], [3],
                        overrides={"horizon": 15})
    serial = bm.execute(jobs, backend="serial", progress=False)
    procs = bm.execute(jobs, backend="process", workers=2, progress=False)
    for a, b in zip(serial, procs, strict=True):
        np.testing.assert_equal(a["metrics"], b["metrics"])  # NaN == NaN here


def test_benchmark_command(tmp_path, capsys):
    assert main(["benchmark", "fig1_scalar-v0", "--policies", "freshness", "kf_oracle",
                 "--seeds", "1", "--out", str(tmp_path), "--backend", "serial",
                 "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "| fig1_scalar-v0 | freshness |" in out
    assert (tmp_path / "summary.md").exists()


def test_heavy_dependencies_stay_lazy():
    import subprocess
    import sys

    code = ("import sys, netsense, netsense.benchmark, netsense.rl, netsense.rl.wrappers, "
            "netsense.rl.rllib, netsense.rl.torchrl; from netsense.cli import build_parser; "
            "build_parser(); heavy = [m for m in ('torch', 'stable_baselines3', 'sb3_contrib', "
            "'supersuit', 'ray', 'torchrl') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"
