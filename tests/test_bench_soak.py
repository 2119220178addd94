"""experiments/bench/soak.py: its memory sampling, log reading and summary, smoke-sized
(a run of a few iterations through `netsense train`)."""

from __future__ import annotations

import csv
import os
import sys

import pytest
from experiment_loader import load_experiment

soak = load_experiment("bench/soak")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_rss_counts_this_process_and_the_log_reader_skips_a_half_row(tmp_path):
    assert soak.rss_mib(os.getpid()) > 10  # a Python with numpy loaded
    assert os.getpid() in soak.tree(os.getppid())
    log = tmp_path / "log.csv"
    assert soak.logged_steps(log) == 0  # not written yet
    log.write_text("iteration,agent_steps,x\n0,320,1.5\n1,640,2.5\n2,96")
    assert soak.logged_steps(log) == 640  # the row being written is not counted
    log.write_text("iteration,agent_steps,x\n0,320,1.5\n1,640,2.5\n")
    assert soak.logged_steps(log) == 640


def test_fit_gives_a_flat_series_no_slope_and_a_growing_one_its_slope():
    flat = [{"agent_steps": s, "rss_mib": 900.0} for s in range(0, 10**7, 10**5)]
    out = soak.fit(flat, 10**6)
    assert out["slope_mib_per_10m"] == pytest.approx(0.0, abs=1e-9)
    assert out["first_fifth_median_mib"] == out["last_fifth_median_mib"] == 900.0
    grow = [{"agent_steps": s, "rss_mib": 900.0 + s / 10**6} for s in range(0, 10**7, 10**5)]
    assert soak.fit(grow, 10**6)["slope_mib_per_10m"] == pytest.approx(10.0)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_smoke_run_writes_csv_txt_and_png(tmp_path):
    pytest.importorskip("torchrl")
    rc = soak.main(["--scenario", "message_cost-v1", "--steps", "1280", "--interval", "0.2",
                    "--out", str(tmp_path), "--", "--num-envs", "4", "--rollout", "8",
                    "--batch-size", "16", "--epochs", "1", "--eval-interval", "2",
                    "--eval-envs", "2", "--override", "horizon=12", "--torch-threads", "1"])
    assert rc == 0
    with (tmp_path / "soak.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert all(float(r["rss_mib"]) > 0 for r in rows)
    assert (tmp_path / "soak.png").stat().st_size > 0
    assert "MiB per 10M agent-steps" in (tmp_path / "soak.txt").read_text()
