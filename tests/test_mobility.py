"""Mobility graph processes: reproducibility, geometry, and the Assumption-1 report."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from netsense.graphs.families import window_connectivity
from netsense.graphs.mobility import (
    MobilityState,
    RandomWalk,
    RandomWaypoint,
    disk_graph,
    mobility_from_dict,
)
from netsense.graphs.processes import check_joint_connectivity


@pytest.mark.parametrize("process", [RandomWaypoint(6, radius=0.3, pause=2),
                                     RandomWalk(6, radius=0.3, step_std=0.05)])
def test_reproducible_from_seed_and_picklable(process):
    a = process.sequence(80, 11)
    assert np.array_equal(a, process.sequence(80, 11))
    assert not np.array_equal(a, process.sequence(80, 12))
    clone = pickle.loads(pickle.dumps(process))
    assert np.array_equal(clone.sequence(80, 11), a)
    # sampling in chunks continues the same run (state is picklable too)
    rng = np.random.default_rng(11)
    s = process.initial_state(rng)
    g1, s = process.sample(rng, 30, s)
    s = pickle.loads(pickle.dumps(s))
    g2, _ = process.sample(rng, 50, s)
    assert np.array_equal(np.concatenate([g1, g2]), a)
    assert mobility_from_dict(process.to_dict()) == process


def test_disk_graph_geometry_and_directed_radii():
    pos = np.array([[0.0, 0.0], [0.3, 0.0], [1.0, 0.0]])
    adj = disk_graph(pos, 0.5)
    assert adj.tolist() == [[False, True, False], [True, False, False], [False, False, False]]
    # node 2 transmits far (radius 1.0): 2 -> 0 and 2 -> 1, but nobody reaches node 2
    adj = disk_graph(pos, np.array([0.5, 0.5, 1.0]))
    assert adj[0, 2] and adj[1, 2] and not adj[2, 0] and not adj[2, 1]


def test_positions_stay_in_area_and_waypoint_speed_bounded():
    p = RandomWaypoint(5, radius=0.2, area=2.0, speed_min=0.05, speed_max=0.1)
    pos, graphs = p.sequence_with_positions(200, 3)
    assert np.array_equal(graphs, p.sequence(200, 3))
    assert pos.min() >= 0 and pos.max() <= 2.0
    step = np.linalg.norm(np.diff(pos, axis=0), axis=-1)
    assert step.max() <= 0.1 + 1e-12
    assert np.array_equal(graphs, disk_graph(pos, 0.2))
    w = RandomWalk(5, radius=0.2, step_std=0.5)
    pos, _ = w.sequence_with_positions(100, 0)
    assert pos.min() >= 0 and pos.max() <= 1.0


def test_assumption1_lost_with_small_radius_and_kept_with_large():
    # radius >= diagonal of the unit square: complete graph at every step
    big = RandomWaypoint(6, radius=1.5).sequence(30, 0)
    assert check_joint_connectivity(big, 1).holds
    assert window_connectivity(big, 1).all()
    # radius 0: no links at all -> the checker reports the very first window
    none = RandomWalk(6, radius=0.0).sequence(30, 0)
    rep = check_joint_connectivity(none, 5)
    assert not rep.holds and rep.first_failure == (0, 5)
    assert "fails" in str(rep)
    # intermediate radius: some windows connected, some not
    mid = window_connectivity(RandomWaypoint(8, radius=0.25).sequence(400, 2), 5)
    assert 0 < mid.mean() < 1


def test_validation_names_the_field():
    with pytest.raises(ValueError, match="radius"):
        RandomWaypoint(4, radius=-1.0)
    with pytest.raises(ValueError, match="radius"):
        RandomWaypoint(4, radius=(0.1, 0.2))
    with pytest.raises(ValueError, match="speed"):
        RandomWaypoint(4, speed_min=0.2, speed_max=0.1)
    with pytest.raises(ValueError, match="step_std"):
        RandomWalk(4, step_std=0.0)
    with pytest.raises(ValueError, match="num_nodes"):
        RandomWalk(1)
    with pytest.raises(ValueError, match="unknown fields"):
        mobility_from_dict({"kind": "random_walk", "num_nodes": 3, "sped": 1})
    with pytest.raises(ValueError, match="kind"):
        mobility_from_dict({"kind": "levy", "num_nodes": 3})
    assert isinstance(RandomWalk(3).initial_state(np.random.default_rng(0)), MobilityState)


def test_mobility_graphs_drive_the_environment():
    # The env's CoreModel takes any GraphProcess: moving agents plug in without a scenario
    # key (see the README for what the scenario schema still lacks).
    import dataclasses

    from pettingzoo.test import parallel_api_test

    from netsense.env.pettingzoo_env import NetSenseEnv
    from netsense.env.policies import make_policy
    from netsense.env.registry import build_model, load

    base = build_model(load("fault_message_drops-v0"))
    model = dataclasses.replace(base, graphs=RandomWaypoint(8, radius=0.4))
    parallel_api_test(NetSenseEnv(model), num_cycles=20)
    env = NetSenseEnv(model)
    obs, infos = env.reset(seed=0)
    policy = make_policy("freshness", env)
    errs = []
    while env.agents:
        obs, _, _, _, infos = env.step(policy.act_dict(env, obs, infos))
        errs.append(max(infos[a]["error"] for a in infos))
    assert len(errs) == base.horizon and np.mean(errs[-20:]) < 1e-3
    clone = pickle.loads(pickle.dumps(env))
    assert clone is not env
