"""Layer 4 — switching communication graphs and what can be said of them.

Graph processes and Assumption 1's joint strong connectivity (:mod:`.processes`), more
families for topology experiments (:mod:`.families`), mobility-driven disk graphs
(:mod:`.mobility`), the scenario files' graph specifications (:mod:`.spec`), the bounds of
Lemmas 3 and 5, Theorem 1 and Corollary 1 on the freshness indices (:mod:`.bounds`) and
age-of-information statistics of an index history (:mod:`.aoi`).

May import: :mod:`netsense.kernels`, :mod:`netsense.sensing`, :mod:`netsense.systems`.
"""

from netsense.graphs.aoi import aoi_stats, trigger_step, worst_index
from netsense.graphs.families import (
    FAMILIES,
    RoundRobinRing,
    StaticGraph,
    make_graph_process,
    ring_with_chords,
    window_connectivity,
)
from netsense.graphs.mobility import RandomWalk, RandomWaypoint
from netsense.graphs.processes import (
    Gossip,
    GraphProcess,
    MarkovLinkFailures,
    PeriodicGraphs,
    RandomJointlyConnected,
    as_adjacency,
    check_joint_connectivity,
    fig1_graphs,
    in_neighbor_slots,
    is_strongly_connected,
    smallest_period,
)
from netsense.graphs.spec import graph_process_from_dict

__all__ = [
    "FAMILIES", "Gossip", "GraphProcess", "MarkovLinkFailures", "PeriodicGraphs",
    "RandomJointlyConnected", "RandomWalk", "RandomWaypoint", "RoundRobinRing", "StaticGraph",
    "aoi_stats", "as_adjacency", "check_joint_connectivity", "fig1_graphs",
    "graph_process_from_dict", "in_neighbor_slots", "is_strongly_connected",
    "make_graph_process", "ring_with_chords", "smallest_period", "trigger_step",
    "window_connectivity", "worst_index",
]
