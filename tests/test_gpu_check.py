"""The GPU check script (experiments/bench/gpu_check.py) runs end to end: on the CPU with
--smoke here, and refuses to pretend without a CUDA device."""

from __future__ import annotations

import csv

import pytest
from experiment_loader import load_experiment

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")


@pytest.fixture(scope="module")
def gpu_check():
    return load_experiment("bench/gpu_check")


def test_smoke_run_writes_both_rows(gpu_check, tmp_path):
    assert gpu_check.main(["--smoke", "--skip-tests", "--out", str(tmp_path),
                           "--num-envs", "4", "--iterations", "3"]) == 0
    with (tmp_path / "gpu_check.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [r["device"] for r in rows] == ["cpu", "cpu"]
    assert all(float(r["agent_steps_per_s"]) > 0 for r in rows)
    assert float(rows[1]["vs_cpu"]) == pytest.approx(1.0)
    assert "| learner on |" in (tmp_path / "gpu_check.md").read_text()


def test_without_cuda_it_says_so(gpu_check, tmp_path, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert gpu_check.main(["--out", str(tmp_path)]) == 2
    assert not (tmp_path / "gpu_check.csv").exists()
    with pytest.raises(SystemExit):
        gpu_check.main(["--smoke", "--iterations", "1", "--out", str(tmp_path)])
