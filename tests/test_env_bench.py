"""Smoke runs of the env benchmark (CLI and experiment script)."""

from __future__ import annotations

import csv

from experiment_loader import load_experiment

from netsense.cli import main


def test_cli_bench_env_smoke(tmp_path, capsys):
    out = tmp_path / "b.csv"
    assert main(["bench", "env", "--N", "3", "--seconds", "0.02", "--no-mpe",
                 "--csv", str(out)]) == 0
    rows = list(csv.DictReader(open(out)))
    assert [r["N"] for r in rows] == ["3"]
    assert float(rows[0]["agent_steps_per_s"]) == 3 * float(rows[0]["env_steps_per_s"]) > 0
    assert "agent-steps/s" in capsys.readouterr().out


def test_experiment_script_smoke(tmp_path):
    mod = load_experiment("bench/env")
    out = tmp_path / "s.csv"
    assert mod.main(["--smoke", "--csv", str(out)]) == 0
    assert out.exists()
