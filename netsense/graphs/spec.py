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
from netsense.kernels import checks

__all__ = ["graph_process_from_dict"]

#: Fields of every kind that hold integers / probabilities / edge lists (checked first, so
#: ``num_nodes = 3.5`` or ``p_fail = "x"`` fail naming the field instead of being rounded).
_INTEGERS = ("num_nodes", "period")
_PROBABILITIES = ("extra_edge_prob", "p_fail", "p_recover")


def _check_values(spec: dict) -> None:
    for k in _INTEGERS:
        if k in spec:
            checks.integer(k, spec[k], 1)
    for k in _PROBABILITIES:
        if k in spec:
            checks.number(k, spec[k], 0, 1)
    for k in ("draws", "order"):
        if k in spec and not isinstance(spec[k], str):
            raise ValueError(f"{k} must be a string, got {spec[k]!r}")


def _pairs(name: str, edges) -> list[tuple]:
    """An edge list ``[[l, i], ...]`` as tuples (pairs of ints are checked by
    :func:`netsense.graphs.processes.as_adjacency`)."""
    if not isinstance(edges, (list, tuple)) or not all(isinstance(e, (list, tuple))
                                                        for e in edges):
        raise ValueError(f"{name} must be a list of [l, i] pairs, got {edges!r:.60}")
    return [tuple(e) for e in edges]


def graph_process_from_dict(spec: dict) -> GraphProcess:
    """Build a graph process from its ``to_dict`` form (used by scenario files).

    Raises
    ------
    ValueError
        On an unknown ``kind`` or a missing/extra field (named in the message).
    """
    if not isinstance(spec, dict):
        raise ValueError(f"graph spec must be a dict, got {type(spec).__name__}")
    spec = dict(spec)
    kind = spec.pop("kind", None)
    _check_values(spec)
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
        return StaticGraph(as_adjacency(_pairs("edges", spec["edges"]),
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
        return PeriodicGraphs.from_edges(N, [_pairs(f"edges[{t}]", g)
                                             for t, g in enumerate(spec["edges"])])
    if kind == "random_jsc":
        return RandomJointlyConnected(N, int(spec["period"]),
                                      float(spec.get("extra_edge_prob", 0.0)))
    if kind == "markov":
        return MarkovLinkFailures(as_adjacency(_pairs("base_edges", spec["base_edges"]), N),
                                  float(spec["p_fail"]), float(spec["p_recover"]),
                                  str(spec.get("draws", "all")))
    if "base_edges" in spec:
        return Gossip(as_adjacency(_pairs("base_edges", spec["base_edges"]), N))
    return Gossip.complete(N)
