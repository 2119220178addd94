"""``netsense sweep`` and the sweep runner: outputs on small rings match hand-computed values."""

from __future__ import annotations

import csv

import pytest

from netsense.cli import main
from netsense.topology import SweepCase, run_sweep, summarize


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


def test_sweep_rejects_bad_arguments():
    with pytest.raises(ValueError, match="family"):
        main(["sweep", "--family", "torus", "--quiet"])
    with pytest.raises(ValueError, match="no case"):
        main(["sweep", "--family", "ring", "--N", "3", "--T", "5", "--quiet"])
    with pytest.raises(ValueError, match="workers"):
        run_sweep([SweepCase("ring", 3)], workers=0)
