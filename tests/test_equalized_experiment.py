"""Smoke-size run of experiments/papers/equalized_sec4a_batch_reactor.py (section IV-A)."""

import csv

import numpy as np
from experiment_loader import load_experiment


def load():
    return load_experiment("papers/equalized_sec4a_batch_reactor")


def test_resolved_B_reproduces_printed_A():
    mod = load()
    B, dA = mod.resolve_B()
    assert dA < 1e-4  # the printed A is c2d(Ts = 0.05) of the continuous reactor
    np.testing.assert_allclose(B[:3], np.array(mod.B_PRINTED_ROWS)[:3], atol=1e-4)
    np.testing.assert_allclose(B[3], mod.B_PRINTED_ROWS[4], atol=1e-4)


def test_smoke_run_writes_outputs_and_keeps_bounds(tmp_path):
    mod = load()
    s = mod.main(["--runs", "3", "--horizon", "3", "--max-delay", "1", "--pattern", "110",
                  "--periods", "2", "--out", str(tmp_path)])
    assert s["bound_violations"] == 0 and s["switching_bound_violations"] == 0
    assert s["C_violation"] == 0 and s["D_violation"] == 0
    assert s["feasibility_monotone_on_trace"]
    for name in ("summary.csv", "errors.csv", "search.csv", ".png"):
        assert (tmp_path / f"equalized_batch_reactor{'_' if name[0] != '.' else ''}{name}"
                ).stat().st_size > 0
    rows = list(csv.reader(open(tmp_path / "equalized_batch_reactor_errors.csv")))
    assert len(rows) == 1 + 3 * (3 * 2 + 1)
