"""Redrawing what a graph process has drawn but not yet shown: conditional future states.

A graph process's state after step ``k`` (what :meth:`GraphProcess.sample` returns) may
already hold randomness about ``G[k+1]`` and later graphs: the link states of the next step
(:class:`~netsense.graphs.processes.MarkovLinkFailures`), the agents' next positions
(mobility), the rest of a window (:class:`~netsense.graphs.processes.RandomJointlyConnected`).
A simulation that forks a run at step ``k`` and must not know ``G[k+1]`` (the causal
reference of :mod:`netsense.benchmark.lookahead`, through :mod:`netsense.engine.fork`) needs a
state drawn from the process's law *given what was shown up to* ``k``:
:meth:`~netsense.graphs.processes.GraphProcess.redraw_state`.

This module holds the one non-trivial case, the rest of a random jointly connected window.
The window of :class:`RandomJointlyConnected` (``N`` nodes, period ``T``, extra-edge
probability ``p``) is a union ``U`` of the Hamiltonian cycle of a uniform random
permutation and i.i.d. extra pairs (probability ``p``), with every edge of ``U`` shown at
one step ``when(e)`` drawn uniformly from ``0..T-1``. Given the graphs of the first
``pos`` steps, with ``O`` the edges they showed, the unseen edges ``R = U \\ O`` (each
shown at a step ``>= pos``) have the law

.. math::

    P(R \\mid O) \\propto H(O \\cup R)\\, r^{|R|}, \\qquad
    r = \\frac{p}{1 - p}\\,\\frac{T - pos}{T},

with ``H(G)`` the number of directed Hamiltonian cycles of ``G`` (each is ``N``
permutations, and ``P(U | perm) \\propto (p / (1 - p))^{|U|}`` when the cycle of ``perm``
lies in ``U``), and each edge of ``R`` at a uniform step of ``pos..T-1``. It is sampled
exactly: with ``q = r / (1 + r)``, draw a Hamiltonian cycle ``C`` with probability
proportional to ``q^{|C \\setminus O|}`` (a subset dynamic programme over paths from node
0, then backward sampling: :func:`hamiltonian_cycle`), take ``R = (C \\setminus O)`` plus
every other unseen off-diagonal pair independently with probability ``q``. Summing over
the cycles inside ``O \\cup R`` gives back the law above. For ``p = 0`` the union is the
cycle alone: ``C`` is uniform among the cycles that contain ``O``.
``tests/test_fork.py`` checks the sampler against the exact conditional law computed by
enumerating every window of a three-node process.
"""

from __future__ import annotations

import numpy as np

from netsense.kernels.jit import njit_cached

__all__ = ["MAX_CYCLE_NODES", "hamiltonian_cycle", "redraw_window"]

#: Largest ``N`` for the subset programme (``2^N N`` doubles: 8 MB at 16).
MAX_CYCLE_NODES = 16


@njit_cached(nogil=True)
def _cycle_dp(w, u, succ):  # pragma: no cover - compiled
    """Weighted directed Hamiltonian cycle through node 0 by a subset programme.

    ``w[a, b]`` weight of the edge ``a -> b``; ``u`` holds ``N`` uniforms for the backward
    draws; writes the successor of every node into ``succ``. Returns the total weight of
    all cycles (0: none, nothing written).
    """
    N = w.shape[0]
    full = (1 << N) - 1
    f = np.zeros((1 << N, N))
    f[1, 0] = 1.0
    for S in range(1, full + 1):
        if not S & 1:
            continue
        for v in range(1, N):
            if not (S >> v) & 1:
                continue
            prev = S ^ (1 << v)
            acc = 0.0
            for a in range(N):
                if (prev >> a) & 1 and f[prev, a] != 0.0:
                    acc += f[prev, a] * w[a, v]
            f[S, v] = acc
    total = 0.0
    for v in range(1, N):
        total += f[full, v] * w[v, 0]
    if N == 1 or not total > 0.0:
        return total
    # backward: the last node v (edge v -> 0), then its predecessors
    target = u[0] * total
    acc = 0.0
    v = N - 1
    for c in range(1, N):
        acc += f[full, c] * w[c, 0]
        if acc > target and f[full, c] * w[c, 0] > 0.0:
            v = c
            break
    succ[v] = 0
    S = full
    for step in range(1, N - 1):
        prev = S ^ (1 << v)
        row = 0.0
        for a in range(N):
            if (prev >> a) & 1:
                row += f[prev, a] * w[a, v]
        target = u[step] * row
        acc = 0.0
        pick = -1
        for a in range(N):
            if (prev >> a) & 1:
                x = f[prev, a] * w[a, v]
                acc += x
                if x > 0.0:
                    pick = a
                    if acc > target:
                        break
        succ[pick] = v
        S = prev
        v = pick
    succ[0] = v
    return total


def hamiltonian_cycle(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A directed Hamiltonian cycle drawn with probability proportional to the product of
    its edge weights.

    Parameters
    ----------
    weights : (N, N) array
        ``weights[a, b] >= 0``: weight of the edge ``a -> b`` (the diagonal is ignored).
    rng : numpy.random.Generator
        Draws ``N`` uniforms.

    Returns
    -------
    (N,) int array
        ``succ[a]``: the node after ``a`` on the cycle.

    Raises
    ------
    ValueError
        If ``N`` exceeds :data:`MAX_CYCLE_NODES`, a weight is negative or not finite, or no
        cycle has a positive weight.
    """
    w = np.array(weights, dtype=float)
    N = w.shape[0]
    if w.ndim != 2 or w.shape != (N, N) or N < 2:
        raise ValueError(f"weights must be a square (N, N) array with N >= 2, got {w.shape}")
    if N > MAX_CYCLE_NODES:
        raise ValueError(f"hamiltonian_cycle runs a 2^N subset programme: N <= "
                         f"{MAX_CYCLE_NODES}, got {N}")
    if not np.isfinite(w).all() or (w < 0).any():
        raise ValueError("weights must be finite and >= 0")
    np.fill_diagonal(w, 0.0)
    succ = np.full(N, -1, dtype=np.int64)
    total = _cycle_dp(w, rng.random(N), succ)
    if not total > 0.0:
        raise ValueError("no Hamiltonian cycle has a positive weight")
    return succ


def redraw_window(window: np.ndarray, pos: int, p: float, rng: np.random.Generator
                  ) -> np.ndarray:
    """The window of a random jointly connected process with its unseen steps redrawn.

    Parameters
    ----------
    window : (T, N, N) bool
        The current window (``[s, i, l]``: edge ``l -> i`` at step ``s``); steps
        ``0..pos-1`` have been shown.
    pos : int
        Steps shown, ``1 <= pos < T`` (``pos = 0``: nothing of the next window exists yet,
        nothing to redraw).
    p : float
        The process's ``extra_edge_prob``.
    rng : numpy.random.Generator

    Returns
    -------
    (T, N, N) bool
        Steps ``< pos`` as given, steps ``>= pos`` drawn from their law given those (the
        module docstring).
    """
    T, N = window.shape[0], window.shape[1]
    if not 1 <= pos < T:
        raise ValueError(f"pos must be in 1..T-1 = 1..{T - 1}, got {pos}")
    seen = window[:pos].any(0)  # O, [i, l]: l -> i
    free = ~seen
    np.fill_diagonal(free, False)
    ahead = seen.T  # [a, b]: a -> b shown
    if p > 0.0:
        r = np.inf if p >= 1.0 else p / (1.0 - p) * (T - pos) / T
        q = 1.0 if not np.isfinite(r) else r / (1.0 + r)
        w = np.where(ahead, 1.0, q)
    else:  # the union is the cycle: every shown edge is on it
        out_deg, in_deg = ahead.sum(1), ahead.sum(0)
        w = np.where(ahead, 1.0, 0.0)
        ok = (out_deg[:, None] == 0) & (in_deg[None, :] == 0)
        w[~ahead & ok] = 1.0
        q = 0.0
    succ = hamiltonian_cycle(w, rng)
    cycle = np.zeros((N, N), dtype=bool)
    cycle[succ, np.arange(N)] = True  # a -> succ[a] at [succ[a], a]
    unseen = (cycle & free) | (free & ~cycle & (rng.random((N, N)) < q))
    out = window.copy()
    out[pos:] = False
    i, l = np.nonzero(unseen)
    out[rng.integers(pos, T, size=i.size), i, l] = True
    return out
