"""Graph processes from their dictionary form: the ``[graph]`` table of a scenario file.

Every process of :mod:`netsense.graphs` (periodic, random jointly connected, Markov link
failures, gossip, mobility, round-robin ring, static) is built here from ``kind`` and its
fields; unknown kinds and missing or extra fields raise a ``ValueError`` that names them.
"""

from __future__ import annotations

from netsense.graphs.families import RoundRobinRing, StaticGraph
from netsense.graphs.mobility import mobility_from_dict
from netsense.graphs.processes import (
    Gossip,
    GraphProcess,
    MarkovLinkFailures,
    PeriodicGraphs,
    RandomJointlyConnected,
    as_adjacency,
)

__all__ = ["graph_process_from_dict"]


def graph_process_from_dict(spec: dict) -> GraphProcess:
    """Build a graph process from its ``to_dict`` form (used by scenario files).

    Raises
    ------
    ValueError
        On an unknown ``kind`` or a missing/extra field (named in the message).
    """
    spec = dict(spec)
    kind = spec.pop("kind", None)
    if kind in ("random_waypoint", "random_walk"):
        return mobility_from_dict({"kind": kind, **spec})
    if kind in ("round_robin_ring", "static"):
        if kind == "round_robin_ring":
            extra = set(spec) - {"num_nodes", "period", "order"}
            if extra or "num_nodes" not in spec:
                raise ValueError(f"graph kind 'round_robin_ring' takes num_nodes, period, order; "
                                 f"unknown fields {sorted(extra)}")
            return RoundRobinRing(int(spec["num_nodes"]), int(spec.get("period", 1)),
                                           str(spec.get("order", "forward")))
        if set(spec) != {"num_nodes", "edges"}:
            raise ValueError(f"graph kind 'static' takes exactly num_nodes and edges, "
                             f"got {sorted(spec)}")
        return StaticGraph(as_adjacency([tuple(e) for e in spec["edges"]],
                                                 int(spec["num_nodes"])))
    fields = {
        "periodic": {"num_nodes", "edges"},
        "random_jsc": {"num_nodes", "period", "extra_edge_prob"},
        "markov": {"num_nodes", "p_fail", "p_recover", "base_edges", "draws"},
        "gossip": {"num_nodes", "base_edges"},
    }
    optional = {"random_jsc": {"extra_edge_prob"}, "gossip": {"base_edges"},
                "markov": {"draws"}}
    if kind not in fields:
        known = sorted(fields) + ["random_walk", "random_waypoint", "round_robin_ring", "static"]
        raise ValueError(f"graph kind must be one of {known}, got {kind!r}")
    missing = fields[kind] - optional.get(kind, set()) - set(spec)
    extra = set(spec) - fields[kind]
    if missing or extra:
        raise ValueError(f"graph kind {kind!r}: missing fields {sorted(missing)}, "
                         f"unknown fields {sorted(extra)}")
    N = int(spec["num_nodes"])
    if kind == "periodic":
        return PeriodicGraphs.from_edges(N, [[tuple(e) for e in g] for g in spec["edges"]])
    if kind == "random_jsc":
        return RandomJointlyConnected(N, int(spec["period"]),
                                      float(spec.get("extra_edge_prob", 0.0)))
    if kind == "markov":
        return MarkovLinkFailures(as_adjacency([tuple(e) for e in spec["base_edges"]], N),
                                  float(spec["p_fail"]), float(spec["p_recover"]),
                                  str(spec.get("draws", "all")))
    if "base_edges" in spec:
        return Gossip(as_adjacency([tuple(e) for e in spec["base_edges"]], N))
    return Gossip.complete(N)
