"""``experiments/bench/time_to_return.py``: return at equal wall-clock time across the
training benchmark's grid points, on made-up runs whose answer is known, on bad input, and on
the committed results (which its command at its defaults must reproduce)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

pytest.importorskip("rliable")

from experiment_loader import load_experiment  # noqa: E402


def _run(folder: Path, task: str, learner: str, seed: int, point: tuple[int, int],
         evals: list[tuple[int, float]], *, finished: bool = True) -> None:
    d = folder / "runs" / task / learner / f"seed_{seed}"
    d.mkdir(parents=True)
    (d / "config.json").write_text(json.dumps({"num_envs": point[0], "minibatch": point[1],
                                               "lr": 1e-3}))
    with (d / "log.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["iteration", "agent_steps", "eval_return"])
        w.writeheader()
        for i, (x, y) in enumerate(evals):
            w.writerow({"iteration": 2 * i, "agent_steps": x, "eval_return": y})
            w.writerow({"iteration": 2 * i + 1, "agent_steps": x + 1, "eval_return": ""})
    if finished:
        (d / "summary.json").write_text("{}")


@pytest.fixture
def made_up(tmp_path):
    """Learner ``slow`` (4:8, 100 agent-steps/s, 1000 agent-steps: 10 s) learns more per
    sample than ``fast`` (8:32, 400 agent-steps/s, 8000 agent-steps: 20 s), but ``fast``
    returns more at equal time. Seed ``k`` adds ``k / 10`` to every return (IQM of five
    seeds: the middle three, + 0.2)."""
    runs = tmp_path / "runs_folder"
    for k in range(5):
        _run(runs, "t", "slow", k, (4, 8),
             [(x, -100 + x / 20 + k / 10) for x in range(100, 1001, 100)])
        _run(runs, "t", "fast", k, (8, 32),
             [(x, -100 + x / 50 + k / 10) for x in range(400, 8001, 400)])
    _run(runs, "t", "slow", 9, (4, 8), [(100, 1000.0)], finished=False)  # still training
    with (runs / "curves.csv").open("w", newline="") as fh:  # learners.py's curves (plotted)
        w = csv.writer(fh)
        w.writerow(["task", "learner", "agent_steps", "iqm", "ci_low", "ci_high"])
        w.writerows(["t", "slow", x, -100 + x / 20, -101 + x / 20, -99 + x / 20]
                    for x in range(100, 1001, 100))
    thr = tmp_path / "thr.csv"
    with thr.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["round", "path", "num_envs", "minibatch",
                                           "agent_steps_per_s"])
        w.writeheader()
        for r, (slow, fast) in enumerate([(90, 390), (100, 400), (120, 410)]):
            w.writerow({"round": r, "path": "torchrl-tuned-tx", "num_envs": 4, "minibatch": 8,
                        "agent_steps_per_s": slow})
            w.writerow({"round": r, "path": "torchrl-tuned-tx", "num_envs": 8,
                        "minibatch": 32, "agent_steps_per_s": fast})
            w.writerow({"round": r, "path": "torchrl-defaults-tx", "num_envs": 8,
                        "minibatch": 32, "agent_steps_per_s": 1e9})  # not the grid's path
    return runs, thr, tmp_path / "out"


def test_time_to_return_ranks_the_grid_at_equal_wall_clock(made_up):
    runs, thr, out = made_up
    mod = load_experiment("bench/time_to_return")
    path = mod.main(["--runs", str(runs), "--throughput", f"t={thr}", "--defaults", "slow",
                     "--out", str(out)])
    rows = {(r["learner"], float(r["budget"])): r for r in csv.DictReader(path.open())}
    # W: the shorter whole run, slow's 1000 agent-steps at the median 100 agent-steps/s
    assert {float(r["seconds"]) for (_, f), r in rows.items() if f == 1.0} == {10.0}
    # at W: slow's last evaluation (1000 agent-steps), fast's latest within 4000
    assert int(rows["slow", 1.0]["agent_steps"]) == 1000
    assert int(rows["fast", 1.0]["agent_steps"]) == 4000
    assert float(rows["slow", 1.0]["iqm"]) == pytest.approx(-100 + 1000 / 20 + 0.2)
    assert float(rows["fast", 1.0]["iqm"]) == pytest.approx(-100 + 4000 / 50 + 0.2)
    assert rows["fast", 1.0]["best"] == "True" and rows["slow", 1.0]["best"] == "False"
    assert float(rows["fast", 1.0]["p_defaults_better"]) == 0.0
    # at W / 4 = 2.5 s: slow's 200 agent-steps (-90) against fast's 1000 (latest: 800, -84)
    assert int(rows["fast", 0.25]["agent_steps"]) == 800
    assert rows["fast", 0.25]["best"] == "True"
    lo, hi = float(rows["slow", 0.5]["ci_low"]), float(rows["slow", 0.5]["ci_high"])
    assert lo <= float(rows["slow", 0.5]["iqm"]) <= hi
    text = (out / "time_to_return.txt").read_text()
    assert ("best settings at W: fast (8:32, 400 agent-steps/s); defaults / best settings, "
            "agent-steps/s: 0.25x") in text
    assert (out / "time_to_return.png").stat().st_size > 0


def test_time_to_return_when_the_defaults_win(made_up):
    runs, thr, out = made_up
    mod = load_experiment("bench/time_to_return")
    # the same runs with fast's throughput at 120 agent-steps/s: at W = 10 s it has 1200
    # agent-steps (-76) against slow's -50
    thr.write_text(thr.read_text().replace(",390", ",110").replace(",400", ",120")
                   .replace(",410", ",130"))
    path = mod.main(["--runs", str(runs), "--throughput", f"t={thr}", "--defaults", "slow",
                     "--out", str(out)])
    rows = {(r["learner"], float(r["budget"])): r for r in csv.DictReader(path.open())}
    assert rows["slow", 1.0]["best"] == "True"
    assert int(rows["fast", 1.0]["agent_steps"]) == 1200
    assert float(rows["fast", 1.0]["p_defaults_better"]) == 1.0
    assert "defaults / best settings, agent-steps/s: 1.00x" in (
        out / "time_to_return.txt").read_text()


def test_time_to_return_a_learner_not_yet_evaluated_has_no_return(made_up):
    """A learner whose first evaluation comes after a budget has no return there (NaN,
    never the best), rather than being credited with a later evaluation."""
    runs, thr, out = made_up
    mod = load_experiment("bench/time_to_return")
    for k in range(5):  # 1000 agent-steps/s, evaluated at 5 s and 12 s
        _run(runs, "t", "late", k, (16, 64), [(5000, -1.0), (12000, -1.0)])
    with thr.open("a", newline="") as fh:
        fh.write("0,torchrl-tuned-tx,16,64,1000\n")
    path = mod.main(["--runs", str(runs), "--throughput", f"t={thr}", "--defaults", "slow",
                     "--out", str(out)])
    rows = {(r["learner"], float(r["budget"])): r for r in csv.DictReader(path.open())}
    assert rows["late", 0.25]["iqm"] == "nan" and rows["late", 0.25]["best"] == "False"
    assert rows["late", 0.5]["best"] == "True"  # at 5 s: -1 against slow's -75, fast's -60
    assert int(rows["late", 1.0]["agent_steps"]) == 5000
    text = (out / "time_to_return.txt").read_text()
    assert "no evaluation of every seed within the budget" in text


def test_time_to_return_rejects_bad_input(made_up, capsys):
    runs, thr, out = made_up
    mod = load_experiment("bench/time_to_return")
    for argv, words in [
        (["--throughput", str(thr)], "TASK=CSV"),
        (["--throughput", f"t={out / 'none.csv'}"], "no file"),
        (["--throughput", f"t={thr}", "--path", "nope"], "no rows of path 'nope'"),
        (["--throughput", f"t={thr}", "--defaults", "mlp"], "no runs of learner 'mlp'"),
    ]:
        with pytest.raises(SystemExit):
            mod.main(["--runs", str(runs), "--out", str(out), *argv])
        assert words in capsys.readouterr().err
    (runs / "curves.csv").rename(runs / "curves.csv.away")
    with pytest.raises(SystemExit):
        mod.main(["--runs", str(runs), "--throughput", f"t={thr}", "--defaults", "slow",
                  "--out", str(out)])
    assert "no curves.csv" in capsys.readouterr().err
    (runs / "curves.csv.away").rename(runs / "curves.csv")
    thr.write_text("\n".join(line for line in thr.read_text().splitlines()
                             if ",8,32," not in line or "defaults" in line) + "\n")
    with pytest.raises(SystemExit):
        mod.main(["--runs", str(runs), "--throughput", f"t={thr}", "--defaults", "slow",
                  "--out", str(out)])
    assert "no rate for num_envs:minibatch 8:32" in capsys.readouterr().err
    assert not out.exists()  # nothing written before the input is checked


def test_time_to_return_committed_results_reproduce(tmp_path):
    """The committed CSV is what the command gives at its defaults."""
    mod = load_experiment("bench/time_to_return")
    committed = mod.RESULTS / "time_to_return.csv"
    path = mod.main(["--out", str(tmp_path)])
    fresh = list(csv.DictReader(path.open()))
    kept = list(csv.DictReader(committed.open()))
    assert [r.keys() for r in fresh] == [r.keys() for r in kept] and len(fresh) == len(kept)
    for a, b in zip(fresh, kept, strict=True):
        for k in a:
            if k in ("iqm", "ci_low", "ci_high", "p_defaults_better") and a[k]:
                assert float(a[k]) == pytest.approx(float(b[k]), rel=1e-9), (a, k)
            else:
                assert a[k] == b[k], (a, k)
    assert (tmp_path / "time_to_return.txt").read_text() == (
        mod.RESULTS / "time_to_return.txt").read_text()
