"""Graph families for topology experiments and the measurements of a topology sweep.

What a network researcher asks of the freshness-index observer (Section IV of the paper)
on a given switching pattern, and how this module answers it:

* **When is every index triggered?** :func:`trigger_step` -- the first step from which
  every ``tau_i^{(j)}`` is finite; Lemma 3 bounds it by ``(N-1)T``
  (:func:`lemma3_bound`).
* **How stale does information get afterwards?** :func:`worst_index` -- the largest
  index from a given step on; Lemma 5 bounds it by ``2(N-1)T`` after ``(N-1)T``
  (:func:`lemma5_bound`); the same argument as Lemma 3's gives ``NT - 1``
  (:func:`sharp_index_bound`), which some graphs attain.
* **How long until the estimates are good?** :func:`steps_to_tolerance` on
  :func:`relative_error`; with deadbeat gains Corollary 1 bounds the time to an exact
  estimate by ``n + 2N(N-1)T`` (:func:`corollary1_bound`); with Theorem 1's rho-ordered
  gains the error bound of eq. (33) only starts at ``(2N-1)(N-1)T``
  (:func:`theorem1_onset`).
* **What does it cost?** ``Trajectory.messages`` (links that carried a message) and
  ``Trajectory.adoptions`` (substate estimates actually adopted) per step.
* **Age of information.** :func:`aoi_stats`: time-average, average peak and maximum of
  every ``tau_i^{(j)}`` (the freshness index *is* the AoI of node ``i``'s information
  about substate ``j`` relative to its source).

Graph families beyond :mod:`netsense.graphs`: :class:`RoundRobinRing` (a directed ring
whose edges are shown one residue class of steps at a time; ``period = 1`` is the static
directed ring, ``period = N`` the token ring) and :class:`StaticGraph`.
:func:`make_graph_process` builds every family of the sweep by name, and :func:`run_case`
runs one sweep case (a batch of seeds through the batched observer).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from netsense.graphs import (
    Gossip,
    GraphProcess,
    MarkovLinkFailures,
    RandomJointlyConnected,
    as_adjacency,
    check_joint_connectivity,
    is_strongly_connected,
    smallest_period,
)
from netsense.kernels import OMEGA

if TYPE_CHECKING:  # pragma: no cover
    from netsense.observers.base import DistributedObserver
    from netsense.systems import Plant

__all__ = [
    "FAMILIES", "RoundRobinRing", "StaticGraph", "SweepCase", "Trajectory", "aoi_stats",
    "corollary1_bound", "guaranteed_period", "lemma3_bound", "lemma5_bound",
    "sharp_index_bound",
    "make_graph_process",
    "relative_error", "ring_with_chords", "run_case", "run_observer", "run_sweep",
    "sample_graphs", "summarize", "write_csv",
    "steps_to_tolerance", "theorem1_onset",
    "trigger_step", "window_connectivity", "worst_index",
]


# ----------------------------------------------------------------------------- bounds
def lemma3_bound(N: int, T: int | float) -> float:
    """``(N-1)T``: every index is finite from this step on (Lemma 3, eq. (15))."""
    return (N - 1) * T


def lemma5_bound(N: int, T: int | float) -> float:
    """``2(N-1)T``: bound on every index for ``k >= (N-1)T`` (Lemma 5, eq. (17))."""
    return 2 * (N - 1) * T


def sharp_index_bound(N: int, T: int | float) -> float:
    """``NT - 1``: a sharper form of Lemma 5 (not in the paper), attained by some graphs.

    For ``k >= (N-1)T`` every index satisfies ``tau_i^{(j)}[k] <= NT - 1``. Proof: call
    information about substate ``j`` *as fresh as* ``t`` when its index is at most
    ``k - t``. Freshness as fresh as ``t`` never gets lost (an agent adopts only strictly
    fresher data, eqs. (9), (13), and otherwise ages by one, eq. (14)), and an agent with
    an in-neighbour holding it gets it (the rule adopts the freshest neighbour, or keeps
    something at least as fresh). In window ``[wT, (w+1)T)`` the union graph is strongly
    connected, so some edge leaves the set of agents holding data as fresh as ``wT``: the
    set grows by one agent per window, and by ``(w + N - 1)T`` all ``N`` agents hold data
    as fresh as ``wT``. For ``k`` in window ``w'``, take ``w = w' - N + 1``: the age is at
    most ``k - (w' - N + 1)T <= NT - 1``. The static directed ring (``T = 1``: ``N - 1``)
    and random jointly connected graphs (e.g. ``N = 4``, ``T = 4``: 15) attain it.
    """
    return N * T - 1


def corollary1_bound(n: int, N: int, T: int | float) -> float:
    """``n + 2N(N-1)T``: deadbeat gains give zero error from this step on (Corollary 1)."""
    return n + 2 * N * (N - 1) * T


def theorem1_onset(N: int, T: int | float) -> float:
    """``(2N-1)(N-1)T``: the step from which the rate bound of eq. (33) holds (Theorem 1)."""
    return (2 * N - 1) * (N - 1) * T


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
        from netsense.mobility import RandomWaypoint

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

    The timeline behind :func:`netsense.graphs.check_joint_connectivity` (which stops at
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


# ----------------------------------------------------------------------------- simulation
@dataclass(frozen=True, eq=False)
class Trajectory:
    """Everything a sweep measures from one batched run of ``K`` steps.

    Attributes
    ----------
    tau : (K+1, B, N, N) int
        Freshness indices ``tau_i^{(j)}[k]`` at ``[k, b, i, j]`` (``OMEGA = -1``).
    errors : (K+1, B, N) float
        ``||x_hat_i[k] - x[k]||`` per agent.
    sub_errors : (K+1, B, N, N) float
        ``||e_i^{(j)}[k]||``: agent ``i``'s error on substate ``j`` (Lemma 1 coordinates).
    state_norm : (K+1, B) float
        ``||x[k]||``.
    messages : (K, B) int
        Links ``l -> i`` present in ``G[k]`` whose sender transmitted (one message each).
    adoptions : (K, B) int
        Pairs ``(i, j)`` where agent ``i`` adopted a neighbour's estimate of substate ``j``
        (eqs. (9)-(10)); zero for observers that do not adopt (consensus).
    alive : (N,) bool
        Agents counted in :func:`relative_error` (crashed agents are excluded).
    """

    tau: np.ndarray
    errors: np.ndarray
    sub_errors: np.ndarray
    state_norm: np.ndarray
    messages: np.ndarray
    adoptions: np.ndarray
    alive: np.ndarray

    @property
    def steps(self) -> int:
        return self.messages.shape[0]


#: ``hook(k, x, y, adjacency, transmit, arrived) -> (y, adjacency, transmit, arrived)``,
#: called before every observer step; fault models use it (see :mod:`netsense.faults`).
StepHook = Callable[[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
                    tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]


def run_observer(observer: DistributedObserver, plant: Plant, graphs: np.ndarray,
                 x0: np.ndarray, *,
                 x0_hat: np.ndarray | None = None, hook: StepHook | None = None,
                 alive: np.ndarray | None = None,
                 noise_rng: np.random.Generator | None = None) -> Trajectory:
    """Run a batched distributed observer on a noiseless plant and record a trajectory.

    Parameters
    ----------
    observer : DistributedObserver
        Built with ``batch_size=B``; it is reset here.
    plant : Plant
        ``x[k+1] = A x[k]``, ``y_i[k] = C_i x[k]`` (eqs. (1)-(2)), plus the plant's
        process and measurement noise when it has any (drawn from ``noise_rng``).
    graphs : (B, K, N, N) bool
        ``G[k]`` per batch member (``adjacency[i, l]``: ``l -> i``).
    x0 : (B, n)
        Initial states.
    x0_hat : (n,), (N, n) or (B, N, n), optional
        Initial estimates (default zero).
    hook : StepHook, optional
        Rewrites the step inputs (faults).
    alive : (N,) bool, optional
        Agents counted by :func:`relative_error` (default all).
    noise_rng : Generator, optional
        Required when the plant has noise.
    """
    graphs = np.asarray(graphs, dtype=bool)
    B, N, n = observer.B, observer.N, observer.n
    if graphs.ndim != 4 or graphs.shape[0] != B or graphs.shape[2:] != (N, N):
        raise ValueError(f"graphs must have shape ({B}, K, {N}, {N}), got {graphs.shape}")
    x = np.asarray(x0, dtype=float)
    if x.shape != (B, n):
        raise ValueError(f"x0 must have shape ({B}, {n}), got {x.shape}")
    K = graphs.shape[1]
    observer.reset(x0_hat)
    T = observer.design.decomposition.T
    block_of = observer.block_of
    onehot = (block_of[:, None] == np.arange(N)[None, :]).astype(float)  # (n, N)
    tau = np.empty((K + 1, B, N, N), dtype=np.int64)
    errors = np.empty((K + 1, B, N))
    sub = np.empty((K + 1, B, N, N))
    xn = np.empty((K + 1, B))
    messages = np.zeros((K, B), dtype=np.int64)
    adoptions = np.zeros((K, B), dtype=np.int64)
    own = np.arange(N)[None, :, None]

    def record(k: int) -> None:
        tau[k] = observer.tau
        ez = observer.Z - (x @ T)[:, None, :]  # (B, N, n) error in z coordinates
        sub[k] = np.sqrt((ez ** 2) @ onehot)
        errors[k] = np.linalg.norm(ez, axis=-1)  # T orthogonal: same norm in x
        xn[k] = np.linalg.norm(x, axis=-1)

    record(0)
    ones = np.ones((B, N), dtype=bool)
    for k in range(K):
        y = plant.measure(x, noise_rng)
        adj, tx, arr = graphs[:, k], ones, ones
        if hook is not None:
            y, adj, tx, arr = hook(k, x, y, adj, tx, arr)
        observer.step(y, adj, transmit=tx, arrived=arr)
        messages[k] = (adj & tx[:, None, :]).sum((-1, -2))
        src = getattr(observer, "last_source", None)
        if src is not None:
            adoptions[k] = (src != own).sum((-1, -2))
        x = plant.step(x, noise_rng)
        record(k + 1)
    alive = np.ones(N, dtype=bool) if alive is None else np.asarray(alive, dtype=bool)
    return Trajectory(tau, errors, sub, xn, messages, adoptions, alive)


# ----------------------------------------------------------------------------- measures
def trigger_step(tau: np.ndarray) -> np.ndarray:
    """First step from which every index is finite (triggered), per batch member.

    Parameters
    ----------
    tau : (K+1, B, N, N) int
        Index history (``Trajectory.tau``).

    Returns
    -------
    (B,) int
        The smallest ``k`` with ``tau_i^{(j)}[k'] != omega`` for all ``i, j`` and all
        ``k' >= k`` in the horizon; ``-1`` if some index is still omega at the end.
        Lemma 3: ``<= (N-1)T`` under Assumption 1.
    """
    done = (tau != OMEGA).all((-1, -2))  # (K+1, B)
    K1 = done.shape[0]
    # last step that is not done, per batch member
    not_done = ~done
    last_bad = np.where(not_done.any(0), K1 - 1 - np.argmax(not_done[::-1], axis=0), -1)
    return np.where(done[-1], last_bad + 1, -1)


def worst_index(tau: np.ndarray, start: np.ndarray | int) -> np.ndarray:
    """Largest freshness index over ``k >= start`` (per batch member), ``(B,)`` int.

    ``start`` may differ per batch member (e.g. :func:`trigger_step`); a negative start
    gives ``-1``. Lemma 5: ``<= 2(N-1)T`` for ``start >= (N-1)T``.
    """
    K1, B = tau.shape[:2]
    start = np.broadcast_to(np.asarray(start), (B,))
    per_step = tau.max((-1, -2))  # (K+1, B); omega (-1) never wins against 0
    mask = np.arange(K1)[:, None] >= start[None, :]
    out = np.where(mask, per_step, -1).max(0)
    return np.where((start >= 0) & (start < K1), out, -1)


def relative_error(traj: Trajectory) -> np.ndarray:
    """``max_i ||x_hat_i[k] - x[k]|| / ||x[k]||`` over the alive agents, ``(K+1, B)``."""
    err = traj.errors[:, :, traj.alive].max(-1)
    return err / np.maximum(traj.state_norm, np.finfo(float).tiny)


def steps_to_tolerance(rel_err: np.ndarray, eps: float) -> np.ndarray:
    """First step from which ``rel_err`` stays below ``eps`` to the end, ``(B,)`` int.

    ``-1`` if it is not below ``eps`` at the last step. Compare with
    :func:`corollary1_bound` (deadbeat gains) or :func:`theorem1_onset`.
    """
    if eps <= 0:
        raise ValueError(f"eps must be > 0, got {eps}")
    bad = ~(rel_err < eps)  # NaN counts as bad
    K1 = bad.shape[0]
    last_bad = np.where(bad.any(0), K1 - 1 - np.argmax(bad[::-1], axis=0), -1)
    return np.where(bad[-1], -1, last_bad + 1)


def aoi_stats(tau: np.ndarray, start: int = 0) -> dict[str, np.ndarray]:
    """Age-of-information statistics of every index over ``k >= start``.

    The freshness index ``tau_i^{(j)}[k]`` is the age, at node ``i``, of its newest
    information about substate ``j`` (measured from the source ``j``). Steps where the
    index is still omega are excluded from the averages.

    Returns
    -------
    dict of (B, N, N) arrays
        ``mean`` -- time-average age; ``peak`` -- average peak age (the age just before
        each refresh, i.e. each step where the age does not grow by one; NaN if the index
        is never refreshed in the window); ``max`` -- largest age (``-1`` if always omega);
        ``omega_fraction`` -- fraction of the window spent at omega.
    """
    a = tau[start:].astype(float)
    a[tau[start:] == OMEGA] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(a, axis=0)
        refresh = a[1:] <= a[:-1]  # NaN comparisons are False
        peaks = np.where(refresh, a[:-1], np.nan)
        peak = np.nanmean(peaks, axis=0)
    return {"mean": mean, "peak": peak, "max": tau[start:].max(0).astype(float),
            "omega_fraction": np.isnan(a).mean(0)}


# ----------------------------------------------------------------------------- sweep case
@dataclass(frozen=True)
class SweepCase:
    """One point of a topology sweep: a family, its size and a batch of seeds.

    Attributes
    ----------
    family : str
        A key of :data:`FAMILIES`.
    N : int
        Number of agents.
    T : int
        Period for the families that have one (``ring``, ``ring_backward``,
        ``random_jsc``); ignored otherwise (their ``T`` is measured on the realised
        sequence with :func:`netsense.graphs.smallest_period`).
    n : int
        Plant dimension (``random_structured(n, N)`` with ``spectral_radius``).
    param : float
        Family parameter (see :data:`FAMILIES`).
    seeds : int
        Batch size ``B``: graph sequences and initial states per case.
    steps : int
        Horizon ``K``.
    seed : int
        Master seed (plant, graphs, initial states).
    eps : float
        Relative-error tolerance of :func:`steps_to_tolerance`.
    rho : float
        Theorem 1 rate for the rho-ordered gains.
    spectral_radius : float
        Largest eigenvalue modulus of the plant.
    """

    family: str
    N: int
    T: int = 1
    n: int = 4
    param: float = 0.0
    seeds: int = 8
    steps: int = 200
    seed: int = 0
    eps: float = 1e-6
    rho: float = 0.5
    spectral_radius: float = 1.05

    def __post_init__(self) -> None:
        if self.family not in FAMILIES:
            raise ValueError(f"family must be one of {sorted(FAMILIES)}, got {self.family!r}")
        for name, low in (("N", 2), ("T", 1), ("n", 1), ("seeds", 1), ("steps", 1)):
            if getattr(self, name) < low:
                raise ValueError(f"{name} must be >= {low}, got {getattr(self, name)}")
        if not 0 < self.rho < 1:
            raise ValueError(f"rho must be in (0, 1), got {self.rho}")
        if self.eps <= 0:
            raise ValueError(f"eps must be > 0, got {self.eps}")


def sample_graphs(process: GraphProcess, batch: int, steps: int,
                  rng: np.random.Generator) -> np.ndarray:
    """``(B, K, N, N)``: ``batch`` independent sequences, each from a child generator."""
    children = rng.spawn(batch)
    return np.stack([process.sequence(steps, c) for c in children])


def run_case(case: SweepCase) -> list[dict]:
    """Run one sweep case with the batched freshness observer; one result row per seed.

    Both gain designs (deadbeat, Corollary 1; rho-ordered, Theorem 1) see the same plant,
    graph sequences and initial states. Row fields: the case fields, ``batch`` (seed
    index), ``T_used`` (the guaranteed period, else the smallest ``T <= steps / 4`` for
    which Assumption 1 holds on the realised sequence, NaN if there is none),
    ``assumption1``, ``trigger`` / ``bound_lemma3``,
    ``worst_index`` (over ``k >= trigger``) / ``bound_lemma5``, ``worst_after_lemma3``
    (over ``k >= (N-1)T``), ``steps_deadbeat`` / ``bound_corollary1``, ``steps_rho`` /
    ``onset_theorem1``, ``messages_per_step``, ``adoptions_per_step``, ``aoi_mean``,
    ``aoi_peak``, ``aoi_max`` (over non-source pairs after the trigger step).
    """
    from netsense.decomposition import decompose
    from netsense.design import design_observer
    from netsense.observers.freshness import FreshnessObserver
    from netsense.systems import random_structured

    rng = np.random.default_rng(case.seed)
    plant = random_structured(case.n, case.N, rng=rng, spectral_radius=case.spectral_radius)
    process = make_graph_process(case.family, case.N, case.T, case.param)
    graphs = sample_graphs(process, case.seeds, case.steps, rng)
    x0 = rng.standard_normal((case.seeds, case.n))
    trajs = {}
    dec = decompose(plant.A, plant.C)  # one Lemma 1 decomposition serves both designs
    for label, kw in (("deadbeat", {"deadbeat": True}), ("rho", {"rho": case.rho})):
        design = design_observer(plant, decomposition=dec, **kw)
        obs = FreshnessObserver(design, batch_size=case.seeds)
        trajs[label] = run_observer(obs, plant, graphs, x0)
    tr = trajs["deadbeat"]
    trig = trigger_step(tr.tau)
    worst = worst_index(tr.tau, trig)
    steps_db = steps_to_tolerance(relative_error(tr), case.eps)
    steps_rho = steps_to_tolerance(relative_error(trajs["rho"]), case.eps)
    T_guar = guaranteed_period(process)
    offdiag = ~np.eye(case.N, dtype=bool)
    rows = []
    for b in range(case.seeds):
        if T_guar is not None:
            T_used, holds = T_guar, True
        else:
            # at least four complete windows, so "Assumption 1 holds" says something
            T_emp = smallest_period(graphs[b], max_period=max(case.steps // 4, 1))
            holds = T_emp is not None
            T_used = T_emp if holds else float("nan")
        if holds and T_guar is None:
            holds = check_joint_connectivity(graphs[b], int(T_used)).holds
        start3 = int(lemma3_bound(case.N, T_used)) if holds else -1
        t0 = int(trig[b]) if trig[b] >= 0 else case.steps + 1
        st = aoi_stats(tr.tau[:, b:b + 1], min(t0, case.steps))
        rows.append({
            "family": case.family, "N": case.N, "T": case.T, "n": case.n,
            "param": case.param, "seed": case.seed, "batch": b, "steps": case.steps,
            "T_used": T_used, "assumption1": holds,
            "trigger": int(trig[b]), "bound_lemma3": lemma3_bound(case.N, T_used),
            "worst_index": int(worst[b]), "bound_lemma5": lemma5_bound(case.N, T_used),
            "bound_index_sharp": sharp_index_bound(case.N, T_used),
            "worst_after_lemma3": int(worst_index(tr.tau[:, b:b + 1], start3)[0])
            if 0 <= start3 <= case.steps else -1,
            "steps_deadbeat": int(steps_db[b]),
            "bound_corollary1": corollary1_bound(case.n, case.N, T_used),
            "steps_rho": int(steps_rho[b]), "onset_theorem1": theorem1_onset(case.N, T_used),
            "messages_per_step": float(tr.messages[:, b].mean()),
            "adoptions_per_step": float(tr.adoptions[:, b].mean()),
            "aoi_mean": float(np.nanmean(st["mean"][0][offdiag]))
            if trig[b] >= 0 else float("nan"),
            "aoi_peak": float(np.nanmean(st["peak"][0][offdiag]))
            if trig[b] >= 0 else float("nan"),
            "aoi_max": float(st["max"][0][offdiag].max()) if trig[b] >= 0 else float("nan"),
        })
    return rows


def run_sweep(cases: list[SweepCase], *, workers: int = 1, progress: bool = True
              ) -> list[dict]:
    """Run :func:`run_case` for every case, in ``workers`` processes, with a progress bar.

    Rows come back in the order of ``cases`` (results do not depend on ``workers``).
    """
    from tqdm import tqdm

    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    rows: list[dict] = []
    bar = tqdm(total=len(cases), disable=not progress, desc="sweep", unit="case")
    if workers == 1:
        for c in cases:
            rows.extend(run_case(c))
            bar.update()
    else:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=workers) as pool:
            for r in pool.map(run_case, cases):
                rows.extend(r)
                bar.update()
    bar.close()
    return rows


def summarize(rows: list[dict]) -> list[dict]:
    """Per case (family, N, T, n, param): medians over seeds and measured/bound ratios.

    ``*_ratio`` is the median over seeds of measured / bound (1 = the bound is attained);
    runs where a quantity was not reached in the horizon (``-1``) or Assumption 1 failed
    are left out of the ratios and counted in ``not_reached`` / ``assumption1_frac``.
    """
    keys = ("family", "N", "T", "n", "param")
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    out = []
    pairs = (("trigger", "bound_lemma3", "trigger_ratio"),
             ("worst_after_lemma3", "bound_lemma5", "worst_after_lemma3_ratio"),
             ("worst_after_lemma3", "bound_index_sharp", "worst_sharp_ratio"),
             ("steps_deadbeat", "bound_corollary1", "steps_deadbeat_ratio"),
             ("steps_rho", "onset_theorem1", "steps_rho_ratio"))
    for key, rs in groups.items():
        s = dict(zip(keys, key, strict=True))
        s["runs"] = len(rs)
        s["assumption1_frac"] = float(np.mean([r["assumption1"] for r in rs]))
        s["T_used_median"] = float(np.nanmedian([r["T_used"] for r in rs])) \
            if any(np.isfinite(r["T_used"]) for r in rs) else float("nan")
        for q, b, ratio in pairs:
            ok = [r for r in rs if r[q] >= 0 and r["assumption1"]]
            vals = [r[q] for r in rs if r[q] >= 0]
            s[f"{q}_median"] = float(np.median(vals)) if vals else float("nan")
            s[f"{q}_max"] = float(np.max(vals)) if vals else float("nan")
            s[f"{b}_median"] = float(np.nanmedian([r[b] for r in rs])) \
                if any(np.isfinite(r[b]) for r in rs) else float("nan")
            s[ratio] = float(np.median([r[q] / r[b] for r in ok])) if ok \
                else float("nan")
            s[f"{q}_not_reached"] = sum(r[q] < 0 for r in rs)
        for q in ("worst_index", "messages_per_step", "adoptions_per_step", "aoi_mean",
                  "aoi_peak", "aoi_max"):
            vals = [r[q] for r in rs if np.isfinite(r[q]) and r[q] >= 0]
            s[q] = float(np.median(vals)) if vals else float("nan")
        out.append(s)
    return out


def write_csv(rows: list[dict], path) -> None:
    """Write dict rows (same keys) as CSV; floats with 6 significant digits."""
    import csv

    if not rows:
        raise ValueError("rows is empty")
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
