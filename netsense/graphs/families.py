"""Graph families for topology experiments, built by name.

:class:`RoundRobinRing` (a directed ring whose edges are shown one residue class of steps
at a time; ``period = 1`` is the static directed ring, ``period = N`` the token ring),
:class:`StaticGraph`, :func:`ring_with_chords`, and :func:`make_graph_process`, which
builds every family of a topology sweep (:data:`FAMILIES`) by name. :func:`guaranteed_period`
says which ``T`` a family guarantees Assumption 1 for; :func:`window_connectivity` is the
window-by-window timeline behind :func:`netsense.graphs.processes.check_joint_connectivity`.
The sweep itself (observers run on these families) is :mod:`netsense.studies.sweep`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from netsense.graphs.processes import (
    Gossip,
    GraphProcess,
    MarkovLinkFailures,
    RandomJointlyConnected,
    as_adjacency,
    is_strongly_connected,
)

__all__ = [
    "FAMILIES", "MARKOV_P_RECOVER", "RoundRobinRing", "StaticGraph", "guaranteed_period",
    "make_graph_process", "ring_with_chords", "window_connectivity",
]


# ----------------------------------------------------------------------------- families
@dataclass(frozen=True)
class RoundRobinRing(GraphProcess):
    """Directed ring ``0 -> 1 -> ... -> N-1 -> 0`` shown one residue class at a time.

    Edge ``l -> l+1 (mod N)`` is present at the steps ``k`` with ``k ≡ slot(l) (mod
    period)``, where ``slot(l) = l mod period`` for ``order="forward"`` (a message can
    travel on consecutive hops without waiting) and ``slot(l) = (-l - 1) mod period`` for
    ``order="backward"`` (each hop waits for the next period: the slowest schedule).
    The union over every window ``[kT, (k+1)T)`` with ``T = period`` is the ring, so
    Assumption 1 holds with ``T = period``; ``period = 1`` is the static directed ring,
    ``period = N`` the token ring (one message per step).

    Parameters
    ----------
    num_nodes : int
        ``N >= 2``.
    period : int
        ``1 <= T <= N``.
    order : {"forward", "backward"}
        Schedule of the edges inside a period (see above).
    """

    num_nodes: int
    period: int = 1
    order: str = "forward"

    def __post_init__(self) -> None:
        if self.num_nodes < 2:
            raise ValueError(f"num_nodes must be >= 2, got {self.num_nodes}")
        if not 1 <= self.period <= self.num_nodes:
            raise ValueError(f"period must be in [1, num_nodes = {self.num_nodes}], "
                             f"got {self.period}")
        if self.order not in ("forward", "backward"):
            raise ValueError(f"order must be 'forward' or 'backward', got {self.order!r}")

    @property
    def max_in_degree(self) -> int:
        return 1

    def slots(self) -> np.ndarray:
        """``slot[l]``: residue mod ``period`` of the steps showing edge ``l -> l+1``."""
        l = np.arange(self.num_nodes)
        return l % self.period if self.order == "forward" else (-l - 1) % self.period

    def sample(self, rng, num_steps, state):
        N = self.num_nodes
        k = state + np.arange(num_steps)
        on = (k[:, None] % self.period) == self.slots()[None, :]  # (K, N): edge l on
        out = np.zeros((num_steps, N, N), dtype=bool)
        l = np.arange(N)
        out[:, (l + 1) % N, l] = on
        return out, int(state + num_steps)

    def to_dict(self) -> dict:
        return {"kind": "round_robin_ring", "num_nodes": self.num_nodes,
                "period": self.period, "order": self.order}


@dataclass(frozen=True, eq=False)
class StaticGraph(GraphProcess):
    """The same graph at every step (Assumption 1 with ``T = 1`` iff strongly connected)."""

    adjacency: np.ndarray
    num_nodes: int = field(init=False)

    def __post_init__(self) -> None:
        adj = as_adjacency(np.asarray(self.adjacency))
        object.__setattr__(self, "adjacency", adj)
        object.__setattr__(self, "num_nodes", adj.shape[0])

    @property
    def max_in_degree(self) -> int:
        return int(self.adjacency.sum(-1).max())

    def sample(self, rng, num_steps, state):
        return np.broadcast_to(self.adjacency, (num_steps,) + self.adjacency.shape).copy(), state

    def to_dict(self) -> dict:
        i, l = np.nonzero(self.adjacency)
        return {"kind": "static", "num_nodes": self.num_nodes,
                "edges": [[int(a), int(b)] for a, b in zip(l, i, strict=True)]}


def ring_with_chords(N: int, chords: int = 1) -> np.ndarray:
    """Bidirectional ring plus links to the ``chords`` next-nearest nodes on each side.

    ``chords = 0`` is the bidirectional ring, the base graph of the Markov link-failure
    family of the sweep.
    """
    adj = np.zeros((N, N), dtype=bool)
    l = np.arange(N)
    for h in range(1, chords + 2):
        adj[(l + h) % N, l] = True
        adj[(l - h) % N, l] = True
    np.fill_diagonal(adj, False)
    return adj


#: Recovery probability of a failed link in the ``markov`` family.
MARKOV_P_RECOVER = 0.2

#: Families of :func:`make_graph_process` and the meaning of their ``param``.
FAMILIES: dict[str, str] = {
    "ring": "RoundRobinRing forward, T = period (param unused)",
    "ring_backward": "RoundRobinRing backward (slowest schedule), T = period",
    "random_jsc": "RandomJointlyConnected with period T, param = extra_edge_prob",
    "gossip": "one uniformly drawn edge of the complete graph per step (T measured)",
    "markov": "Markov link failures on the bidirectional ring, param = p_fail, "
              "p_recover = 0.2 (T measured)",
    "mobility": "random-waypoint agents in the unit square, param = radius (T measured)",
}


def make_graph_process(family: str, N: int, T: int = 1, param: float = 0.0) -> GraphProcess:
    """Build the graph process of a sweep family (see :data:`FAMILIES`).

    Raises
    ------
    ValueError
        On an unknown ``family`` (the message lists the known ones).
    """
    if family == "ring":
        return RoundRobinRing(N, T, "forward")
    if family == "ring_backward":
        return RoundRobinRing(N, T, "backward")
    if family == "random_jsc":
        return RandomJointlyConnected(N, T, param)
    if family == "gossip":
        return Gossip.complete(N)
    if family == "markov":
        return MarkovLinkFailures(ring_with_chords(N, 0), param, MARKOV_P_RECOVER)
    if family == "mobility":
        from netsense.graphs.mobility import RandomWaypoint

        return RandomWaypoint(N, radius=param)
    raise ValueError(f"family must be one of {sorted(FAMILIES)}, got {family!r}")


def guaranteed_period(process: GraphProcess) -> int | None:
    """The ``T`` for which a family guarantees Assumption 1, if it does by construction."""
    if isinstance(process, RandomJointlyConnected | RoundRobinRing):
        return process.period
    if isinstance(process, StaticGraph):
        return 1 if is_strongly_connected(process.adjacency) else None
    return None


def window_connectivity(seq: np.ndarray, period: int) -> np.ndarray:
    """Per complete window ``[wT, (w+1)T)``: is its union strongly connected? ``(W,)`` bool.

    The timeline behind :func:`netsense.graphs.processes.check_joint_connectivity` (which stops at
    the first failure): it shows *when* joint strong connectivity is lost and regained.
    """
    seq = np.asarray(seq, dtype=bool)
    if seq.ndim != 3:
        raise ValueError(f"seq must have shape (K, N, N), got {seq.shape}")
    if period < 1:
        raise ValueError(f"period must be >= 1, got {period}")
    W = seq.shape[0] // period
    unions = seq[: W * period].reshape(W, period, *seq.shape[1:]).any(1)
    return np.array([is_strongly_connected(u) for u in unions], dtype=bool)




























