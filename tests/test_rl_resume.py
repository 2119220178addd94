"""Resuming killed training runs, and run folders that are never clobbered nor read half
written (netsense.rl.resume, netsense.rl.run_folder, netsense.rl.atomic, the launcher and
``netsense train --resume / --overwrite``)."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

from netsense.rl import run_folder
from netsense.rl.atomic import atomic_path, write_atomic

pytest.importorskip("torchrl")
import torch  # noqa: E402

from netsense.cli import main  # noqa: E402
from netsense.rl.config import PPOConfig  # noqa: E402

#: a tiny run: 4 environments x 8 steps of message_cost-v1's 10 agents per iteration,
#: evaluated and checkpointed after every iteration, the serial loop, one torch thread
TINY = ["message_cost-v1", "--num-envs", "4", "--rollout", "8", "--batch-size", "16",
        "--epochs", "2", "--eval-interval", "1", "--eval-envs", "2", "--override",
        "horizon=12", "--no-overlap", "--torch-threads", "1", "--no-progress"]
ITERS = 10
STEPS = ITERS * 4 * 8 * 10
#: non-timing columns of log.csv, compared between runs
TIMING = {"wall_s", "agent_steps_per_s", "collect_s", "learn_s"}


def _tiny(**kw) -> PPOConfig:
    kw = {"steps": STEPS, **kw}
    return PPOConfig("message_cost-v1", num_envs=4, rollout=8, minibatch=16, epochs=2,
                     eval_interval=2, eval_envs=2, overrides={"horizon": 12},
                     torch_threads=1, **kw)


def _actor(path: Path) -> dict:
    return torch.load(path, weights_only=True)["actor"]


def _same_weights(a: Path, b: Path) -> bool:
    x, y = _actor(a), _actor(b)
    return x.keys() == y.keys() and all(torch.equal(x[k], y[k]) for k in x)


def _log(path: Path) -> list[dict]:
    from netsense.rl.runlog import read_log

    rows, _ = read_log(path)
    return [{k: v for k, v in r.items() if k not in TIMING} for r in rows]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Two uninterrupted runs (seeds 0 and 1) of the tiny CLI configuration."""
    out = tmp_path_factory.mktemp("reference") / "out"
    assert main(["train", *TINY, "--steps", str(STEPS), "--seeds", "0", "1",
                 "--out", str(out)]) == 0
    return out


def _spawn(argv: list[str]) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([sys.executable, "-c", "import sys; from netsense.cli import "
                             "main; sys.exit(main(sys.argv[1:]))", *argv],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env,
                            start_new_session=True)


def _kill_at_random(proc: subprocess.Popen, run: Path) -> str:
    """SIGKILL ``proc`` (and its worker processes) at a random point after ``run``'s
    first checkpoint: a random iteration's checkpoint, then up to 50 ms more. Returns
    where, for the assertions' messages."""
    rng = random.Random()
    k, delay = rng.randint(1, ITERS - 3), rng.uniform(0.0, 0.05)
    ckpt = run / f"checkpoint_{k:05d}.pt"
    deadline = time.monotonic() + 240
    while not ckpt.exists():
        assert proc.poll() is None, f"training ended before {ckpt.name}: " \
                                    f"{proc.stderr.read().decode()[-2000:]}"
        assert time.monotonic() < deadline, f"no {ckpt.name} within 240 s"
        time.sleep(0.005)
    time.sleep(delay)
    assert proc.poll() is None, "training finished before it was killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    return f"killed {delay:.3f} s after {ckpt.name}"


def test_cli_resume_after_sigkill_ends_where_an_uninterrupted_run_ends(reference, tmp_path):
    out = tmp_path / "out"
    proc = _spawn(["train", *TINY, "--steps", str(STEPS), "--out", str(out)])
    delay = _kill_at_random(proc, out / "seed_0")
    run = out / "seed_0"
    assert not run_folder.is_finished(run) and not run_folder.is_finished(out), delay
    # every reader refuses the killed run's folder by name
    ckpt = run / "checkpoint_00001.pt"
    with pytest.raises(ValueError, match="unfinished training run"):
        run_folder.check_finished(run)
    assert main(["policy", "check", str(ckpt)]) == 2
    # the same command without --resume is refused, naming the folder and both flags
    with pytest.raises(ValueError, match=r"already holds a training run.*--resume.*"
                                         r"--overwrite"):
        _raise_from_cli(["train", *TINY, "--steps", str(STEPS), "--out", str(out)])
    assert main(["train", *TINY, "--steps", str(STEPS), "--out", str(out), "--resume"]) == 0
    assert run_folder.is_finished(run) and run_folder.is_finished(out)
    assert not (run / "resume.pt").exists()
    assert _same_weights(run / "policy.pt", reference / "seed_0" / "policy.pt"), delay
    rows = _log(run / "log.csv")
    assert [r["iteration"] for r in rows] == list(range(ITERS)), delay  # each once
    assert rows == _log(reference / "seed_0" / "log.csv"), delay
    # a finished run resumed: nothing trained again
    before = (run / "policy.pt").stat().st_mtime_ns
    assert main(["train", *TINY, "--steps", str(STEPS), "--out", str(out), "--resume"]) == 0
    assert (run / "policy.pt").stat().st_mtime_ns == before


def _raise_from_cli(argv: list[str]) -> None:
    """Run the command's own ``run`` (the CLI turns its ValueError into exit code 2)."""
    from netsense.cli import build_parser

    args = build_parser().parse_args(argv)
    from netsense.commands import train

    train.run(args)


def test_cli_seeds_resume_with_workers_keeps_finished_seeds(reference, tmp_path):
    """Seeds 0 and 1 one after another, killed once seed 1 has a checkpoint; resumed with
    two worker processes: seed 0 is not trained again, seed 1 continues."""
    out = tmp_path / "out"
    proc = _spawn(["train", *TINY, "--steps", str(STEPS), "--seeds", "0", "1",
                   "--out", str(out)])
    where = _kill_at_random(proc, out / "seed_1")
    assert run_folder.is_finished(out / "seed_0"), where
    assert not run_folder.is_finished(out / "seed_1"), where
    done = (out / "seed_0" / "policy.pt").stat().st_mtime_ns
    assert main(["train", *TINY, "--steps", str(STEPS), "--seeds", "0", "1", "--out",
                 str(out), "--resume", "--workers", "2"]) == 0
    assert (out / "seed_0" / "policy.pt").stat().st_mtime_ns == done
    for s in ("seed_0", "seed_1"):
        assert _same_weights(out / s / "policy.pt", reference / s / "policy.pt"), (s, where)
        assert _log(out / s / "log.csv") == _log(reference / s / "log.csv"), (s, where)
    summary = json.loads((out / "summary.json").read_text())
    assert [e["seed"] for e in summary] == [0, 1]
    assert all(e["status"] == "ok" for e in summary)
    assert run_folder.run_status(out) == "finished"


@pytest.mark.parametrize("kw", [{"overlap": False}, {"overlap": True},
                                {"overlap": False, "control": "full", "bc": "freshness",
                                 "bc_steps": 256, "bc_epochs": 2}],
                         ids=["serial", "overlap", "warm-start"])
def test_resume_is_bit_identical_in_process(tmp_path, monkeypatch, kw):
    """Interrupted after the fifth iteration's log row (its last checkpoint after the
    fourth), resumed: the final weights and log equal an uninterrupted run's, with the
    serial loop, with the overlapped collection (whose collector draws from its own
    generators: deterministic too) and after a behaviour-cloning warm start (not run
    again)."""
    from netsense.rl import ppo

    cfg = _tiny(**kw)
    if "bc" in kw:
        cfg = cfg.conservative()
    ppo.train_ppo(cfg, tmp_path / "full")
    add = ppo.RunLog.add

    def interrupted(self, row):
        add(self, row)
        if row["iteration"] == 4:
            raise KeyboardInterrupt

    monkeypatch.setattr(ppo.RunLog, "add", interrupted)
    with pytest.raises(KeyboardInterrupt):
        ppo.train_ppo(cfg, tmp_path / "part")
    monkeypatch.setattr(ppo.RunLog, "add", add)
    assert len(_log(tmp_path / "part" / "log.csv")) == 5  # one row past the checkpoint
    res = ppo.train_ppo(cfg, tmp_path / "part", resume=True)
    assert [r["iteration"] for r in res.rows] == list(range(ITERS))
    assert res.bc == json.loads((tmp_path / "full" / "summary.json").read_text())["bc"]
    assert _same_weights(tmp_path / "part" / "policy.pt", tmp_path / "full" / "policy.pt")
    assert _log(tmp_path / "part" / "log.csv") == _log(tmp_path / "full" / "log.csv")


def test_resume_refuses_another_configuration(tmp_path, monkeypatch, capsys):
    from netsense.rl import ppo

    cfg = _tiny(steps=4 * 4 * 8 * 10)
    add = ppo.RunLog.add

    def interrupted(self, row):
        add(self, row)
        if row["iteration"] == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(ppo.RunLog, "add", interrupted)
    with pytest.raises(KeyboardInterrupt):
        ppo.train_ppo(cfg, tmp_path)
    monkeypatch.setattr(ppo.RunLog, "add", add)
    before = sorted(p.name for p in tmp_path.iterdir())
    # the benchmark refuses the unfinished run's checkpoint, naming the folder
    ckpt = tmp_path / "checkpoint_00002.pt"
    assert main(["benchmark", "message_cost-v1", "--policies", f"learned:{ckpt}", "--out",
                 str(tmp_path / "bench")]) == 2
    assert f"{tmp_path} is an unfinished training run" in capsys.readouterr().err
    with pytest.raises(ValueError, match=r"differs in lr: 0.001 in the run, 0.002 now"):
        ppo.train_ppo(replace(cfg, lr=2e-3), tmp_path, resume=True)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "bench") == before


def test_log_drops_rows_after_the_checkpoint_and_a_half_written_row(tmp_path):
    from netsense.rl.runlog import RunLog, read_log

    log = RunLog(tmp_path)
    for i in range(4):
        log.add({"iteration": i, "agent_steps": 10 * (i + 1), "x": i / 3})
    log.add({"iteration": 4, "agent_steps": 50, "x": 1.0, "eval_return": -2.5})
    log.close()
    with (tmp_path / "log.csv").open("a") as fh:
        fh.write("5,60,0.")  # killed mid-row
    rows, header = read_log(tmp_path / "log.csv")
    assert [r["iteration"] for r in rows] == [0, 1, 2, 3, 4]
    assert header == ["iteration", "agent_steps", "x", "eval_return"]
    assert rows[1]["x"] == 1 / 3  # floats come back exactly
    again = RunLog(tmp_path, resume_at=3)
    assert [r["iteration"] for r in again.kept] == [0, 1, 2]
    again.add({"iteration": 3, "agent_steps": 40, "x": 0.0})
    again.close()
    assert [r["iteration"] for r in read_log(tmp_path / "log.csv")[0]] == [0, 1, 2, 3]


# ------------------------------------------------------------ no clobbering, no half files
def test_cli_refuses_a_folder_holding_another_run_before_writing(tmp_path, capsys):
    out = tmp_path / "out"
    (out / "seed_0").mkdir(parents=True)
    (out / "seed_0" / "policy.pt").write_bytes(b"not touched")
    assert main(["train", *TINY, "--steps", "320", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(out) in err and "--resume" in err and "--overwrite" in err
    assert (out / "seed_0" / "policy.pt").read_bytes() == b"not touched"
    assert main(["train", *TINY, "--steps", "320", "--out", str(out), "--resume",
                 "--overwrite"]) == 2
    assert "not both" in capsys.readouterr().err


def test_cli_overwrite_replaces_the_run_and_keeps_other_files(tmp_path):
    out = tmp_path / "out"
    (out / "seed_3").mkdir(parents=True)
    (out / "seed_3" / "log.csv").write_text("stale\n")
    (out / "notes.txt").write_text("mine\n")
    assert main(["train", *TINY, "--steps", "320", "--out", str(out), "--overwrite"]) == 0
    assert not (out / "seed_3").exists() and (out / "notes.txt").read_text() == "mine\n"
    assert run_folder.is_finished(out / "seed_0") and run_folder.is_finished(out)


def test_run_folder_status_of_legacy_and_plain_folders(tmp_path):
    assert run_folder.run_status(tmp_path) is None  # empty: no run
    run_folder.check_finished(tmp_path)
    (tmp_path / "config.json").write_text("{}")  # a killed run of an older netsense
    assert run_folder.run_status(tmp_path) == "running"
    (tmp_path / "policy.pt").write_bytes(b"")  # its final policy, written last
    assert run_folder.is_finished(tmp_path)
    run_folder.mark(tmp_path, "running")  # the marker decides where there is one
    assert not run_folder.is_finished(tmp_path)
    (tmp_path / "run.json").write_text("[1, 2")
    with pytest.raises(ValueError, match="run.json: not a readable run marker"):
        run_folder.run_status(tmp_path)
    assert run_folder.claim(tmp_path / "new") == "new"
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="is a file, not a folder"):
        run_folder.claim(tmp_path / "file")


def test_atomic_writes_leave_the_old_file_when_interrupted(tmp_path):
    path = write_atomic(tmp_path / "a.json", '{"v": 1}\n')
    with pytest.raises(RuntimeError), atomic_path(path) as tmp:
        tmp.write_text('{"v": 2, "half')
        raise RuntimeError("killed mid-write")
    assert path.read_text() == '{"v": 1}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]  # no temp file left


def test_resume_state_refuses_foreign_objects(tmp_path):
    import pickle

    from netsense.rl.resume import dumps_state, loads_state

    class Evil:
        def __reduce__(self):
            return (os.system, ("echo pwned",))

    with pytest.raises(ValueError, match=r"names posix.system|names os.system"):
        loads_state(pickle.dumps(Evil()), "resume.pt")
    import numpy as np

    back = loads_state(dumps_state({"a": np.arange(3), "g": np.random.default_rng(1)}), "x")
    assert back["a"].tolist() == [0, 1, 2] and back["g"].integers(9) == \
        np.random.default_rng(1).integers(9)


# ------------------------------------------------------------ the default backend
def test_train_defaults_to_torchrl_and_names_the_extra_when_missing(monkeypatch, capsys):
    import importlib.util

    from netsense.commands.train import resolve_backend

    assert resolve_backend(None) == "torchrl" and resolve_backend("sb3") == "sb3"
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "torchrl" else real(name, *a))
    assert main(["train", "message_cost-v1", "--steps", "10"]) == 2
    err = capsys.readouterr().err
    assert 'pip install -e ".[torchrl]"' in err and "--backend sb3" in err


def test_a_ray_task_resumes_from_the_files_it_is_given(tmp_path, monkeypatch):
    """What a Ray task does on --resume, without Ray: the unfinished run's resume files go
    to the task, which trains in a temporary folder; the files it returns finish the run
    here, as an uninterrupted run would have (checked bit for bit)."""
    from netsense.rl import launch, ppo

    cfg = _tiny()
    ppo.train_ppo(cfg, tmp_path / "full")
    add = ppo.RunLog.add

    def interrupted(self, row):
        add(self, row)
        if row["iteration"] == 6:
            raise KeyboardInterrupt

    run = tmp_path / "out" / "seed_0"
    monkeypatch.setattr(ppo.RunLog, "add", interrupted)
    with pytest.raises(KeyboardInterrupt):
        ppo.train_ppo(cfg, run)
    monkeypatch.setattr(ppo.RunLog, "add", add)
    given = launch._given(run)
    assert set(given) == {"resume.pt", "log.csv", "config.json", "run.json"}
    entry = launch._train_one(launch.Run(cfg), None, False, True, given)
    assert entry["status"] == "ok", entry.get("error")
    assert "resume.pt" not in entry["files"]
    launch._write_files(run, entry["files"])
    (run / "resume.pt").unlink()  # as launch does for a run that finished where it ran
    assert run_folder.is_finished(run)
    assert _same_weights(run / "policy.pt", tmp_path / "full" / "policy.pt")
    assert _log(run / "log.csv") == _log(tmp_path / "full" / "log.csv")


def test_cli_resume_with_other_flags_is_refused_before_writing(tmp_path, capsys):
    from dataclasses import asdict

    out = tmp_path / "out"
    (out / "seed_0").mkdir(parents=True)
    started = replace(_tiny(), lr=5e-4, eval_interval=1, minibatch=16, epochs=2,
                      overlap=False, torch_threads=1)
    (out / "seed_0" / "config.json").write_text(json.dumps(asdict(started), default=list))
    run_folder.mark(out / "seed_0", "running")
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert main(["train", *TINY, "--steps", str(STEPS), "--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert f"{out / 'seed_0'}: --resume needs the flags the run was started with" in err
    assert "lr: 0.0005 in the run, 0.001 now" in err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
