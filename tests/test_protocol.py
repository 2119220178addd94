"""The evaluation protocol: seeds, bootstrap intervals, the frontier outputs, learned points,
and the calibration claims of the communication scenarios."""

from __future__ import annotations

import csv

import numpy as np
import pytest

import netsense.benchmark as bm
from netsense.benchmark import protocol as pr
from netsense.cli import main


def test_eval_seeds_are_disjoint_from_training_seeds():
    seeds = pr.eval_seeds()
    assert len(seeds) == pr.DEFAULT_EPISODES >= 100
    assert min(seeds) == pr.EVAL_SEED0 >= pr.TRAIN_SEED_LIMIT
    pr.check_disjoint(range(0, 64), seeds)
    with pytest.raises(ValueError, match="used in training"):
        pr.check_disjoint([pr.EVAL_SEED0 + 3], seeds)
    with pytest.raises(ValueError):
        pr.eval_seeds(0)


def test_bootstrap_interval_contains_the_mean_and_is_reproducible():
    rng = np.random.default_rng(0)
    v = rng.standard_normal(100) + 3
    mean, lo, hi = pr.bootstrap_ci(v)
    assert mean == pytest.approx(v.mean()) and lo < mean < hi
    # about the normal-theory half-width 1.96 s / sqrt(n)
    half = 1.96 * v.std(ddof=1) / 10
    assert 0.8 * half < (hi - lo) / 2 < 1.2 * half
    assert pr.bootstrap_ci(v) == (mean, lo, hi)
    assert pr.bootstrap_ci([2.0] * 5) == (2.0, 2.0, 2.0)
    assert all(np.isnan(pr.bootstrap_ci([1.0, np.nan])))


def test_protocol_metrics_equal_the_benchmark_metrics():
    seeds = [pr.EVAL_SEED0 + i for i in range(4)]
    over = {"horizon": 30}
    vals = pr.evaluate("comm_process_noise-v0", "event:2", seeds, over)
    jobs = bm.make_jobs(["comm_process_noise-v0"], ["event:2"], seeds, overrides=over)
    res = bm.execute(jobs, progress=False)
    for m in ("mean_rel_error", "final_rel_error", "msgs_per_agent_step", "reward"):
        np.testing.assert_allclose(vals[m], [r["metrics"][m] for r in res], rtol=1e-12)
    np.testing.assert_array_equal(vals["load_per_agent_step"], vals["msgs_per_agent_step"])


def test_on_step_sees_every_step_of_every_live_member():
    """The hook runs once per step with the members still in their episode; what it records
    adds up to the protocol's own metric (messages per agent-step)."""
    seeds = [pr.EVAL_SEED0 + i for i in range(3)]
    sent, lives = [], []

    def record(core, live):
        sent.append(core.transmit.sum(1) / core.N)
        lives.append(live)

    vals = pr.evaluate("comm_channel_k2-v0", "tdma:1", seeds, {"horizon": 25},
                       on_step=record)
    assert len(sent) == 25 and all(lv.all() for lv in lives)
    np.testing.assert_allclose(np.mean(sent, 0), vals["msgs_per_agent_step"], rtol=1e-12)


def test_benchmark_summary_has_intervals():
    _, rows = bm.run_benchmark(["comm_channel_k2-v0"], ["bernoulli:0.2"], range(6),
                               overrides={"horizon": 10}, progress=False)
    r = rows[0]
    assert r["reward_ci_low"] <= r["reward_mean"] <= r["reward_ci_high"]


def _read(path):
    with path.open() as fh:
        return list(csv.DictReader(fh))


def test_smoke_frontier_writes_png_and_csv(tmp_path):
    fams = {"periodic": (1, 5), "whittle": (2,)}
    rows = pr.run_frontier(["comm_channel_k2-v0", "fig1_scalar-v0"], tmp_path, episodes=3,
                           families=fams, overrides={"horizon": 12}, progress=False,
                           informed_bases=(), settled_bases=())  # (the wrapped rules:
    # test_comm_informed.py)
    for sc in ("comm_channel_k2-v0", "fig1_scalar-v0"):
        png, table = tmp_path / f"frontier_{sc}.png", tmp_path / f"frontier_{sc}.csv"
        assert png.stat().st_size > 10_000
        with table.open() as fh:
            assert next(csv.reader(fh)) == list(pr.CSV_COLUMNS)
        got = _read(table)
        assert [r["policy"] for r in got] == ["always", "never", "periodic:1", "periodic:5",
                                              "whittle:2"]
        for r in got:
            assert r["episodes"] == "3" and r["seed_first"] == str(pr.EVAL_SEED0)
            for m in pr.PROTOCOL_METRICS:
                lo, mean, hi = (float(r[f"{m}_{s}"]) for s in ("ci_low", "mean", "ci_high"))
                assert lo <= mean <= hi
    assert {r["control"] for r in rows} == {"transmit"}  # fig1 runs transmit-only
    assert len(_read(tmp_path / "frontier.csv")) == 10
    md = (tmp_path / "frontier.md").read_text()
    assert "| fig1_scalar-v0 | decentralised | periodic:5 |" in md
    # Pareto: never (no messages) always is; a dominated point is not
    flags = {r["policy"]: r["pareto"] for r in rows if r["scenario"] == "comm_channel_k2-v0"}
    assert flags["never"] and not flags["periodic:1"]


def test_frontier_command(tmp_path, capsys):
    assert main(["benchmark", "comm_substates-v0", "--frontier", "--seeds", "2",
                 "--families", "event", "--override", "horizon=8", "--out", str(tmp_path),
                 "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "| comm_substates-v0 | decentralised | event:16 |" in out
    rows = _read(tmp_path / "frontier_comm_substates-v0.csv")
    assert {r["control"] for r in rows} == {"substates"}


def test_learned_points_greedy_and_sampled(tmp_path):
    pytest.importorskip("sb3_contrib")
    run = tmp_path / "run"
    over = ["--override", "horizon=10"]
    assert main(["train", "comm_channel_k2-v0", "--backend", "sb3", "--steps", "800",
                 "--out", str(run),
                 "--n-steps", "32", "--batch-size", "64", "--num-envs", "2", *over,
                 "--no-progress"]) == 0
    path = str(run / "policy.zip")
    rows = pr.frontier("comm_channel_k2-v0", episodes=3, families={}, learned=[path],
                       overrides={"horizon": 10}, progress=False, settled_bases=())
    learned = [r for r in rows if r["family"] == "learned"]
    assert [r["evaluation"] for r in learned] == ["greedy", "sampled"]
    assert all(r["control"] == "transmit" for r in learned)
    again = pr.evaluate("comm_channel_k2-v0", f"learned_sampled:{path}",
                        pr.eval_seeds(3), {"horizon": 10})
    assert again["reward"].mean() == pytest.approx(learned[1]["reward_mean"], rel=1e-12)
    # greedy: the batched evaluation equals the benchmark's episodes through the env
    greedy = pr.evaluate("comm_channel_k2-v0", f"learned:{path}", pr.eval_seeds(3),
                         {"horizon": 10})
    jobs = bm.make_jobs(["comm_channel_k2-v0"], [f"learned:{path}"], pr.eval_seeds(3),
                        overrides={"horizon": 10})
    res = bm.execute(jobs, backend="serial", progress=False)
    np.testing.assert_allclose(greedy["reward"], [r["metrics"]["reward"] for r in res],
                               rtol=1e-9)


@pytest.mark.parametrize("sid,best", [("comm_process_noise-v0", "sources:0"),
                                      ("comm_substates-v0", "event:1"),
                                      ("comm_channel_k2-v0", "whittle:2")])
def test_calibration_neither_always_nor_never_is_optimal(sid, best):
    """The claim of each scenario's docs, on 24 of the evaluation seeds: an intermediate
    policy of the frontier beats both ends on the reward."""
    seeds = pr.eval_seeds(24)
    r = {p: pr.evaluate(sid, p, seeds)["reward"] for p in ("always", "never", best)}
    for end in ("always", "never"):
        assert r[best].mean() > r[end].mean() + 5, (end, {k: v.mean() for k, v in r.items()})
    assert 0 < pr.evaluate(sid, best, seeds[:4])["msgs_per_agent_step"].mean() < 1


def test_comm_training_config_matches_the_committed_runs():
    """experiments/rl/configs/train_comm_tasks.toml is what trained the committed policies of
    the communication tasks, on seeds below the evaluation range."""
    import json
    from pathlib import Path

    from experiment_loader import load_experiment

    pytest.importorskip("sb3_contrib")
    root = Path(__file__).resolve().parents[1]
    train = load_experiment("rl/train_maskable_ppo")
    configs = train.load_configs(root / "experiments/rl/configs/train_comm_tasks.toml")
    assert set(configs) == {"comm_process_noise-v0", "comm_substates-v0", "comm_channel_k2-v0"}
    for sc, cfg in configs.items():
        run = root / "experiments/results/rl/train_maskable_ppo" / sc
        meta = json.loads((run / "train_config.json").read_text())
        assert meta["overrides"] == cfg.overrides and meta["steps"] == cfg.steps
        assert meta["seed"] + meta["num_vec_envs"] <= pr.TRAIN_SEED_LIMIT
        assert meta["mask_violations"] == 0
