"""``netsense sweep`` and the sweep runner: outputs on small rings match hand-computed values."""

from __future__ import annotations

import csv

import pytest

from netsense.cli import main
from netsense.studies.sweep import SweepCase, run_sweep, summarize


def _read(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_sweep_command_on_rings_matches_hand_values(tmp_path, capsys):
    out, summ = tmp_path / "rows.csv", tmp_path / "summary.csv"
    code = main(["sweep", "--family", "ring", "--N", "4", "--T", "1,4,5", "--n", "4",
                 "--seeds", "2", "--steps", "60", "--out", str(out), "--summary", str(summ),
                 "--quiet"])
    assert code == 0
    text = capsys.readouterr().out
    assert "trigger" in text and "wrote" in text
    rows = _read(out)
    assert len(rows) == 4  # T = 5 > N is skipped; 2 seeds x {T = 1, T = 4}
    by_T = {int(r["T"]): r for r in rows}
    # Static directed ring (T = 1): node at distance d holds tau = d from step d on.
    r = by_T[1]
    assert (int(r["trigger"]), int(r["worst_index"])) == (3, 3)
    assert float(r["bound_lemma3"]) == 3 and float(r["bound_lemma5"]) == 6
    assert float(r["bound_corollary1"]) == 4 + 2 * 4 * 3 * 1
    assert float(r["messages_per_step"]) == 4.0
    # Token ring (T = N = 4): trigger and worst index 2N - 2 = 6, one message per step.
    r = by_T[4]
    assert (int(r["trigger"]), int(r["worst_index"])) == (6, 6)
    assert float(r["messages_per_step"]) == 1.0
    assert float(r["bound_lemma3"]) == 12 and float(r["bound_lemma5"]) == 24
    for r in rows:
        assert 0 < int(r["steps_deadbeat"]) <= float(r["bound_corollary1"])
        assert r["assumption1"] == "True"
    s = _read(summ)
    assert {float(x["trigger_ratio"]) for x in s} == {1.0, 0.5}  # 3/3 and 6/12


def test_sweep_is_reproducible_across_workers():
    cases = [SweepCase("random_jsc", 5, 2, n=4, param=0.2, seeds=3, steps=60, seed=s)
             for s in range(2)] + [SweepCase("gossip", 4, seeds=2, steps=80)]
    a = run_sweep(cases, workers=1, progress=False)
    b = run_sweep(cases, workers=2, progress=False)
    strip = [{k: v for k, v in r.items() if k != "T_used"} for r in a]
    assert strip == [{k: v for k, v in r.items() if k != "T_used"} for r in b]
    assert len(summarize(a)) == 2  # master seeds of one case are pooled


def test_sweep_rejects_bad_arguments(capsys):
    # the command reports bad arguments in one line with exit code 2 (netsense.cli)
    assert main(["sweep", "--family", "torus", "--quiet"]) == 2
    assert "--family: unknown family 'torus'" in capsys.readouterr().err
    assert main(["sweep", "--family", "ring", "--N", "3", "--T", "5", "--quiet"]) == 2
    assert "no case" in capsys.readouterr().err
    with pytest.raises(ValueError, match="workers"):
        run_sweep([SweepCase("ring", 3)], workers=0)


# ----------------------------------------------------------------------------- experiments
def _experiment(name):
    """Import ``experiments/<name>.py`` under its own name (so worker processes can too)."""
    from experiment_loader import import_experiment

    return import_experiment(name)


def test_topology_sweep_experiment_smoke(tmp_path):
    res = _experiment("studies/topology_sweep").main(
        ["--N", "4", "--n", "3", "--seeds", "2", "--max-steps", "120", "--workers", "1",
         "--out", str(tmp_path)])
    assert res["violations"] == []
    for f in ("topology_sweep.csv", "topology_summary.csv", "topology_tightness.csv",
              "topology_bounds.png", "topology_ratio_vs_N.png", "topology_markov.png"):
        assert (tmp_path / f).stat().st_size > 0
    ring = [s for s in res["summary"] if s["family"] == "ring" and s["T"] == 1]
    assert ring[0]["trigger_ratio"] == 1.0  # static ring: Lemma 3 attained


def test_aoi_experiment_smoke(tmp_path):
    res = _experiment("studies/aoi_heatmap").main(
        ["--N", "4", "--n", "3", "--seeds", "2", "--steps", "40", "--workers", "1",
         "--out", str(tmp_path)])
    ring = next(r for r in res["rows"] if r["family"] == "ring")
    # ring with T = 4 = N (token ring): worst index 2N - 2 = 6
    assert ring["aoi_max"] == 6
    assert (tmp_path / "aoi_heatmap.png").stat().st_size > 0


def test_mobility_experiment_smoke(tmp_path):
    res = _experiment("studies/mobility").main(
        ["--N", "4", "--n", "3", "--seeds", "2", "--steps", "60", "--radii", "0.0,2.0",
         "--timeline-radius", "2.0", "--workers", "1", "--out", str(tmp_path)])
    by_r = {(s["model"], s["radius"]): s for s in res["summary"]}
    assert by_r[("random_walk", 0.0)]["windows_connected"] == 0.0
    assert by_r[("random_walk", 0.0)]["converged_frac"] == 0.0  # nobody ever talks
    assert by_r[("random_waypoint", 2.0)]["assumption1_frac"] == 1.0
    assert by_r[("random_waypoint", 2.0)]["converged_frac"] == 1.0
    assert (tmp_path / "mobility_timeline.png").stat().st_size > 0


def test_faults_experiment_smoke(tmp_path):
    res = _experiment("studies/faults").main(["--seeds", "4", "--steps", "80", "--at", "30",
                                      "--workers", "1", "--out", str(tmp_path)])
    rows = {(r["scenario"], r["observer"]): r for r in res["rows"]}
    fresh = {s: r for (s, o), r in rows.items() if o == "freshness"}
    assert fresh["none"]["ratio_to_fault_free"] == 1.0
    stuck = next(s for s in fresh if s.startswith("stuck_sensor"))
    assert fresh[stuck]["ratio_to_fault_free"] > 10
    assert fresh["liar_agent_0_claim0"]["captured_fraction"] > 0
    assert (tmp_path / "faults_errors.png").stat().st_size > 0
