"""experiments/bench/scale.py: the scenarios it builds for each N, the arithmetic of its
table, and (slow) a smoke-sized run. No timing is asserted."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from experiment_loader import load_experiment

scale = load_experiment("bench/scale")


@pytest.mark.parametrize("N", scale.NS)
def test_each_N_has_N_agents_five_sources_and_a_circulant_graph_of_in_degree_3(N):
    from netsense.graphs.processes import MarkovLinkFailures

    model = scale.scale_model(N)
    plant = model.plant
    assert plant.num_agents == N
    assert plant.A.shape == (10, 10)
    src = scale.sources(N)
    assert len(set(src)) == 5 and src[0] == 0 and max(src) < N
    # source j measures block j (two rows of the identity); every other agent is a relay
    for i, C in enumerate(plant.C):
        if i in src:
            j = src.index(i)
            np.testing.assert_array_equal(C, np.eye(10)[2 * j:2 * j + 2])
        else:
            assert C.shape[0] == 0
    # A: the five rotation blocks, nothing outside them
    mask = np.kron(np.eye(5), np.ones((2, 2))).astype(bool)
    assert not plant.A[~mask].any()
    g = model.graphs
    assert isinstance(g, MarkovLinkFailures) and g.draws == "base"
    assert g.max_in_degree == 3
    # node i hears i - 1, i - 3 and i - 7 (mod N): base[i, l] for the link l -> i
    want = np.zeros((N, N), dtype=bool)
    for o in scale.OFFSETS:
        want[(np.arange(N) + o) % N, np.arange(N)] = True
    np.testing.assert_array_equal(g.base, want)


def test_the_jsc_family_at_N_10_is_the_registered_task_step_for_step():
    """At N = 10 the resized scenario with the registered graph process is
    comm_process_noise-v0 itself: the core's outputs agree bit for bit."""
    from netsense.engine.core import BatchedCore
    from netsense.env.registry import build_model, load, with_overrides

    reg = load(scale.BASE)
    ours = with_overrides(reg, **scale.scale_overrides(10, "jsc"))
    assert ours.plant["A"] == reg.plant["A"] and ours.plant["C"] == reg.plant["C"]
    assert ours.graph == reg.graph
    cores = [BatchedCore(scale.scale_model(10, "jsc"), 3), BatchedCore(build_model(reg), 3)]
    outs = [c.reset(5) for c in cores]
    np.testing.assert_array_equal(outs[0][0], outs[1][0])
    rng = np.random.default_rng(0)
    for _ in range(30):
        a = rng.integers(0, 2, size=(3, 10, 1))
        s0, s1 = (c.step(a) for c in cores)
        np.testing.assert_array_equal(s0.obs, s1.obs)
        np.testing.assert_array_equal(s0.action_mask, s1.action_mask)
        np.testing.assert_array_equal(s0.reward, s1.reward)
    np.testing.assert_array_equal(cores[0].Z, cores[1].Z)


def test_cost_and_ratios_from_known_rates():
    assert scale.cost_us(2e6) == pytest.approx(0.5)
    assert math.isnan(scale.cost_us(0.0)) and math.isnan(scale.cost_us(float("nan")))
    # N = 1,000 at half N = 50's rate: an agent-step costs twice as much
    r = scale.cost_ratio({10: 4e6, 50: 2e6, 1000: 1e6}, 50)
    assert r == pytest.approx({10: 0.5, 50: 1.0, 1000: 2.0})
    assert math.isnan(scale.cost_ratio({10: 1e6, 50: float("nan")}, 10)[50])
    assert math.isnan(scale.cost_ratio({10: 1e6}, 50)[10])  # no reference
    assert scale.bytes_per_agent(64 * 1000 * 512, 64, 1000) == 512


def test_critic_state_bytes_from_the_state_layout():
    pytest.importorskip("torch")  # the training environment's state layout
    # the defaults' rollout of global states: 33 x 256 states of 1 + 2N + N^2 + 2NM floats
    assert scale.train_state_bytes(10, 5, 256, 32) == 4 * 33 * 256 * (1 + 20 + 100 + 100)
    # on Markov link failures the state carries the N D base links, not N^2 pairs
    model = scale.scale_model(40)
    E = scale.support_edges(model)
    assert E == int(model.graphs.base.sum()) == 40 * model.graphs.max_in_degree  # circulant
    assert scale.train_state_bytes(40, 5, 256, 32, E) == \
        4 * 33 * 256 * (1 + 80 + E + 400)


def test_plant_needs_one_agent_per_oscillator():
    with pytest.raises(ValueError, match="at least 5"):
        scale.oscillator_plant(4)
    with pytest.raises(ValueError, match="graph must be one of"):
        scale.scale_overrides(10, "ring")


@pytest.mark.slow
def test_smoke_run_writes_csv_md_and_png(tmp_path):
    pytest.importorskip("torchrl")
    scale.main(["--smoke", "--out", str(tmp_path), "--no-progress"])
    with (tmp_path / "scale_smoke.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["N"]) for r in rows] == [6, 12]
    assert all(float(r["core_agent_steps_per_s"]) > 0 for r in rows)
    # the smoke's smaller num_envs sizes its iterations: two of them, not two of the
    # defaults' (which would be 64 of the smoke's)
    assert [int(r["train_iterations"]) for r in rows] == [2, 2]
    assert "Targets" in (tmp_path / "scale_smoke.md").read_text()
    assert (tmp_path / "scale_smoke.png").stat().st_size > 0


def test_steady_rate_is_the_median_after_the_first_iteration():
    rows = [{"agent_steps": 0, "wall_s": 0.0}, {"agent_steps": 100, "wall_s": 10.0},
            {"agent_steps": 300, "wall_s": 11.0}, {"agent_steps": 400, "wall_s": 12.0},
            {"agent_steps": 500, "wall_s": 14.0}]
    # rows[0] ends the first iteration; the four later ones ran at 10, 200, 100, 50 /s
    assert scale.steady_rate(rows) == pytest.approx(75.0)
    assert math.isnan(scale.steady_rate(rows[:1]))
