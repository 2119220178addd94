"""Smoke run of experiments/rl/comm_tasks.py: the frontier with the informed and
privileged rules, and the summary's picks and paired gains."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from experiment_loader import load_experiment


def test_smoke_run_writes_the_frontier_and_the_summary(tmp_path):
    exp = load_experiment("rl/comm_tasks")
    summary = exp.main(["--scenarios", "comm_fading-v0", "comm_channel_k2-v0",
                        "--episodes", "3", "--horizon", "12", "--out", str(tmp_path),
                        "--no-progress"])
    for f in ("frontier.csv", "frontier.md", "summary.csv", "summary.md",
              "frontier_comm_fading-v0.png"):
        assert (tmp_path / f).is_file(), f
    whats = {(r["scenario"], r["what"]): r for r in summary}
    informed = whats["comm_fading-v0", "best informed"]
    assert informed["policy"].startswith("acked(") and informed["kind"] == "decentralised"
    assert whats["comm_fading-v0", "best privileged"]["kind"] == "privileged"
    assert ("comm_channel_k2-v0", "best centralised") in whats
    assert ("comm_channel_k2-v0", "best informed") not in whats  # no acks, no next_out
    with (tmp_path / "frontier.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    fading = [r for r in rows if r["scenario"] == "comm_fading-v0"]
    best = max((r for r in fading if r["kind"] == "decentralised"),
               key=lambda r: float(r["reward_mean"]))
    assert whats["comm_fading-v0", "best decentralised"]["policy"] == best["policy"]
    assert {r["kind"] for r in fading} == {"decentralised", "privileged", "centralised"}
    assert {r["kind"] for r in fading if r["family"] == "settled"} == {"decentralised"}
    # the gain is the paired mean difference of the two rows' episodes
    pick = whats["comm_fading-v0", "best privileged"]
    assert pick["gain_over"] == whats["comm_fading-v0", "best decentralised"]["policy"]
    assert pick["gain"] == pytest.approx(pick["reward_mean"] - float(best["reward_mean"]),
                                         abs=1e-4)  # (the CSV keeps 6 digits)
    assert np.isfinite(pick["gain_ci_low"]) and pick["gain_ci_low"] <= pick["gain"]
    table = list(csv.DictReader((tmp_path / "summary.csv").open()))
    assert len(table) == len(summary)
