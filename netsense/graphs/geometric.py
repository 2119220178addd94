"""Sensors placed on the plane and linked by distance: a random geometric graph.

``N`` positions are drawn uniformly in the unit square and every pair at distance at most
``radius`` is linked in both directions (a random geometric graph, drawn by
:func:`networkx.random_geometric_graph`, so one ``seed`` gives one layout on every
machine). The layout is fixed: it is drawn once, from the scenario file's seed, not per
episode. A scenario makes the links switch by using the graph as the base of Markov link
failures (fading: ``[graph] kind = "markov"`` with ``base = {kind = "geometric", radius =
..., seed = ...}``, see :mod:`netsense.env.registry`).

Unlike :mod:`netsense.graphs.mobility`, where positions move with every episode's
randomness, here the positions belong to the task.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from netsense.kernels import checks

__all__ = ["check_geometric_spec", "geometric_edges", "geometric_layout"]


def geometric_layout(num_nodes: int, radius: float, seed: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Positions and links of a random geometric graph in the unit square.

    Parameters
    ----------
    num_nodes : int
        ``N >= 2`` sensors.
    radius : float
        Link distance ``r > 0``: ``l`` and ``i`` are linked when ``||p_l - p_i|| <= r``.
    seed : int
        Seed of the placement (:func:`networkx.random_geometric_graph`).

    Returns
    -------
    pos : (N, 2) float array
        Positions in ``[0, 1]^2``.
    adj : (N, N) bool array
        ``adj[i, l]``: ``l`` and ``i`` are linked (symmetric, no self-loops), the
        convention of :mod:`netsense.graphs.processes`.

    Raises
    ------
    ValueError
        Naming the parameter, before anything is drawn: ``num_nodes < 2``, ``radius`` not
        a finite number ``> 0``, ``seed`` not an integer ``>= 0``.
    """
    N = checks.integer("num_nodes", num_nodes, 2)
    r = checks.number("radius", radius, 0, lo_open=True)
    seed = checks.seed_value("seed", seed)
    import networkx as nx  # imported on first use (import netsense stays light)

    G = nx.random_geometric_graph(N, r, dim=2, seed=seed)
    pos = np.array([G.nodes[v]["pos"] for v in range(N)], dtype=float)
    adj = np.zeros((N, N), dtype=bool)
    if G.number_of_edges():
        e = np.array(G.edges(), dtype=np.int64)
        adj[e[:, 0], e[:, 1]] = adj[e[:, 1], e[:, 0]] = True
    return pos, adj


def geometric_edges(num_nodes: int, radius: float, seed: int) -> list[list[int]]:
    """The links of :func:`geometric_layout` as a directed edge list ``[[l, i], ...]``
    (both directions of every link, sorted), the ``base_edges`` of a graph process."""
    _, adj = geometric_layout(num_nodes, radius, seed)
    i, l_ = np.nonzero(adj)
    order = np.lexsort((i, l_))
    return [[int(l_[k]), int(i[k])] for k in order]


def check_geometric_spec(spec: dict[str, Any]) -> tuple[float, int]:
    """``radius`` and ``seed`` of a ``{kind = "geometric", radius, seed}`` table, checked
    (errors name the field); no other key is allowed."""
    extra = sorted(set(spec) - {"kind", "radius", "seed"})
    if extra:
        raise ValueError(f"{extra[0]}: unknown key; a geometric base takes radius and seed")
    for k in ("radius", "seed"):
        if k not in spec:
            raise ValueError(f"{k}: is required for a geometric base")
    return (checks.number("radius", spec["radius"], 0, lo_open=True),
            checks.seed_value("seed", spec["seed"]))
