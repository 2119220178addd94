"""Many training runs (netsense.rl.launch): the same files and weights in this process, in
worker processes and as Ray tasks; a failed run is reported and the others finish."""

from __future__ import annotations

import csv
import json
import os
from dataclasses import replace
from pathlib import Path

import pytest

pytest.importorskip("torchrl")

#: Columns of log.csv that measure time (they differ between any two runs).
TIMING = {"wall_s", "agent_steps_per_s", "collect_s", "learn_s"}


def _tiny(**kw):
    from netsense.rl.config import PPOConfig

    # two iterations of 4 x 8 env-steps, evaluated and checkpointed after each
    return PPOConfig("message_cost-v1", steps=2 * 4 * 8 * 10, num_envs=4, rollout=8,
                     minibatch=16, epochs=2, eval_interval=1, eval_envs=2,
                     overrides={"horizon": 12}, **kw)


def _runs():
    from netsense.rl.launch import Run, make_runs

    cfg = _tiny()
    # a run that fails when it starts: a learner device this machine does not have (a
    # config checks the device's name only, so that GPU-trained policies load anywhere)
    bad = Run(replace(cfg, device="cuda:97"), "bad")
    return [*make_runs({"mappo": cfg}, [0, 1]), bad]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The runs trained one after another in this process."""
    from netsense.rl.launch import launch

    out = tmp_path_factory.mktemp("in_process")
    return out, launch(_runs(), out, progress=False)


def _files(root: Path) -> set[str]:
    # TensorBoard names its event file after the clock and the host: count them instead
    return {p.relative_to(root).as_posix() for p in root.rglob("*")
            if p.is_file() and "/tb/" not in f"/{p.relative_to(root).as_posix()}"}


def _log(path: Path) -> list[dict]:
    with path.open() as fh:
        return [{k: v for k, v in row.items() if k not in TIMING} for row in csv.DictReader(fh)]


def _same_as_reference(reference, out: Path, summary: list[dict]) -> None:
    import torch

    ref_out, ref = reference
    assert _files(out) == _files(ref_out)
    for folder in ("mappo/seed_0", "mappo/seed_1"):
        assert len(list((out / folder / "tb").iterdir())) == 1
        assert _log(out / folder / "log.csv") == _log(ref_out / folder / "log.csv")
        for name in ("policy.pt", "checkpoint_00001.pt", "checkpoint_00002.pt"):
            a = torch.load(ref_out / folder / name, weights_only=True)
            b = torch.load(out / folder / name, weights_only=True)
            for part in ("actor", "critic"):
                assert a[part].keys() == b[part].keys()
                for k in a[part]:
                    assert torch.equal(a[part][k], b[part][k]), (folder, name, part, k)
        assert (json.loads((out / folder / "config.json").read_text())
                == json.loads((ref_out / folder / "config.json").read_text()))
    # the summary: same entries up to the timings and the failed run's traceback
    assert json.loads((out / "summary.json").read_text()) == summary

    def strip(e):
        return {k: v for k, v in e.items() if k not in TIMING | {"traceback", "thread_env"}}

    assert [strip(e) for e in summary] == [strip(e) for e in ref]


def test_in_process_runs_and_a_failed_run(reference):
    out, summary = reference
    assert [e["folder"] for e in summary] == ["mappo/seed_0", "mappo/seed_1", "bad/seed_0"]
    assert [e["status"] for e in summary] == ["ok", "ok", "failed"]
    ok, bad = summary[0], summary[2]
    assert ok["agent_steps"] == 2 * 4 * 8 * 10 and ok["mask_violations"] == 0
    assert all(ok[k] is not None for k in ("eval_return", "eval_sampled_error"))
    assert "cuda:97" in bad["error"] and bad["error"].startswith("ValueError")
    assert bad["config"]["device"] == "cuda:97"
    assert "Traceback" in bad["traceback"]
    for folder in ("mappo/seed_0", "mappo/seed_1"):
        assert {"config.json", "log.csv", "policy.pt", "summary.json"} <= {
            p.name for p in (out / folder).iterdir()}
    # different seeds train different weights (the comparisons below could fail)
    import torch

    a = torch.load(out / "mappo/seed_0/policy.pt", weights_only=True)["actor"]
    b = torch.load(out / "mappo/seed_1/policy.pt", weights_only=True)["actor"]
    assert any(not torch.equal(a[k], b[k]) for k in a)
    assert json.loads((out / "summary.json").read_text()) == summary


def test_worker_processes_write_what_the_in_process_runs_write(reference, tmp_path):
    from netsense.rl.launch import launch

    summary = launch(_runs(), tmp_path, workers=2, progress=False)
    _same_as_reference(reference, tmp_path, summary)
    # each worker started with one thread per pool (unless this process sets a variable)
    from netsense.rl.launch import THREAD_VARS

    assert all(e["thread_env"] == {k: os.environ.get(k, "1") for k in THREAD_VARS}
               for e in summary)


def test_ray_tasks_write_what_the_in_process_runs_write(reference, tmp_path):
    ray = pytest.importorskip("ray")
    from netsense.rl.launch import launch

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
             ignore_reinit_error=True)
    try:
        summary = launch(_runs(), tmp_path, ray_address="local", progress=False)
    finally:
        ray.shutdown()
    _same_as_reference(reference, tmp_path, summary)
    from netsense.rl.launch import THREAD_VARS

    assert all(e["thread_env"] == {k: os.environ.get(k, "1") for k in THREAD_VARS}
               for e in summary)


# ------------------------------------------------------------------ inputs (no training)
def test_make_runs_folders():
    from netsense.rl.launch import make_runs

    cfg = _tiny(seed=5)
    assert [r.folder for r in make_runs(cfg, [2, 0])] == ["seed_2", "seed_0"]
    runs = make_runs({"a": cfg, "b": replace(cfg, lr=1e-3)}, [0, 1])
    assert [r.folder for r in runs] == ["a/seed_0", "a/seed_1", "b/seed_0", "b/seed_1"]
    assert [r.config.seed for r in runs] == [0, 1, 0, 1]
    assert runs[2].config.lr == 1e-3


@pytest.mark.parametrize("name", ["../x", "a/../b", "a//b", "/a", "a/", "a/seed_3", "seed_3",
                                  "", ".hidden", "a/.b", 3])
def test_run_names_are_plain_folder_names(name):
    from netsense.rl.launch import Run

    with pytest.raises(ValueError, match="Run.name"):
        Run(_tiny(), name)


def test_run_names_may_be_paths_of_plain_folder_names():
    from netsense.rl.launch import Run

    assert Run(_tiny(seed=2), "comm_fading-v0/mlp").folder == "comm_fading-v0/mlp/seed_2"


@pytest.mark.parametrize("kw, match", [
    ({"workers": 0}, "workers must be an integer >= 1"),
    ({"workers": 2, "ray_address": "local"}, "with ray_address Ray places the runs"),
    ({"resources": {"num_cpus": 2}}, "resources are Ray's"),
    ({"threads": 0}, "threads must be an integer >= 1"),
    ({"ray_address": ""}, "ray_address must be"),
])
def test_launch_names_bad_options_before_writing(tmp_path, kw, match):
    from netsense.rl.launch import launch, make_runs

    with pytest.raises(ValueError, match=match):
        launch(make_runs(_tiny(), [0]), tmp_path / "out", **kw)
    assert not (tmp_path / "out").exists()


def test_launch_refuses_runs_that_share_a_folder(tmp_path):
    from netsense.rl.launch import Run, launch

    with pytest.raises(ValueError, match=r"share output folders \['x/seed_0'\]"):
        launch([Run(_tiny(), "x"), Run(_tiny(lr=1e-3), "x")], tmp_path / "out")
    with pytest.raises(TypeError, match="Run objects"):
        launch([_tiny()], tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_thread_env_keeps_what_the_user_set(monkeypatch):
    from netsense.rl.launch import THREAD_VARS, thread_env

    for k in THREAD_VARS:
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    env = thread_env(2)
    assert env == {**dict.fromkeys(THREAD_VARS, "2"), "OMP_NUM_THREADS": "3"}
    assert thread_env(None) == {}


def test_worker_processes_start_with_the_thread_variables(monkeypatch):
    """What a spawned worker sees before it imports anything: the pool's environment."""
    import multiprocessing as mp
    import os
    from concurrent.futures import ProcessPoolExecutor

    from netsense.rl.launch import THREAD_VARS, spawn_environment, thread_env

    for k in THREAD_VARS:
        monkeypatch.delenv(k, raising=False)
    with spawn_environment(thread_env(1)), ProcessPoolExecutor(
            1, mp_context=mp.get_context("spawn")) as pool:
        seen = list(pool.map(os.getenv, THREAD_VARS))
    assert seen == ["1"] * len(THREAD_VARS)
    assert not any(k in os.environ for k in THREAD_VARS)  # restored afterwards


# ------------------------------------------------------------------ command line
def test_cli_seeds_train_what_launch_trains(reference, tmp_path, capsys):
    import torch

    from netsense.cli import main

    ref_out, _ = reference
    argv = ["train", "message_cost-v1", "--backend", "torchrl", "--seeds", "1", "0",
            "--steps", "640", "--num-envs", "4", "--rollout", "8", "--batch-size", "16",
            "--epochs", "2", "--eval-interval", "1", "--eval-envs", "2", "--override",
            "horizon=12", "--out", str(tmp_path), "--no-progress"]
    assert main(argv) == 0
    assert "seed 1: mappo/mlp on message_cost-v1, 640 agent-steps" in capsys.readouterr().out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert [(e["folder"], e["status"]) for e in summary] == [("seed_1", "ok"), ("seed_0", "ok")]
    # the command's config is the test's: the same weights as the launch above
    a = torch.load(ref_out / "mappo/seed_0/policy.pt", weights_only=True)["actor"]
    b = torch.load(tmp_path / "seed_0/policy.pt", weights_only=True)["actor"]
    assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("flags, text", [
    (["--backend", "torchrl", "--workers", "2", "--ray", "local"], "with --ray, Ray places"),
    (["--backend", "torchrl", "--cpus-per-run", "2"], "need --ray ADDRESS"),
    (["--backend", "torchrl", "--gpus-per-run", "0.5"], "need --ray ADDRESS"),
    (["--backend", "sb3", "--seeds", "0", "1"], "--seeds belongs to --backend torchrl"),
    (["--backend", "sb3", "--clock", "5"], "--clock belongs to --backend torchrl"),
    (["--backend", "sb3", "--news-gate"], "--news-gate belongs to --backend torchrl"),
    (["--backend", "sb3", "--no-overlap"], "--no-overlap belongs to --backend torchrl"),
    (["--backend", "torchrl", "--news-gate", "--control", "full"],
     "PPOConfig.news_gate gates the send choices"),
    (["--backend", "torchrl", "--clock", "1"], "PPOConfig.clock[0] must be an integer in [2,"),
    (["--backend", "sb3", "--workers", "2"], "--backend sb3 trains one"),
    (["--backend", "torchrl", "--workers", "0"], "argument --workers: must be >= 1"),
])
def test_cli_names_bad_launcher_flags(tmp_path, capsys, flags, text):
    from netsense.cli import main

    try:
        rc = main(["train", "message_cost-v1", "--out", str(tmp_path / "o"), *flags])
    except SystemExit as exc:  # argparse's own errors
        rc = exc.code
    assert rc == 2 and text in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_cli_ray_flags_become_launch_options():
    from netsense.cli import build_parser
    from netsense.commands.train import _launch_options

    parse = build_parser().parse_args
    args = parse(["train", "x-v0", "--ray", "auto", "--cpus-per-run", "2",
                  "--gpus-per-run", "0.5"])
    assert _launch_options(args) == {"ray_address": "auto", "threads": 2,
                                     "resources": {"num_cpus": 2, "num_gpus": 0.5}}
    assert _launch_options(parse(["train", "x-v0", "--workers", "3"])) == {"workers": 3}


# ------------------------------------------------------------------ the benchmark script
def test_bench_parallel_runs_report_by_hand():
    from experiment_loader import load_experiment

    mod = load_experiment("bench/parallel_runs")
    rows = [{"round": 0, "condition": "alone", "runs_at_once": 1, "agent_steps_per_s": 100},
            {"round": 0, "condition": "pair", "runs_at_once": 2, "agent_steps_per_s": 50},
            {"round": 0, "condition": "pair", "runs_at_once": 2, "agent_steps_per_s": 80},
            {"round": 1, "condition": "alone", "runs_at_once": 1, "agent_steps_per_s": 200},
            {"round": 1, "condition": "pair", "runs_at_once": 2, "agent_steps_per_s": 100},
            {"round": 1, "condition": "pair", "runs_at_once": 2, "agent_steps_per_s": 160}]
    lines = mod.report(rows)
    pair = next(ln for ln in lines if ln.startswith("pair "))
    # slowdowns 2.0, 1.25, 2.0, 1.25 against the same round's alone: median 1.62
    assert "1.62 (1.25 - 2.00) vs alone" in pair
    assert "90 (50 - 160)" in pair


def test_bench_parallel_runs_smoke(tmp_path):
    from experiment_loader import load_experiment

    mod = load_experiment("bench/parallel_runs")
    path = mod.main(["--smoke", "--out", str(tmp_path)])
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["condition"], r["runs_at_once"]) for r in rows] == [("alone", "1")]
    assert int(rows[0]["agent_steps"]) == 4 * 8 * 10 and float(rows[0]["wall_s"]) > 0
    assert (tmp_path / "bench_parallel_runs.png").stat().st_size > 0
    assert "alone" in (tmp_path / "bench_parallel_runs.txt").read_text()


# ------------------------------------------------------------------ docs/rl.md
def _docs_section() -> str:
    text = (Path(__file__).resolve().parents[1] / "docs" / "rl.md").read_text()
    text = text[text.index("## Many runs: worker processes and a Ray cluster"):]
    end = text.find("\n## ", 1)  # up to the next section
    return text if end < 0 else text[:end]


def test_docs_cluster_commands_parse():
    import shlex

    from netsense.cli import build_parser
    from netsense.commands.train import _launch_options

    blocks = _docs_section().split("```bash\n")[1:]
    cmds = [c for b in blocks for c in b.split("```")[0].replace("\\\n", " ").splitlines()
            if c.startswith("netsense train")]
    assert cmds
    for cmd in cmds:
        argv = shlex.split(cmd.split("#")[0])[1:]
        assert _launch_options(build_parser().parse_args(argv))["ray_address"] == "auto"


def test_docs_sweep_example_builds_its_runs():
    block = _docs_section().split("```python\n")[1].split("```")[0]
    ns = {"__name__": "docs_example"}  # not __main__: builds the runs, launches nothing
    exec(compile(block, "docs/rl.md", "exec"), ns)
    runs = ns["runs"]
    assert [r.folder for r in runs[:2]] == ["lr3e-4/seed_0", "lr3e-4/seed_1"]
    assert len(runs) == 10 and {r.config.lr for r in runs[5:]} == {1e-3}


def test_a_ray_connection_failure_says_how_to_join(monkeypatch, tmp_path):
    ray = pytest.importorskip("ray")
    from netsense.rl.launch import launch, make_runs

    def refuse(**kw):
        raise ConnectionError(f"Failed to connect to Ray cluster at {kw['address']}")

    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", refuse)
    with pytest.raises(ConnectionError, match="at head:6379; .*RAY_AUTH_MODE=token"):
        launch(make_runs(_tiny(), [0]), tmp_path, ray_address="head:6379", progress=False)
    assert not (tmp_path / "summary.json").exists()  # no run finished
