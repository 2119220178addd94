"""Consensus baselines of eq. (6) and the Fig. 2 outcome."""

import numpy as np

from netsense import ConsensusObserver, design_observer, fig1_graphs, fig1_scalar
from netsense.graphs.processes import as_adjacency, in_neighbor_slots
from netsense.observers.consensus import hop_distances, tree_parents
from netsense.studies.examples import run_fig2


def test_uniform_consensus_matches_eq6_by_hand():
    """Node 1 exact, a = 2, weights 1/2: errors follow e' = M e with M alternating
    [[1,0],[1,1]] (graph a) and [[1,1],[0,1]] (graph b)."""
    des = design_observer(fig1_scalar(), deadbeat=True)
    obs = ConsensusObserver(des, weights="uniform")
    x = 1.0
    obs.reset(np.array([[x], [x + 0.3], [x - 0.2]]))
    e = np.array([0.3, -0.2])
    g = fig1_graphs().sequence(10)
    for k in range(10):
        obs.step([np.array([x]), np.zeros(0), np.zeros(0)], g[k])
        x *= 2
        M = np.array([[1, 0], [1, 1]]) if k % 2 == 0 else np.array([[1, 1], [0, 1]])
        e = M @ e
        assert np.allclose(obs.estimates[1:, 0] - x, e, atol=1e-9)


def test_tree_parents_hand_graph():
    # 0 -> 1 -> 2, 0 -> 3, 3 -> 2 : BFS from 0 gives parent(2) = 1 (smaller id, same depth)
    adj = as_adjacency([(0, 1), (1, 2), (0, 3), (3, 2)], 4)[None]
    nbr, valid = in_neighbor_slots(adj, 3)
    assert hop_distances(adj)[0, 0].tolist() == [0, 1, 2, 1]
    src = tree_parents(adj, nbr, valid)
    assert src[0, :, 0].tolist() == [0, 0, 1, 0]
    # root 2 reaches nobody: everyone else keeps its own estimate
    assert src[0, :, 2].tolist() == [0, 1, 2, 3]


def test_fig2_outcome():
    """Paper, Fig. 2: both consensus weightings diverge for a = 2, freshness converges."""
    res = run_fig2(steps=30, seed=4)
    assert res["consensus (uniform)"][-4:].max() > 1e3
    assert res["consensus (tree)"][-4:].max() > 1e6
    assert res["freshness index"][3:].max() < 1e-12
