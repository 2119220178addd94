"""Batched reproductions and the speed harness (issue 8, items 3-5): smoke-sized runs and
oracle checks; no timing is asserted."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from experiment_loader import load_experiment

from netsense import speed
from netsense.engine.core import BatchedCore
from netsense.studies.examples import FIG2_OBSERVERS, run_fig2

load = load_experiment


def test_fig2_montecarlo_batch_equals_single_runs_and_reproduces_the_claim(tmp_path):
    mod = load("papers/freshness_fig2_montecarlo")
    res = mod.run_montecarlo(runs=6, steps=12, seed=3)
    # every batch member equals the unbatched observers started from its estimates
    from netsense.graphs.processes import fig1_graphs
    from netsense.systems.design import design_observer
    from netsense.systems.plants import fig1_scalar

    plant = fig1_scalar(2.0)
    design = design_observer(plant, deadbeat=True)
    graphs = fig1_graphs().sequence(12)
    for r in (0, 4):
        for lab, (cls, kw) in FIG2_OBSERVERS.items():
            obs = cls(design, **kw)
            obs.reset(res["x0_hat"][r])
            x = np.array([1.0])
            for k in range(12):
                obs.step(plant.measure(x), graphs[k])
                x = plant.step(x)
                np.testing.assert_allclose(obs.errors(x), res[lab][k + 1, r], atol=1e-12)
    single = run_fig2(steps=12, seed=3)
    for lab in FIG2_OBSERVERS:
        np.testing.assert_allclose(res[lab][:, 0], single[lab], atol=1e-12)
    rows = {r["observer"]: r for r in mod.summarize(res)}
    assert rows["freshness index"]["converged_frac"] == 1.0
    assert rows["consensus (uniform)"]["diverged_frac"] == 1.0
    assert rows["consensus (tree)"]["diverged_frac"] == 1.0
    assert mod.main(["--runs", "5", "--steps", "8", "--loop-runs", "1", "--out",
                     str(tmp_path)]) == 0
    assert (tmp_path / "fig2_montecarlo.png").exists()


def test_lemma_checks_batched_smoke_finds_no_violation_and_members_differ(tmp_path):
    mod = load("papers/freshness_lemmas3_5")
    row = mod.run_case(mod.Case("random_jsc", 5, 2, 0.2), batch=6, seed=1)
    assert row["violations_lemma3"] == row["violations_lemma5"] == 0
    assert row["trigger_max"] <= row["bound_lemma3"] and row["worst_max"] <= row["bound_lemma5"]
    assert row["distinct_sequences"] > 1  # independent random graph sequences per member
    # hand-checked: on the backward ring edge l -> l+1 exists at k = -l-1 (mod T).
    # N = 3, T = 2: source 2 reaches 0 at k = 1 and 1 at k = 3, so node 1's index of
    # substate 2 becomes finite at step 4 = (N-1)T (the bound is attained);
    # N = 3, T = 3: source 0 reaches 1 at k = 2 and 2 at k = 4 -> finite at step 5.
    for T, want in ((2, 4), (3, 5)):
        row3 = mod.run_case(mod.Case("ring_backward", 3, T), batch=2)
        assert row3["trigger_max"] == row3["trigger_median"] == want
    assert mod.main(["--smoke", "--out", str(tmp_path), "--no-progress"]) == 0
    rows = list(csv.DictReader(open(tmp_path / "lemma_checks_batched_smoke.csv")))
    assert len(rows) == 2


def test_bench_batched_smoke_writes_every_output(tmp_path):
    mod = load("bench/batched")
    assert mod.main(["--smoke", "--no-vmas", "--out", str(tmp_path), "--no-progress"]) == 0
    for suffix in ("", "_scaling", "_growth"):
        assert (tmp_path / f"bench_batched_smoke{suffix}.csv").exists()
    assert (tmp_path / "bench_batched_smoke_scaling.png").exists()
    rows = list(csv.DictReader(open(tmp_path / "bench_batched_smoke.csv")))
    for r in rows:
        assert float(r["core_rate"]) > 0 and float(r["kernel_rate"]) > 0
        assert float(r["core_rate"]) == pytest.approx(int(r["B"]) * int(r["N"]) /
                                                      float(r["core_s"]))


def test_speed_helpers():
    m = speed.bench_model(11, 5)
    assert m.plant.num_agents == 11 and m.plant.n == 5 and m.graphs.max_in_degree == 3
    core = BatchedCore(m, 3)
    core.reset(0)
    sizes = speed.core_state_bytes(core)
    assert sizes["Z"] == core.Z.nbytes and sizes["tau"] == core.tau.nbytes
    prof = speed.profile_core(3, 11, 5, steps=3, top=5)
    assert len(prof) == 5 and all(0 <= share <= 1 for _, _, share in prof)
    o = speed.observation_cost(3, 11, 5, steps=3, repeats=1)
    assert o["full_s"] > 0 and o["no_obs_s"] > 0 and o["kernel_s"] > 0
    assert speed.loglog_slope([1, 2, 4], [3, 12, 48]) == pytest.approx(2.0)
    rows = [{"B": 1024, "N": 10, "n": 10, "M": 5, "core_rate": 2.0, "kernel_rate": 3.0,
             "vmas_rate": 0.1, "core_vs_kernel": 2 / 3, "core_vs_vmas": 20.0}]
    assert "| 1024 | 10 | 10 | 5 |" in speed.format_table(rows)
    assert [v.endswith("met") for v in speed.verdicts(rows)] == [True, True]
    grow, diff = speed.allocation_growth(20, B=2, every=10, progress=False)
    assert [g["step"] for g in grow] == [10, 20] and len(diff) <= 5


def test_speed_main_prints_table_and_rejects_bad_shapes(tmp_path, capsys):
    out = tmp_path / "s.csv"
    assert speed.main(["--shapes", "4,5,3", "--steps", "2", "--repeats", "1", "--no-vmas",
                       "--no-progress", "--csv", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| 4 | 5 | 3 |" in text and "core >= 0.5 x kernel" in text
    assert out.exists()
    with pytest.raises(SystemExit):
        speed.main(["--shapes", "4,5"])


def test_vmas_contender_runs_in_a_process_of_its_own():
    from netsense.speed.runners import _VmasProcess

    # a failing worker (no vmas, or an invalid thread count) is reported, not hung on
    with pytest.raises(RuntimeError, match="VMAS worker failed"):
        _VmasProcess(2, 2, threads=0)
    if not speed.vmas_available():
        pytest.skip("vmas is not installed")
    vm = _VmasProcess(2, 2, threads=1)
    try:
        assert vm.threads == 1
        assert vm._proc.pid != __import__("os").getpid() and vm._proc.is_alive()
        assert vm.block(3) > 0
    finally:
        vm.close()
    assert not vm._proc.is_alive()
