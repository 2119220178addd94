"""Each fault's documented effect, on hand-built plants and graphs."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from netsense import GaussianNoise, Plant, design_observer
from netsense.graphs.aoi import aoi_stats, trigger_step
from netsense.graphs.families import RoundRobinRing, StaticGraph
from netsense.kernels.update import OMEGA
from netsense.observers.faults import (
    CrashedAgents,
    LinkDrops,
    LyingAgent,
    StuckSensor,
    captured_fraction,
    fault_from_dict,
    run_with_faults,
)
from netsense.sensing.drops import BernoulliArrivals, GilbertElliottArrivals

# Lower-triangular plant: agent 0 sees x1, agent 1 sees x2, agent 2 sees x3, agent 3 sees
# nothing (a relay). Lemma 1 then gives substates 0, 1, 2 of size 1, owned by agents
# 0, 1, 2, and an empty substate 3. Every diagonal entry is unstable.
A = np.array([[1.2, 0.0, 0.0], [0.5, 1.1, 0.0], [0.3, 0.2, 1.3]])
E = np.eye(3)
PLANT = Plant(A=A, C=(E[:1], E[1:2], E[2:3], np.zeros((0, 3))))
N, B, K = 4, 3, 40
COMPLETE = StaticGraph(~np.eye(N, dtype=bool))


def _setup(graphs_process=COMPLETE, steps=K, plant=PLANT):
    design = design_observer(plant, deadbeat=True)
    assert design.decomposition.sizes == (1, 1, 1, 0)
    g = np.stack([graphs_process.sequence(steps, b) for b in range(B)])
    x0 = np.random.default_rng(0).normal(size=(B, 3)) + 1.0
    return design, g, x0


def _substate_errors(tr, k=-1):
    return tr.sub_errors[k]  # (B, N agents, N substates)


def test_healthy_baseline_is_exact():
    design, g, x0 = _setup()
    tr, _ = run_with_faults(PLANT, design, g, x0)
    assert np.all(_substate_errors(tr) < 1e-8)
    assert trigger_step(tr.tau).tolist() == [1] * B  # complete graph: all heard at once


def test_crashed_source_before_sharing_leaves_substate_open_loop():
    # Source 1 crashes at step 0 on the complete graph: nobody ever hears about
    # substate 1, so tau_i^(1) stays omega (eq. (11)) and everybody else runs substate 1
    # open loop (eq. (12)): the error grows like 1.1^k. Substate 0 (q < 1) is unaffected.
    design, g, x0 = _setup()
    tr, _ = run_with_faults(PLANT, design, g, x0, [CrashedAgents(1, at=0)])
    others = [0, 2, 3]
    assert np.all(tr.tau[:, :, others, 1] == OMEGA)
    assert trigger_step(tr.tau).tolist() == [-1] * B
    e1 = tr.sub_errors[:, :, others, 1]
    assert np.all(e1[-1] > 10 * e1[1])
    assert np.all(tr.sub_errors[-1, :, :, 0] < 1e-8)
    assert not tr.alive[1] and tr.alive[[0, 2, 3]].all()
    assert np.all(tr.messages[:, 0] == N * (N - 1) - (N - 1))  # node 1 sends nothing


def test_crashed_source_after_trigger_indices_grow_by_one_per_step():
    # Static ring 0->1->2->3->0: node at distance d from source 0 holds tau = d. Source 0
    # crashes at step 10, so its last message left at step 9; that information reaches
    # the node at distance d at step 9 + d, and from then on nothing fresher exists: the
    # index grows by one per step (eq. (14)): tau_i^(0)[k] = max(d_i, k - 9).
    ring = RoundRobinRing(N, 1)
    design, g, x0 = _setup(ring, steps=60)
    noisy = dataclasses.replace(PLANT, process_noise=GaussianNoise(0.01))
    tr, _ = run_with_faults(noisy, design, g, x0, [CrashedAgents(0, at=10)], rng=0)
    k = np.arange(10, 61)
    for i, d in ((1, 1), (2, 2), (3, 3)):
        assert np.array_equal(tr.tau[10:, 0, i, 0], np.maximum(d, k - 9))
    healthy, _ = run_with_faults(noisy, design, g, x0, rng=0)
    # with process noise the open-loop error of substate 0 grows like 1.2^k (an unstable
    # AR(1) driven by the noise; averaged, as one run can start near its cancellation)
    assert tr.sub_errors[-1, :, 1:, 0].mean() > 100 * healthy.sub_errors[-1, :, 1:, 0].mean()


@pytest.mark.parametrize("mode", ["stuck", "stale"])
def test_stuck_or_stale_sensor_spreads_wrong_substate_with_fresh_indices(mode):
    # Agent 1's sensor is frozen (or 3 steps old) from step 5: its indices still claim 0,
    # every agent adopts its wrong estimate of substate 1 (error grows), substate 0 is
    # exact (it does not depend on y_1), and the indices are the healthy ones.
    design, g, x0 = _setup()
    healthy, _ = run_with_faults(PLANT, design, g, x0)
    tr, _ = run_with_faults(PLANT, design, g, x0, [StuckSensor(1, at=5, mode=mode, delay=3)])
    assert np.array_equal(tr.tau, healthy.tau)
    assert np.all(tr.sub_errors[-1, :, :, 0] < 1e-8)
    assert np.all(tr.sub_errors[-1, :, :, 1] > 1e-3 * np.abs(x0).max())
    assert np.all(tr.sub_errors[-1, :, :, 1] > tr.sub_errors[20, :, :, 1])
    assert np.allclose(tr.sub_errors[:6], healthy.sub_errors[:6])  # nothing before `at`


def test_liar_with_smallest_index_captures_every_neighbour():
    # Complete graph; agent 0 lies with claim 0. For every other substate it ties with the
    # source and wins the tie (smallest node index), so all honest agents adopt its
    # never-refreshed estimates: captured fraction 1 and large errors on substates 1, 2.
    design, g, x0 = _setup()
    tr, obs = run_with_faults(PLANT, design, g, x0, [LyingAgent(0, claim=0)])
    assert captured_fraction(obs).tolist() == [1.0] * B
    assert np.all(obs.origin[:, 1:, 1:][:, ~np.eye(3, dtype=bool)] == 0)
    honest = [1, 2, 3]
    assert np.all(tr.sub_errors[-1][:, [2, 3], 1] > 1.0)
    assert np.all(tr.sub_errors[-1][:, honest, 0] < 1e-8)  # the liar's own substate is fine
    assert np.all(obs.indices[:, honest, 2][:, [0, 2]] == 1)  # adopted from a "tau = 0"
    assert not tr.alive[0]


def test_liar_losing_the_tie_or_claiming_stale_is_harmless_on_complete_graph():
    design, g, x0 = _setup()
    tr, obs = run_with_faults(PLANT, design, g, x0, [LyingAgent(3, claim=0)])
    assert captured_fraction(obs).tolist() == [0.0] * B
    assert np.all(tr.errors[-1][:, :3] < 1e-8)
    tr, obs = run_with_faults(PLANT, design, g, x0, [LyingAgent(0, claim=5)])
    assert captured_fraction(obs).tolist() == [0.0] * B
    assert np.all(tr.errors[-1][:, 1:] < 1e-8)


def test_liar_on_ring_captures_everything_downstream():
    # 0->1->2->3->0 with liar 1 (claim 0): for substate 0, nodes 2 and 3 only hear the
    # liar's side of the ring, so they are captured; for substate 2 node 3 hears the source
    # first (tau 1) and node 0 hears node 3 (tau 2): not captured.
    design, g, x0 = _setup(RoundRobinRing(N, 1), steps=20)
    _, obs = run_with_faults(PLANT, design, g, x0, [LyingAgent(1, claim=0)])
    assert np.all(obs.origin[:, [2, 3], 0] == 1)
    assert np.all(obs.origin[:, 3, 2] == 2) and np.all(obs.origin[:, 0, 2] == 2)


def test_consensus_liar_runs_open_loop():
    design, g, x0 = _setup()
    tr, obs = run_with_faults(PLANT, design, g, x0, [LyingAgent(3)], observer="consensus")
    assert np.all(obs.z_estimates[:, 3] == 0.0)  # relay with zero start never moves
    healthy, _ = run_with_faults(PLANT, design, g, x0, observer="consensus")
    assert tr.errors[-1][:, :3].mean() > healthy.errors[-1][:, :3].mean()


def test_link_drops():
    design, g, x0 = _setup()
    healthy, _ = run_with_faults(PLANT, design, g, x0)
    all_lost, _ = run_with_faults(PLANT, design, g, x0, [LinkDrops(BernoulliArrivals(0.0))])
    assert trigger_step(all_lost.tau).tolist() == [-1] * B
    assert np.all(all_lost.messages == 0)
    none_lost, _ = run_with_faults(PLANT, design, g, x0, [LinkDrops(BernoulliArrivals(1.0))])
    assert np.array_equal(none_lost.tau, healthy.tau)
    # 60 % loss (i.i.d. and bursty): staler indices than the healthy tau = 1, errors still
    # vanish (deadbeat, the complete graph stays jointly connected)
    for model in (BernoulliArrivals(0.4), GilbertElliottArrivals(0.3, 0.2)):
        tr, _ = run_with_faults(PLANT, design, g, x0, [LinkDrops(model)], rng=3)
        off = ~np.eye(N, dtype=bool)
        assert aoi_stats(tr.tau, 5)["mean"][:, off].mean() > 1.2
        assert np.all(tr.errors[-1] < 1e-6)
        again, _ = run_with_faults(PLANT, design, g, x0, [LinkDrops(model)], rng=3)
        assert np.array_equal(again.tau, tr.tau)  # reproducible from the seed


def test_fault_specs_round_trip_and_validation():
    faults = [LinkDrops(GilbertElliottArrivals(0.1, 0.4), at=3), CrashedAgents((1, 2), at=4),
              StuckSensor(0, mode="stale", delay=2), LyingAgent(3, claim=1, at=2)]
    for f in faults:
        assert fault_from_dict(f.to_dict()) == f
        assert pickle.loads(pickle.dumps(f)) == f
    with pytest.raises(ValueError, match="kind"):
        fault_from_dict({"kind": "meteor"})
    with pytest.raises(ValueError, match="unknown fields"):
        fault_from_dict({"kind": "crash", "agents": [0], "when": 3})
    with pytest.raises(ValueError, match="agents"):
        CrashedAgents(())
    with pytest.raises(ValueError, match="mode"):
        StuckSensor(0, mode="melted")
    with pytest.raises(ValueError, match="delay"):
        StuckSensor(0, mode="stale", delay=0)
    with pytest.raises(ValueError, match="at"):
        LyingAgent(0, at=-1)
    with pytest.raises(ValueError, match="model"):
        LinkDrops(0.5)
    design, g, x0 = _setup()
    with pytest.raises(ValueError, match="agents"):
        run_with_faults(PLANT, design, g, x0, [CrashedAgents(7)])
    with pytest.raises(ValueError, match="LyingAgent"):
        run_with_faults(PLANT, design, g, x0, [LyingAgent(0), LyingAgent(1)])
    with pytest.raises(ValueError, match="observer"):
        run_with_faults(PLANT, design, g, x0, observer="gossip")


# ----------------------------------------------------------------------------- scenarios
FAULT_SCENARIOS = ("fault_message_drops-v0", "fault_bursty_drops-v0",
                   "fault_link_failures-v0", "fault_sensor_outage-v0")


@pytest.mark.parametrize("scenario_id", FAULT_SCENARIOS)
def test_fault_scenarios_freshness_beats_consensus(scenario_id):
    # The env's fault scenarios (the faults the scenario schema supports: per-link message
    # loss, Markov link failures, sensor outages): the scripted freshness policy keeps the
    # error at the noise level, the uniform consensus policy does not.
    from netsense.env.policies import make_policy
    from netsense.env.registry import list_scenarios, make

    assert scenario_id in list_scenarios()
    mean_err = {}
    for name in ("freshness", "uniform"):
        env = make(scenario_id)
        obs, infos = env.reset(seed=0)
        policy = make_policy(name, env)
        errs = []
        while env.agents:
            obs, _, _, _, infos = env.step(policy.act_dict(env, obs, infos))
            errs.append(np.mean([infos[a]["error"] for a in infos]))
        assert len(errs) == 100
        mean_err[name] = float(np.mean(errs[50:]))
    assert mean_err["freshness"] < 0.01 < mean_err["uniform"]


def test_faults_change_nothing_before_their_start():
    design, g, x0 = _setup(RoundRobinRing(N, 2), steps=30)
    healthy, _ = run_with_faults(PLANT, design, g, x0)
    at = 12
    for fault in (LyingAgent(0, claim=0, at=at), LinkDrops(BernoulliArrivals(0.3), at=at),
                  CrashedAgents(1, at=at), StuckSensor(2, at=at, mode="stale", delay=2)):
        tr, _ = run_with_faults(PLANT, design, g, x0, [fault], rng=4)
        assert np.array_equal(tr.tau[:at + 1], healthy.tau[:at + 1]), fault
        assert np.allclose(tr.sub_errors[:at + 1], healthy.sub_errors[:at + 1]), fault
        assert not np.array_equal(tr.tau, healthy.tau) or isinstance(fault, StuckSensor)
