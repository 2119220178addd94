"""Consensus baselines of eq. (6), generalised to the block structure of Lemma 1.

For a non-source agent ``i`` and substate ``j``

.. math::  \\hat z_i^{(j)}[k+1] = A_{jj} \\sum_{l} w^{(j)}_{il}[k] \\hat z_l^{(j)}[k]
           + \\sum_{q<j} A_{jq} \\hat z_i^{(q)}[k],

which is eq. (6) for the scalar plant of Fig. 1 and has the structure of eq. (10) with the
adopted estimate replaced by a weighted average. Sources keep the local update (7) on
their own substate. Two weightings, as in Fig. 2:

``"uniform"``
    ``w_il = 1 / (|N_i[k]| + 1)`` over ``N_i[k] ∪ {i}`` (transmitting neighbours only).
``"tree"``
    all weight on the parent of ``i`` in a breadth-first spanning tree of ``G[k]`` rooted
    at the source ``j`` (parent = the in-neighbour of smallest index one hop closer to
    ``j``); an agent ``j`` cannot reach in ``G[k]`` keeps its own estimate.

Freshness indices are still tracked (as ages of the information used, with averages
taking the stalest contributor) so that the age-of-information can be compared.
"""

from __future__ import annotations

import numpy as np

from netsense.graphs.processes import slot_adjacency
from netsense.kernels import update as kernels
from netsense.observers.base import DistributedObserver


def hop_distances(adj: np.ndarray) -> np.ndarray:
    """``dist[b, j, i]``: hops from ``j`` to ``i`` in ``adj[b]`` (``N`` when unreachable).

    Breadth-first search for all roots at once by boolean matrix products.
    """
    B, N, _ = adj.shape
    dist = np.full((B, N, N), N, dtype=np.int64)
    reach = np.broadcast_to(np.eye(N, dtype=bool), (B, N, N)).copy()  # [b, root, node]
    dist[reach] = 0
    frontier = reach.copy()
    for h in range(1, N):
        # node i is reached if some in-neighbour l (adj[i, l]) is in the frontier
        nxt = np.einsum("bjl,bil->bji", frontier.astype(np.int8), adj.astype(np.int8)) > 0
        nxt &= ~reach
        if not nxt.any():
            break
        dist[nxt] = h
        reach |= nxt
        frontier = nxt
    return dist


def tree_parents(adj: np.ndarray, nbr: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``src[b, i, j]``: parent of ``i`` in the BFS tree of ``adj[b]`` rooted at ``j``."""
    B, N, _ = adj.shape
    dist = hop_distances(adj)  # (B, root j, node i)
    d_i = np.transpose(dist, (0, 2, 1))  # (B, i, j)
    safe = np.where(valid, nbr, 0)
    d_nb = np.transpose(dist[np.arange(B)[:, None, None], :, safe], (0, 1, 3, 2))
    # d_nb[b, i, j, d] = dist from j to the neighbour in slot d of i
    ok = valid[:, :, None, :] & (d_nb == (d_i[..., None] - 1)) & (d_i[..., None] < N)
    has = ok.any(-1)
    first = np.argmax(ok, axis=-1)
    parent = np.take_along_axis(nbr, first, axis=2)
    own = np.broadcast_to(np.arange(N)[None, :, None], (B, N, N))
    return np.where(has, parent, own)


class ConsensusObserver(DistributedObserver):
    """Consensus baseline of eq. (6) with ``weights="uniform"`` or ``"tree"``."""

    def __init__(self, design, *, weights: str = "uniform", **kwargs) -> None:
        if weights not in ("uniform", "tree"):
            raise ValueError(f"weights must be 'uniform' or 'tree', got {weights!r}")
        self.weights = weights
        super().__init__(design, **kwargs)

    def _select(self, Z, tau, nbr, valid, tx):
        N = Z.shape[1]
        if self.weights == "tree":
            usable = kernels.usable_slots(nbr, valid, tx)
            adj = slot_adjacency(np.where(usable, nbr, -1), N)  # the graph of usable links
            src = tree_parents(adj, nbr, usable)
            Z_sel = kernels.gather_substates(Z, src, self.block_of)
            tau_next = kernels.advance_indices(tau, src)
        else:
            Z_sel = kernels.uniform_mix(Z, nbr, valid, tx)
            # age of a uniform average: its stalest contributor (omega if any is omega)
            tau_next = kernels.average_indices(tau, nbr, valid, tx)
        return kernels.keep_own_blocks(Z_sel, Z, self.own_block), tau_next
