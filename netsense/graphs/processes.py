"""Switching directed communication graphs and the joint strong-connectivity check.

Conventions. A graph on ``N`` nodes is a boolean adjacency array ``adj`` of shape
``(N, N)`` with ``adj[i, l] = True`` when ``l`` can send to ``i`` at that step (``l`` is
an in-neighbour of ``i``, ``l ∈ N_i[k]``); the diagonal is always ``False``. A graph
sequence is an array ``(K, N, N)``.

A :class:`GraphProcess` is a frozen description; ``process.sample(rng, K, state)``
returns the next ``K`` graphs and the process state to continue from, so long runs can
be generated in chunks and a run is reproducible from its seed.

Assumption 1 (joint strong connectivity): there is ``T`` such that the union graph over
every interval ``[kT, (k+1)T)`` is strongly connected; :func:`check_joint_connectivity`
tests it on a finite sequence and :func:`smallest_period` finds the smallest such ``T``.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numba import prange
from numba.np.random.generator_core import next_double
from numba.np.random.random_methods import buffered_bounded_lemire_uint32, random_interval

from netsense.kernels import checks
from netsense.kernels.jit import NO_STREAMS, Driver, bit_generator, bit_streams

if TYPE_CHECKING:
    import networkx as nx


# ----------------------------------------------------------------------------- helpers
def as_adjacency(graph, num_nodes: int | None = None) -> np.ndarray:
    """Convert an edge list ``[(l, i), ...]`` (``l -> i``), a networkx DiGraph or an
    adjacency array into the ``(N, N)`` boolean in-neighbour adjacency."""
    nx = sys.modules.get("networkx")  # a DiGraph exists only once networkx is imported
    if nx is not None and isinstance(graph, nx.DiGraph):
        N = graph.number_of_nodes() if num_nodes is None else num_nodes
        adj = np.zeros((N, N), dtype=bool)
        for l, i in graph.edges():
            adj[i, l] = True
    elif isinstance(graph, np.ndarray) and graph.ndim == 2:
        adj = graph.astype(bool).copy()
        if adj.shape[0] != adj.shape[1]:
            raise ValueError(f"adjacency must be square, got shape {adj.shape}")
    else:
        if num_nodes is None:
            raise ValueError("num_nodes is required for an edge list")
        adj = np.zeros((num_nodes, num_nodes), dtype=bool)
        for e in graph:
            if (isinstance(e, (str, bytes)) or not hasattr(e, "__len__") or len(e) != 2
                    or any(isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer))
                           for v in e)):
                raise ValueError(f"edges must be pairs [l, i] of node ids (l -> i), got {e!r}")
            l, i = (int(v) for v in e)
            if not (0 <= l < num_nodes and 0 <= i < num_nodes):
                raise ValueError(f"edge {e} names a node outside 0..{num_nodes - 1}")
            adj[i, l] = True
    np.fill_diagonal(adj, False)
    return adj


def to_networkx(adj: np.ndarray) -> nx.DiGraph:
    """DiGraph with an edge ``l -> i`` for every ``adj[i, l]``."""
    import networkx as nx  # imported on first use (import netsense stays light)

    g = nx.DiGraph()
    g.add_nodes_from(range(adj.shape[0]))
    i, l = np.nonzero(adj)
    g.add_edges_from(zip(l.tolist(), i.tolist(), strict=True))
    return g


def is_strongly_connected(adj: np.ndarray) -> bool:
    """Whether the directed graph ``adj`` is strongly connected (networkx)."""
    import networkx as nx

    return bool(nx.is_strongly_connected(to_networkx(adj)))


def in_neighbor_slots(adj: np.ndarray, max_degree: int | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """In-neighbours of every node as padded slots, in increasing node order.

    Parameters
    ----------
    adj : (..., N, N) bool
        Adjacency (``adj[..., i, l]``: ``l -> i``).
    max_degree : int, optional
        Number of slots ``D``; default the largest in-degree present.

    Returns
    -------
    nbr : (..., N, D) int
        Slot ``d`` of node ``i`` holds its ``d``-th smallest in-neighbour, or ``-1``.
    valid : (..., N, D) bool
        Which slots hold a neighbour.

    Raises
    ------
    ValueError
        If some node has more in-neighbours than ``max_degree``.
    """
    adj = np.asarray(adj, dtype=bool)
    N = adj.shape[-1]
    deg = adj.sum(-1)
    D = int(deg.max(initial=0)) if max_degree is None else int(max_degree)
    if deg.size and deg.max() > D:
        raise ValueError(f"a node has in-degree {int(deg.max())} > max_degree = {D}")
    if D > N:
        raise ValueError(f"max_degree = {D} exceeds N - 1 = {N - 1}")
    # Scatter each neighbour l of i into slot (number of neighbours of i before l): this
    # is the ascending order an argsort would give, at the cost of one nonzero().
    flat = adj.reshape(-1, N)
    rows, cols = np.nonzero(flat)
    cdt = np.int16 if N < 2**15 else np.int64  # counts <= N: small cumsum temporaries
    pos = np.cumsum(flat, axis=1, dtype=cdt)[rows, cols] - 1
    nbr = np.full((flat.shape[0], D), -1, dtype=np.int64)
    nbr[rows, pos] = cols
    nbr = nbr.reshape(adj.shape[:-1] + (D,))
    valid = nbr >= 0
    return nbr, valid


def slot_adjacency(nbr: np.ndarray, num_nodes: int) -> np.ndarray:
    """The graphs of slot tables (inverse of :func:`in_neighbor_slots`).

    ``nbr (..., N, D)`` in-neighbour slots (``-1`` = empty); returns ``adj (..., N, N)``
    bool with ``adj[..., i, l]`` True iff ``l`` is in a slot of ``i``.
    """
    nbr = np.asarray(nbr)
    adj = np.zeros(nbr.shape[:-1] + (int(num_nodes),), dtype=bool)
    *lead, d = np.nonzero(nbr >= 0)
    adj[(*lead, nbr[(*lead, d)])] = True
    return adj


def _check_slot_out(out: np.ndarray, shape: tuple[int, ...]) -> None:
    """``out`` must be a signed integer array of ``shape`` (runs, steps, N, D) whose type
    holds every node id ``0..N-1``."""
    if not isinstance(out, np.ndarray) or out.shape != tuple(shape) \
            or out.dtype.kind != "i" or np.iinfo(out.dtype).max < shape[2] - 1:
        got = (out.shape, out.dtype) if isinstance(out, np.ndarray) else type(out)
        raise ValueError(f"out must be a signed integer array of shape {tuple(shape)} "
                         f"that holds node ids up to {shape[2] - 1}, got {got}")


def _check_runs(rngs: Sequence, states: Sequence) -> None:
    if len(states) != len(rngs):
        raise ValueError(f"states must hold one state per generator ({len(rngs)}), "
                         f"got {len(states)}")


# ----------------------------------------------------------------------------- processes
#: How :class:`MarkovLinkFailures` draws its uniforms: ``"all"`` one per node pair and
#: step (the original stream, every ``-v0`` scenario), ``"base"`` one per base edge and
#: step (O(N D) instead of O(N^2); a different realisation, so only new scenario versions).
MARKOV_DRAWS = ("all", "base")

class GraphProcess:
    """Frozen description of a random or deterministic graph sequence."""

    num_nodes: int

    def initial_state(self, rng: np.random.Generator) -> Any:
        """Process state at ``k = 0``."""
        return 0

    def sample(self, rng: np.random.Generator, num_steps: int, state: Any
               ) -> tuple[np.ndarray, Any]:
        """Next ``num_steps`` graphs ``(K, N, N)`` and the state to continue from."""
        raise NotImplementedError  # pragma: no cover

    def sample_many(self, rngs: Sequence[np.random.Generator], num_steps: int,
                    states: Sequence[Any]) -> tuple[np.ndarray, list]:
        """:meth:`sample` for several independent runs at once: ``(M, K, N, N)`` and the
        ``M`` states. Run ``m`` uses only ``rngs[m]`` and equals ``sample(rngs[m], ...)``
        exactly (processes override this to batch the work; the default loops)."""
        outs, new = [], []
        for rng, st in zip(rngs, states, strict=True):
            adj, st = self.sample(rng, num_steps, st)
            outs.append(adj)
            new.append(st)
        N = self.num_nodes
        return (np.stack(outs) if outs else np.zeros((0, num_steps, N, N), bool)), new

    def sample_slots_many(self, rngs: Sequence[np.random.Generator], num_steps: int,
                          states: Sequence[Any], max_degree: int,
                          out: np.ndarray | None = None) -> tuple[np.ndarray, list]:
        """:meth:`sample_many` as slot tables: ``nbr (M, K, N, max_degree)`` (the
        :func:`in_neighbor_slots` of the graphs, ``-1`` = empty slot) and the states.

        ``out``: an integer array of that shape to write the slots into (returned). The
        arguments are checked before anything is drawn; a node with more than
        ``max_degree`` in-neighbours in a drawn graph raises after drawing (``out`` is not
        written then)."""
        _check_runs(rngs, states)
        if out is not None:
            _check_slot_out(out, (len(rngs), int(num_steps), self.num_nodes, max_degree))
        adj, new = self.sample_many(rngs, num_steps, states)
        nbr = in_neighbor_slots(adj, max_degree)[0]
        if out is None:
            return nbr, new
        out[...] = nbr
        return out, new

    def redraw_state(self, rng: np.random.Generator, state: Any, previous: Any,
                     graph: np.ndarray) -> Any:
        """A state to continue from after step ``k`` whose unseen randomness is redrawn.

        The state :meth:`sample` returns after drawing ``G[k]`` may already hold randomness
        about ``G[k+1]`` (e.g. the next link states). This returns a state drawn from the
        process's law given the state ``previous`` that ``G[k]`` was drawn from and the
        graph ``graph`` = ``G[k]`` it gave, using ``rng`` for everything else
        (:mod:`netsense.graphs.conditional`).

        The default draws step ``k`` again from ``previous`` with ``rng`` and keeps the
        state that gives: exact for processes whose ``G[k]`` is a function of the state
        before it (static, periodic, Markov link failures: ``G[k]`` is the link states,
        mobility: the disk graph of the positions at ``k``). A process that draws ``G[k]``
        itself at random must override this; the default raises ``NotImplementedError``
        when the graph it draws is not ``graph``.

        Parameters
        ----------
        rng : numpy.random.Generator
            Fresh randomness.
        state : state
            The state after ``G[k]`` as drawn (what is redrawn).
        previous : state
            The process state before ``G[k]`` was drawn.
        graph : (N, N) bool
            ``G[k]``.
        """
        adj, state = self.sample(rng, 1, previous)
        if not np.array_equal(adj[0], graph):
            raise NotImplementedError(
                f"{type(self).__name__} draws G[k] at random from the state before it, so "
                "the state after it cannot be redrawn by drawing step k again: the process "
                "must implement redraw_state")
        return state

    @property
    def max_in_degree(self) -> int:
        """Upper bound on any node's in-degree (fixes the env's slot count)."""
        return self.num_nodes - 1

    @property
    def edge_support(self) -> np.ndarray | None:
        """``(N, N)`` bool: the pairs ``[i, l]`` that can be an edge ``l -> i`` of some
        graph of the process (every other entry of every ``G[k]`` is ``False``), or
        ``None`` where the process does not fix one (the default: any pair can be)."""
        return None

    def slot_sample_bytes(self, num_steps: int) -> int:
        """Bytes of temporaries per run of :meth:`sample_slots_many` (batches are drawn
        in groups that keep them near a budget); here ``(K, N, N)`` graphs and their slot
        bookkeeping."""
        return int(num_steps) * self.num_nodes ** 2 * 11

    def sequence(self, num_steps: int, rng: np.random.Generator | int | None = None
                 ) -> np.ndarray:
        """Convenience: ``num_steps`` graphs from a fresh start."""
        num_steps = checks.integer("num_steps", num_steps, 0)
        rng = np.random.default_rng(rng)
        seq, _ = self.sample(rng, num_steps, self.initial_state(rng))
        return seq

    def to_dict(self) -> dict:
        raise NotImplementedError  # pragma: no cover


class _SlotTableProcess(GraphProcess):
    """A process whose compiled pass writes slot tables (:meth:`sample_slots_many`):
    :meth:`sample` and :meth:`sample_many` are the graphs of those tables (every node's
    in-neighbours fit, ``D`` = :attr:`max_in_degree`), so the process's rule has one
    implementation, the compiled one."""

    def sample(self, rng, num_steps, state):
        adj, (state,) = self.sample_many([rng], num_steps, [state])
        return adj[0], state

    def sample_many(self, rngs, num_steps, states):
        nbr, new = self.sample_slots_many(rngs, num_steps, states, self.max_in_degree)
        return slot_adjacency(nbr, self.num_nodes), new


@dataclass(frozen=True, eq=False)
class PeriodicGraphs(GraphProcess):
    """The graphs ``graphs[0], graphs[1], ...`` repeated with period ``len(graphs)``."""

    graphs: tuple[np.ndarray, ...]
    num_nodes: int = field(init=False)

    def __post_init__(self) -> None:
        if len(self.graphs) == 0:
            raise ValueError("PeriodicGraphs needs at least one graph")
        first = np.asarray(self.graphs[0])
        N = first.shape[0] if first.ndim == 2 else None
        if N is None:
            raise ValueError("give the graphs as (N, N) adjacency arrays "
                             "(use as_adjacency for edge lists)")
        gs = tuple(as_adjacency(np.asarray(g), N) for g in self.graphs)
        if any(g.shape != (N, N) for g in gs):
            raise ValueError("all graphs of a PeriodicGraphs must have the same size")
        object.__setattr__(self, "graphs", gs)
        object.__setattr__(self, "num_nodes", N)

    @classmethod
    def from_edges(cls, num_nodes: int, edge_lists: Sequence[Sequence[tuple[int, int]]]
                   ) -> PeriodicGraphs:
        """Build from edge lists ``[(l, i), ...]`` meaning ``l -> i``."""
        return cls(tuple(as_adjacency(list(e), num_nodes) for e in edge_lists))

    @property
    def max_in_degree(self) -> int:
        return int(max(g.sum(-1).max() for g in self.graphs))

    def sample(self, rng, num_steps, state):
        P = len(self.graphs)
        idx = (state + np.arange(num_steps)) % P
        return np.stack(self.graphs)[idx], int((state + num_steps) % P)

    def to_dict(self) -> dict:
        return {"kind": "periodic", "num_nodes": self.num_nodes,
                "edges": [[[int(l), int(i)] for i, l in zip(*np.nonzero(g), strict=True)]
                          for g in self.graphs]}


def fig1_graphs() -> PeriodicGraphs:
    """The two graphs of Fig. 1 (0-based nodes), alternating: (a) at even, (b) at odd steps.

    The paper gives the graphs only as a picture; the text fixes them: at even steps node 2
    hears node 1 (and node 3 hears node 2), at odd steps node 3 hears node 1 and node 2
    hears node 3 ("at time-step 1, node 2 is better off rejecting the information from
    node 3"). Each graph is a spanning tree rooted at node 1, their union is strongly
    connected only with the return edges, so we add 2 -> 1 in (a) and 3 -> 1 in (b)
    (they do not affect nodes 2 and 3). With 0-based labels: (a) 0->1, 1->2, 1->0;
    (b) 0->2, 2->1, 2->0. Assumption 1 holds with ``T = 2``.
    """
    return PeriodicGraphs.from_edges(3, [[(0, 1), (1, 2), (1, 0)], [(0, 2), (2, 1), (2, 0)]])


@dataclass(frozen=True)
class RandomJointlyConnected(_SlotTableProcess):
    """Random graphs whose union over every window ``[kT, (k+1)T)`` is strongly connected.

    Per window: a directed Hamiltonian cycle over a random permutation (strongly connected
    by construction) plus each other ordered pair with probability ``extra_edge_prob``;
    every edge of that union is then shown at one uniformly chosen step of the window.
    """

    num_nodes: int
    period: int
    extra_edge_prob: float = 0.0

    def __post_init__(self) -> None:
        checks.integer("num_nodes", self.num_nodes)
        checks.integer("period", self.period)
        checks.number("extra_edge_prob", self.extra_edge_prob, 0, 1)
        if self.num_nodes < 2:
            raise ValueError(f"num_nodes must be >= 2, got {self.num_nodes}")
        if self.period < 1:
            raise ValueError(f"period must be >= 1, got {self.period}")
        if not 0 <= self.extra_edge_prob <= 1:
            raise ValueError(f"extra_edge_prob must be in [0, 1], got {self.extra_edge_prob}")

    def initial_state(self, rng):
        return (0, None)

    def sample_slots_many(self, rngs, num_steps, states, max_degree, out=None):
        # One compiled pass over the runs draws every window from its run's generator
        # (numpy's algorithms on numpy's stream, :func:`_jsc_slots`) and writes the slot
        # tables; the Python loop over runs and windows it replaces took most of a core
        # step on comm_process_noise-v0 (B = 256, N = 10, T = 2).
        M, K, N, T = len(rngs), int(num_steps), self.num_nodes, self.period
        _check_runs(rngs, states)
        if out is not None:
            _check_slot_out(out, (M, K, N, max_degree))
        pos = np.empty(M, dtype=np.int64)
        windows = np.zeros((M, T, N, N), dtype=bool)
        for m, (p_, w) in enumerate(states):
            pos[m] = p_
            if w is not None:
                windows[m] = w
        # a node of a drawn graph has at most N - 1 in-neighbours: a smaller D can
        # overflow, and then nothing is written into ``out``
        direct = out is not None and max_degree >= N - 1
        nbr = out if direct else np.empty((M, K, N, max_degree), dtype=np.int64)
        streams = bit_streams(rngs) if M else None
        if streams is None:  # one generator twice (or none): run by run, in order
            runs = [(bit_streams([rng]), [m]) for m, rng in enumerate(rngs)]
        else:
            runs = [(streams, list(range(M)))]
        degree = 0
        for (fns, addr), members in runs:
            sel = np.asarray(members)
            if len(runs) == 1:  # every run at once, in place
                w_sel, p_sel, part = windows, pos, nbr
            else:
                w_sel, p_sel = windows[sel], pos[sel]
                part = np.empty((len(sel), K, N, max_degree), dtype=np.int64)
            deg = np.empty(len(sel), dtype=np.int64)
            _jsc_slots.at(len(sel) * K * N * N, runs=len(sel))(
                fns, addr, float(self.extra_edge_prob), p_sel, w_sel, part,
                np.empty((len(sel), N, N), dtype=bool), np.empty((len(sel), N), np.int64), deg)
            degree = max(degree, int(deg.max(initial=0)))
            if len(runs) > 1:
                windows[sel], pos[sel], nbr[sel] = w_sel, p_sel, part
        if degree > max_degree:
            raise ValueError(f"a node has in-degree {degree} > max_degree = {max_degree}")
        if out is not None and not direct:
            out[...] = nbr
            nbr = out
        return nbr, [(int(pos[m]), windows[m]) for m in range(M)]

    def redraw_state(self, rng, state, previous, graph):
        """The state after ``G[k]`` with the unseen steps of its window redrawn from their
        law given the shown ones (:func:`netsense.graphs.conditional.redraw_window`; ``N <=
        16``); at the end of a window nothing of the next one is drawn yet and the state is
        returned as is."""
        from netsense.graphs.conditional import redraw_window

        pos, window = state
        if pos == 0:
            return state
        return pos, redraw_window(window, pos, float(self.extra_edge_prob), rng)

    def to_dict(self) -> dict:
        return {"kind": "random_jsc", "num_nodes": self.num_nodes, "period": self.period,
                "extra_edge_prob": self.extra_edge_prob}


#: Fewest runs for which :meth:`MarkovLinkFailures.sample_slots_many` runs its pass
#: threaded (``Driver(min_runs=...)``; see the measurements there).
MARKOV_THREADED_RUNS = 256


@dataclass(frozen=True, eq=False)
class MarkovLinkFailures(_SlotTableProcess):
    """Each edge of a base graph fails and recovers as an independent two-state chain.

    An up link goes down with probability ``p_fail`` per step; a down link comes back with
    probability ``p_recover``. Links start in the stationary distribution. Joint strong
    connectivity is *not* guaranteed; check it with :func:`check_joint_connectivity`.
    """

    base: np.ndarray
    p_fail: float
    p_recover: float
    draws: str = "all"
    num_nodes: int = field(init=False)

    def __post_init__(self) -> None:
        base = as_adjacency(checks.array("base", self.base, (None, None), kind="ibf"))
        for name in ("p_fail", "p_recover"):
            v = checks.number(name, getattr(self, name), 0, 1)
            if not 0 <= v <= 1:
                raise ValueError(f"{name} must be in [0, 1], got {v}")
        if self.p_fail + self.p_recover == 0:
            raise ValueError("p_fail and p_recover cannot both be 0")
        if self.draws not in MARKOV_DRAWS:
            raise ValueError(f"draws must be one of {MARKOV_DRAWS}, got {self.draws!r}")
        object.__setattr__(self, "base", base)
        object.__setattr__(self, "num_nodes", base.shape[0])
        # base edges in row-major order (node i, then ascending l)
        object.__setattr__(self, "_edges", np.nonzero(base))

    @property
    def max_in_degree(self) -> int:
        return int(self.base.sum(-1).max())

    @property
    def edge_support(self) -> np.ndarray:
        """The base graph: a link that is up is a base edge."""
        return self.base

    def slot_sample_bytes(self, num_steps):
        # per run: its stacked and returned N x N link states, its E link states and slot
        # counters, and with draws = "all" its (K, E) uniforms (the (K, N, N) draw they
        # are taken from is freed run by run; "base" draws inside the compiled pass)
        N, E = self.num_nodes, self._edges[0].size
        per_run = 2 * N * N + E + 8 * N
        return per_run if self.draws == "base" else per_run + int(num_steps) * E * 8

    def _edge_uniforms(self, rng, shape) -> np.ndarray:
        """Uniforms of the base edges, ``shape + (E,)``: ``draws = "all"`` draws one per
        node pair (the original stream) and keeps the edges', ``"base"`` only the E."""
        ei, el = self._edges
        if self.draws == "base":
            return rng.random(shape + (ei.size,))
        return rng.random(shape + self.base.shape)[..., ei, el]

    def initial_state(self, rng):
        p_up = self.p_recover / (self.p_fail + self.p_recover)
        if self.draws == "base":
            ei, el = self._edges
            up = np.zeros(self.base.shape, dtype=bool)
            up[ei, el] = self._edge_uniforms(rng, ()) < p_up
            return up
        return (rng.random(self.base.shape) < p_up) & self.base

    def sample_slots_many(self, rngs, num_steps, states, max_degree, out=None):
        # Works on the E base edges only: each run draws its own chunk from its own
        # generator (the stream of sample()), and the two-state recursion and the slot
        # tables run once over all runs.
        ei, el = self._edges
        M, K, N, E = len(rngs), num_steps, self.num_nodes, ei.size
        # every check before anything is drawn (the compiled pass has no bounds checks)
        _check_runs(rngs, states)
        if max_degree < self.max_in_degree:  # all of a node's base links can be up
            raise ValueError(f"max_degree must be >= the base graph's in-degree "
                             f"{self.max_in_degree}, got {max_degree}")
        try:  # one array of the states (a refill passes 1,024 of them: no Python loop
            held = np.array(states, dtype=bool)  # unless a shape is wrong)
        except ValueError:  # shapes that do not stack
            held = None
        if held is None or held.shape != (M, *self.base.shape):
            for st in states:
                if np.shape(st) != self.base.shape:
                    raise ValueError(f"a link state must have shape {self.base.shape}, "
                                     f"got {np.shape(st)}")
        if out is not None:
            _check_slot_out(out, (M, K, N, max_degree))
        # C order (numpy lays the advanced-index result out as F): one compiled layout
        up = np.ascontiguousarray(held[:, ei, el]) if M else np.zeros((0, E), bool)
        # draws = "base" slot tables: each run's uniforms are drawn inside the compiled
        # pass, from its own generator through numpy's next_double (the same stream as
        # rng.random), so no (M, K, E) array of uniforms is built
        streams = bit_streams(rngs) if self.draws == "base" else None
        if streams is None:
            ue = np.empty((M, K, E))
            for m, rng in enumerate(rngs):
                if self.draws == "base":
                    rng.random(out=ue[m])  # the stream of _edge_uniforms, written in place
                else:
                    ue[m] = self._edge_uniforms(rng, (K,))
            fns, addr = NO_STREAMS, np.zeros(M, dtype=np.uintp)
        else:
            ue = np.empty((0, 0, 0))
            fns, addr = streams
        # slots: the up base links of each node in ascending order (edges are row-major),
        # and the two-state recursion, in one compiled pass over (run, step, edge)
        nbr = np.empty((M, K, N, max_degree), dtype=np.int64) if out is None else out
        # threaded over runs only for many runs: measured on the 2-vCPU benchmark VM, the
        # threaded pass takes 4.4 vs 9.4 ms (serial) per 64-step chunk at 1,024 runs of
        # 30 edges and 12.5 vs 27 ms at 1,024 x 90, but at 64 runs x 300 edges it took
        # either 3.2 ms or, in about half of the processes (under numba's OpenMP layer,
        # for every chunk of that process), 16-20 ms against a steady 5.4 ms serial
        _markov_slots.at(M * K * E, runs=M)(
            ue, fns, addr, streams is not None, up, ei, el, float(self.p_fail),
            float(self.p_recover), nbr, np.empty((M, N), dtype=np.int64))
        new = np.zeros((M, N, N), dtype=bool)
        new[:, ei, el] = up
        return nbr, list(new)

    def to_dict(self) -> dict:
        i, l = np.nonzero(self.base)
        return {"kind": "markov", "num_nodes": self.num_nodes, "p_fail": self.p_fail,
                "p_recover": self.p_recover,
                "base_edges": [[int(a), int(b)] for a, b in zip(l, i, strict=True)],
                **({} if self.draws == "all" else {"draws": self.draws})}


@dataclass(frozen=True, eq=False)
class Gossip(GraphProcess):
    """One directed edge per step, drawn uniformly from a base graph's edges."""

    base: np.ndarray
    num_nodes: int = field(init=False)

    def __post_init__(self) -> None:
        base = as_adjacency(checks.array("base", self.base, (None, None), kind="ibf"))
        if not base.any():
            raise ValueError("Gossip needs a base graph with at least one edge")
        object.__setattr__(self, "base", base)
        object.__setattr__(self, "num_nodes", base.shape[0])

    @classmethod
    def complete(cls, num_nodes: int) -> Gossip:
        """Gossip over the complete directed graph."""
        return cls(~np.eye(num_nodes, dtype=bool))

    @property
    def max_in_degree(self) -> int:
        return 1

    def sample(self, rng, num_steps, state):
        i, l = np.nonzero(self.base)
        pick = rng.integers(0, i.size, size=num_steps)
        out = np.zeros((num_steps,) + self.base.shape, dtype=bool)
        out[np.arange(num_steps), i[pick], l[pick]] = True
        return out, state

    def redraw_state(self, rng, state, previous, graph):
        """Nothing to redraw: every step's edge is drawn afresh."""
        return state

    def to_dict(self) -> dict:
        i, l = np.nonzero(self.base)
        return {"kind": "gossip", "num_nodes": self.num_nodes,
                "base_edges": [[int(a), int(b)] for a, b in zip(l, i, strict=True)]}


# ----------------------------------------------------------------------------- Assumption 1
@dataclass(frozen=True)
class JointConnectivityReport:
    """Outcome of :func:`check_joint_connectivity`.

    Attributes
    ----------
    holds : bool
        Whether every complete window ``[kT, (k+1)T)`` of the sequence is strongly connected.
    period : int
        The ``T`` tested.
    windows_checked : int
        Number of complete windows in the sequence.
    first_failure : tuple of int or None
        ``(start, stop)`` of the first window (half-open) whose union is not strongly
        connected.
    """

    holds: bool
    period: int
    windows_checked: int
    first_failure: tuple[int, int] | None

    def __str__(self) -> str:
        if self.holds:
            return (f"Assumption 1 holds with T = {self.period} on all "
                    f"{self.windows_checked} windows")
        a, b = self.first_failure  # type: ignore[misc]
        return (f"Assumption 1 fails with T = {self.period}: the union over [{a}, {b}) "
                f"is not strongly connected")


def _check_seq(seq: np.ndarray) -> np.ndarray:
    seq = np.asarray(seq, dtype=bool)
    if seq.ndim != 3 or seq.shape[1] != seq.shape[2]:
        raise ValueError(f"graph sequence must have shape (K, N, N), got {seq.shape}")
    return seq


def check_joint_connectivity(seq: np.ndarray, period: int) -> JointConnectivityReport:
    """Test Assumption 1 with a given ``T`` on every complete window of ``seq``."""
    seq = _check_seq(seq)
    if period < 1:
        raise ValueError(f"period must be >= 1, got {period}")
    windows = seq.shape[0] // period
    if windows == 0:
        raise ValueError(f"sequence of length {seq.shape[0]} is shorter than T = {period}")
    unions = seq[: windows * period].reshape(windows, period, *seq.shape[1:]).any(axis=1)
    for w, union in enumerate(unions):
        if not is_strongly_connected(union):
            return JointConnectivityReport(False, period, windows,
                                           (w * period, (w + 1) * period))
    return JointConnectivityReport(True, period, windows, None)


def smallest_period(seq: np.ndarray, max_period: int | None = None) -> int | None:
    """Smallest ``T`` for which Assumption 1 holds on ``seq`` (``None`` if none does).

    Only ``T`` with at least one complete window (``T <= K``) are tried.
    """
    seq = _check_seq(seq)
    K = seq.shape[0]
    for T in range(1, (K if max_period is None else min(K, max_period)) + 1):
        if check_joint_connectivity(seq, T).holds:
            return T
    return None




def _markov_slots(u, fns, states, drawn, up, ei, el, p_fail, p_recover, nbr, pos_all):
    """Two-state link chains and slot tables of :class:`MarkovLinkFailures`.

    The uniform of run ``m``, step ``k``, edge ``e`` is ``u[m, k, e]``, or, when
    ``drawn``, the next double of run ``m``'s generator (``fns``, ``states[m]`` of
    :func:`netsense.kernels.jit.bit_streams`), taken in ``(k, e)`` order: the stream of
    ``rng.random((K, E))``. ``up (M, E)`` link states at the first step
    (advanced in place to the state after the last), edges ``(ei, el)`` in row-major
    order. Step ``k`` uses the states before its transition (an up link stays up iff
    ``u >= p_fail``, a down link comes back iff ``u < p_recover``). Writes
    ``nbr (M, K, N, D)`` (``-1`` = empty slot); the caller guarantees ``D`` at least the
    base graph's in-degree, so every up link has a slot.
    """
    M, K, N, D = nbr.shape
    E = ei.shape[0]
    for m in prange(M):
        pos = pos_all[m]
        bg = bit_generator(fns, states[m])
        for k in range(K):
            nbr[m, k] = -1
            pos[:] = 0
            for e in range(E):
                if up[m, e]:
                    i = ei[e]
                    nbr[m, k, i, pos[i]] = el[e]
                    pos[i] += 1
                v = next_double(bg) if drawn else u[m, k, e]
                up[m, e] = v >= p_fail if up[m, e] else v < p_recover


_markov_slots = Driver(_markov_slots, min_runs=MARKOV_THREADED_RUNS)


def _jsc_slots(fns, states, p, pos_all, windows, nbr, union_all, perm_all, degree):
    """Windows and slot tables of :class:`RandomJointlyConnected`, run by run.

    Run ``m`` continues at step ``pos_all[m]`` of its window ``windows[m] (T, N, N)`` and
    draws a new window from its generator (``fns``, ``states[m]`` of
    :func:`netsense.kernels.jit.bit_streams`) whenever a window starts, with numpy's
    algorithms on numpy's stream, in the order of::

        union = rng.random((N, N)) < p          # next_double, row-major
        perm = rng.permutation(N)               # Fisher-Yates, numpy's random_interval
        union[perm[(m + 1) % N], perm[m]] = True for every m; no self-loops
        when = rng.integers(0, T, size=(N, N))  # Lemire's bounded draw (none when T = 1)
        window[t] = union & (when == t)

    Writes ``nbr (M, K, N, D)``: the in-neighbours of each node at each step in
    increasing order, ``-1`` after them (at most ``D`` of them); leaves ``pos_all`` and
    ``windows`` where the runs continue, and ``degree[m]``, the largest in-degree of run
    ``m``'s graphs (more than ``D``: the slots overflowed and were cut).
    """
    M, K, N, D = nbr.shape
    T = windows.shape[1]
    for m in prange(M):
        degree[m] = 0
        bg = bit_generator(fns, states[m])
        union, perm, window = union_all[m], perm_all[m], windows[m]
        pos = pos_all[m]
        for k in range(K):
            if pos == 0:
                for i in range(N):
                    for j in range(N):
                        union[i, j] = next_double(bg) < p
                for i in range(N):
                    perm[i] = i
                for i in range(N - 1, 0, -1):
                    j = np.int64(random_interval(bg, i))
                    swap = perm[i]
                    perm[i] = perm[j]
                    perm[j] = swap
                for i in range(N):
                    union[perm[(i + 1) % N], perm[i]] = True
                for i in range(N):
                    union[i, i] = False
                for i in range(N):
                    for j in range(N):
                        when = (np.int64(buffered_bounded_lemire_uint32(bg, T - 1))
                                if T > 1 else 0)
                        for t in range(T):
                            window[t, i, j] = union[i, j] and when == t
            for i in range(N):
                d = 0
                for j in range(N):
                    if window[pos, i, j]:
                        if d < D:
                            nbr[m, k, i, d] = j
                        d += 1
                for e in range(d, D):
                    nbr[m, k, i, e] = -1
                degree[m] = max(degree[m], d)
            pos = (pos + 1) % T
        pos_all[m] = pos


_jsc_slots = Driver(_jsc_slots)
