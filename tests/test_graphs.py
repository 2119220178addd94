"""Graph processes and the Assumption 1 checker."""

import pickle

import numpy as np
import pytest

from netsense.graphs.processes import (
    Gossip,
    MarkovLinkFailures,
    PeriodicGraphs,
    RandomJointlyConnected,
    as_adjacency,
    check_joint_connectivity,
    fig1_graphs,
    in_neighbor_slots,
    smallest_period,
)
from netsense.graphs.spec import graph_process_from_dict


def test_fig1_alternates_and_satisfies_assumption1_with_T2():
    seq = fig1_graphs().sequence(8)
    assert seq[0][1, 0] and seq[1][2, 0]  # (a): 1 hears 0 ; (b): 2 hears 0
    assert (seq[0] == seq[2]).all() and (seq[1] == seq[3]).all()
    assert check_joint_connectivity(seq, 2).holds
    assert not check_joint_connectivity(seq, 1).holds
    assert smallest_period(seq) == 2


@pytest.mark.parametrize("seed", range(20))
def test_random_jsc_by_construction(seed):
    rng = np.random.default_rng(seed)
    N, T = int(rng.integers(2, 9)), int(rng.integers(1, 5))
    seq = RandomJointlyConnected(N, T, 0.1).sequence(10 * T, seed)
    assert check_joint_connectivity(seq, T).holds
    assert not np.any(seq[:, np.arange(N), np.arange(N)])


def _jsc_by_numpy(rng, N, T, p, K, state):
    """The process in numpy's own generator methods: one window per T steps."""
    pos, window = state
    out = np.empty((K, N, N), bool)
    for k in range(K):
        if pos == 0:
            union = rng.random((N, N)) < p
            perm = rng.permutation(N)
            union[perm[(np.arange(N) + 1) % N], perm] = True
            union &= ~np.eye(N, dtype=bool)
            when = rng.integers(0, T, size=(N, N))
            window = union & (when == np.arange(T)[:, None, None])
        out[k] = window[pos]
        pos = (pos + 1) % T
    return out, (pos, window)


@pytest.mark.parametrize("N,T,p", [(2, 1, 0.0), (3, 2, 0.3), (10, 2, 0.05), (7, 5, 0.2),
                                   (17, 3, 0.1), (5, 13, 1.0)])
def test_random_jsc_draws_numpys_stream_run_by_run(N, T, p):
    """The compiled pass draws what numpy's random / permutation / integers draw, in the
    same order, over chunks that end inside windows, for runs at once or alone, and
    leaves every generator where numpy leaves it."""
    proc = RandomJointlyConnected(N, T, p)
    M = 5
    mine = [np.random.default_rng(100 + m) for m in range(M)]
    ref = [np.random.default_rng(100 + m) for m in range(M)]
    states = [proc.initial_state(r) for r in mine]
    ref_states = list(states)
    for K in (3, 2 * T + 1, 1, 7):
        adj, states = proc.sample_many(mine, K, states)
        for m in range(M):
            want, ref_states[m] = _jsc_by_numpy(ref[m], N, T, p, K, ref_states[m])
            np.testing.assert_array_equal(adj[m], want)
            assert states[m][0] == ref_states[m][0]
    for a, b in zip(mine, ref, strict=True):
        assert a.random() == b.random()
    # alone, and one generator twice (run one after the other)
    g = np.random.default_rng(5)
    twice, _ = proc.sample_many([g, g], 2 * T + 1, [(0, None), (0, None)])
    h = np.random.default_rng(5)
    first, st = _jsc_by_numpy(h, N, T, p, 2 * T + 1, (0, None))
    second, _ = _jsc_by_numpy(h, N, T, p, 2 * T + 1, (0, None))
    np.testing.assert_array_equal(twice[0], first)
    np.testing.assert_array_equal(twice[1], second)
    one, _ = proc.sample(np.random.default_rng(5), 2 * T + 1, (0, None))
    np.testing.assert_array_equal(one, first)


def test_random_jsc_slots_are_the_graphs_in_neighbours():
    proc = RandomJointlyConnected(6, 2, 0.4)
    rngs = [np.random.default_rng(s) for s in range(4)]
    states = [(0, None)] * 4
    out = np.full((4, 9, 6, 5), 7, dtype=np.int64)
    nbr, _ = proc.sample_slots_many(rngs, 9, states, 5, out=out)
    assert nbr is out
    adj, _ = proc.sample_many([np.random.default_rng(s) for s in range(4)], 9, states)
    np.testing.assert_array_equal(nbr, in_neighbor_slots(adj, 5)[0])
    # fewer slots than a drawn in-degree: an error naming it, and out is not written
    small = np.full((4, 9, 6, 1), 7, dtype=np.int64)
    with pytest.raises(ValueError, match="in-degree .* > max_degree = 1"):
        proc.sample_slots_many([np.random.default_rng(s) for s in range(4)], 9, states, 1,
                               out=small)
    assert (small == 7).all()


def test_first_failing_interval_is_named():
    ring = as_adjacency([(0, 1), (1, 2), (2, 0)], 3)
    empty = np.zeros((3, 3), bool)
    seq = np.stack([ring, ring, empty, empty, ring, ring])
    rep = check_joint_connectivity(seq, 2)
    assert not rep.holds and rep.first_failure == (2, 4)
    assert "[2, 4)" in str(rep)
    assert smallest_period(seq) == 3


def test_in_neighbor_slots():
    adj = as_adjacency([(2, 0), (1, 0), (0, 2)], 3)
    nbr, valid = in_neighbor_slots(adj)
    assert nbr.tolist() == [[1, 2], [-1, -1], [0, -1]]
    assert valid.tolist() == [[True, True], [False, False], [True, False]]
    with pytest.raises(ValueError, match="in-degree"):
        in_neighbor_slots(adj, 1)


def test_markov_and_gossip_statistics():
    base = ~np.eye(4, dtype=bool)
    seq = MarkovLinkFailures(base, p_fail=0.2, p_recover=0.6).sequence(4000, 0)
    up = seq[:, base].mean()
    assert abs(up - 0.6 / 0.8) < 0.02  # stationary availability p_r / (p_f + p_r)
    g = Gossip.complete(5).sequence(200, 1)
    assert (g.sum((1, 2)) == 1).all()


def test_roundtrip_dict_and_pickle():
    for proc in [fig1_graphs(), RandomJointlyConnected(5, 3, 0.2),
                 MarkovLinkFailures(~np.eye(3, dtype=bool), 0.1, 0.5), Gossip.complete(3)]:
        again = graph_process_from_dict(proc.to_dict())
        assert (again.sequence(12, 7) == proc.sequence(12, 7)).all()
        assert (pickle.loads(pickle.dumps(proc)).sequence(5, 1) == proc.sequence(5, 1)).all()
    with pytest.raises(ValueError, match="kind"):
        graph_process_from_dict({"kind": "nope"})
    with pytest.raises(ValueError, match="period"):
        graph_process_from_dict({"kind": "random_jsc", "num_nodes": 3})
    with pytest.raises(ValueError, match="same size"):
        PeriodicGraphs((np.zeros((2, 2)), np.zeros((3, 3))))


def test_topology_and_mobility_kinds_from_dict():
    from netsense.graphs.families import RoundRobinRing, StaticGraph, ring_with_chords
    from netsense.graphs.mobility import RandomWalk, RandomWaypoint

    for proc in [RoundRobinRing(5, 2, "backward"), StaticGraph(ring_with_chords(5)),
                 RandomWaypoint(6, radius=0.5), RandomWalk(6, radius=0.5)]:
        again = graph_process_from_dict(proc.to_dict())
        assert type(again) is type(proc)
        assert (again.sequence(15, 3) == proc.sequence(15, 3)).all()
    with pytest.raises(ValueError, match="static"):
        graph_process_from_dict({"kind": "static", "num_nodes": 3})
