"""Vectorised update rules of the distributed observers — the one implementation.

Every function works on a leading batch axis ``B`` and an agent axis ``N`` and contains
no Python loop over agents or substates, so the scripted observers, the environment and
the batched simulator all call exactly this code.

Array conventions
-----------------
``Z``        ``(B, N, n)``   agent ``i``'s estimate of ``z = T^{-1} x`` (all substates).
``tau``      ``(B, N, N)``   freshness index ``tau_i^{(j)}`` at ``[b, i, j]``; ``OMEGA = -1``
                             encodes the dummy value omega ("never heard of source j").
``nbr``      ``(B, N, D)``   in-neighbour slots of agent ``i`` (``-1`` = empty slot), from
                             :func:`netsense.graphs.in_neighbor_slots`; ascending node order.
``valid``    ``(B, N, D)``   which slots hold a neighbour.
``transmit`` ``(B, N)``      whether agent ``l`` sent its estimates at this step; a neighbour
                             that did not transmit cannot be adopted or averaged.
``src``      ``(B, N, N)``   the agent whose estimate of substate ``j`` agent ``i`` propagates
                             (``src[b, i, j] = i`` keeps its own, eqs. (12), (14)).
``block_of`` ``(n,)``        substate of each coordinate of ``z``.
"""

from __future__ import annotations

import numpy as np

#: Encoding of the freshness index's dummy value omega (eq. (8)ff.).
OMEGA = -1
_BIG = np.iinfo(np.int64).max // 4


def _key(tau: np.ndarray) -> np.ndarray:
    """Sort key of freshness indices: omega is larger than every finite index."""
    return np.where(tau < 0, _BIG, tau)


def neighbor_indices(tau: np.ndarray, nbr: np.ndarray, valid: np.ndarray,
                     transmit: np.ndarray | None = None) -> np.ndarray:
    """Freshness indices a node can see in its slots, ``(B, N, D, N)``.

    Entry ``[b, i, d, j]`` is ``tau_l^{(j)}`` for the neighbour ``l`` in slot ``d`` of
    ``i``, or ``OMEGA`` when the slot is empty or ``l`` did not transmit.
    """
    B, N, D = nbr.shape
    M = tau.shape[-1]
    usable = valid if transmit is None else valid & transmit[
        np.arange(B)[:, None, None], np.where(valid, nbr, 0)]
    # one row gather from a flat (B N + 1, M) table whose last row is all omega: unusable
    # slots point at that row, so no masking pass over the (B, N, D, N) result is needed
    table = np.empty((B * N + 1, M), dtype=tau.dtype)
    table[:-1] = tau.reshape(B * N, M)
    table[-1] = OMEGA
    rows = np.where(usable, nbr + (np.arange(B) * N)[:, None, None], B * N)
    return np.take(table, rows, axis=0)


def freshness_choice(tau: np.ndarray, nbr: np.ndarray, valid: np.ndarray,
                     transmit: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The freshness rule: whom each agent adopts each substate from, eqs. (8)-(14).

    For agent ``i`` and substate ``j``, among the transmitting in-neighbours ``l`` with
    ``tau_l^{(j)} != omega`` (the set ``M_i^{(j)}[k]`` of eq. (8)) take the one with the
    smallest index. Adopt it if ``tau_i^{(j)} = omega`` (Case 1) or if it is strictly
    fresher, ``tau_l^{(j)} < tau_i^{(j)}`` (the set ``F_i^{(j)}[k]`` of eq. (13), Case 2);
    otherwise keep the own estimate. The source ``j`` has ``tau_j^{(j)} = 0`` and so never
    adopts. **Tie-break:** among equally fresh neighbours the one with the smallest node
    index wins (slots are in ascending node order and ``argmin`` returns the first).

    Returns
    -------
    src : (B, N, N) int
        Agent whose estimate of substate ``j`` agent ``i`` uses.
    slot : (B, N, N) int
        Chosen slot ``d`` (``-1`` when keeping the own estimate).
    """
    seen = _key(neighbor_indices(tau, nbr, valid, transmit))  # (B, N, D, N)
    if seen.shape[2] == 0:
        B, N = tau.shape[:2]
        return np.broadcast_to(np.arange(N)[None, :, None], tau.shape).copy(), \
            np.full(tau.shape, -1)
    best_slot = np.argmin(seen, axis=2)  # (B, N, N)
    best_key = np.take_along_axis(seen, best_slot[:, :, None, :], axis=2)[:, :, 0, :]
    adopt = best_key < _key(tau)  # finite < omega covers Case 1; strict < is eq. (13)
    chosen = np.take_along_axis(nbr, best_slot, axis=2)  # (B, N, N) node of best slot
    own = np.broadcast_to(np.arange(tau.shape[1])[None, :, None], tau.shape)
    return np.where(adopt, chosen, own), np.where(adopt, best_slot, -1)


def advance_indices(tau: np.ndarray, src: np.ndarray) -> np.ndarray:
    """Freshness indices at ``k+1`` given whom each agent used, eqs. (9), (11), (14).

    ``tau_i^{(j)}[k+1] = tau_{src}^{(j)}[k] + 1`` (omega stays omega), and every source
    keeps ``tau_j^{(j)} = 0``.
    """
    B, N, _ = tau.shape
    # flat offsets: tau[b, src, j] = tau.flat[(b N + src) N + j] (one np.take)
    base = (np.arange(B) * N)[:, None, None] * N + np.arange(N)[None, None, :]
    out = np.take(tau.reshape(-1), src * N + base)  # tau_src, a fresh array
    out += 1  # omega (-1) becomes 0, which no finite index + 1 can be
    np.copyto(out, OMEGA, where=out == 0)
    idx = np.arange(N)
    out[:, idx, idx] = 0
    return out


def average_indices(tau: np.ndarray, nbr: np.ndarray, valid: np.ndarray,
                    transmit: np.ndarray | None = None) -> np.ndarray:
    """Freshness indices at ``k+1`` after a uniform average (eq. (6)), ``(B, N, N)``.

    The age of an average is that of its stalest contributor plus one: over ``i`` itself
    and every transmitting in-neighbour, ``max tau + 1``, or omega if any contributor's
    index is omega. Every source keeps ``tau_j^{(j)} = 0``. Companion of
    :func:`uniform_mix` (the consensus baseline's bookkeeping of the age of information).
    """
    B, N, _ = tau.shape
    seen = neighbor_indices(tau, nbr, valid, transmit)  # (B, N, D, N), omega if unused
    used = valid if transmit is None else valid & np.take_along_axis(
        transmit[:, None, :].repeat(N, 1), np.where(valid, nbr, 0), axis=2)
    vals = np.where(used[..., None], seen, -2)  # -2: not a contributor
    any_omega = (tau == OMEGA) | (vals == OMEGA).any(2)
    out = np.where(any_omega, OMEGA, np.maximum(tau, vals.max(2, initial=-2)) + 1)
    idx = np.arange(N)
    out[:, idx, idx] = 0
    return out


def gather_substates(Z: np.ndarray, src: np.ndarray, block_of: np.ndarray) -> np.ndarray:
    """``Zg[b, i, c] = Z[b, src[b, i, block_of[c]], c]``: each substate from its chosen agent."""
    B, N, n = Z.shape
    # flat offsets into Z: (b N + src) n + c, then one np.take (about 2x faster than
    # take_along_axis, which builds a three-array fancy index)
    idx = np.take(src, block_of, axis=2).astype(np.intp, copy=False)  # (B, N, n), fresh
    idx *= n
    idx += np.arange(B)[:, None, None] * (N * n) + np.arange(n)
    return np.take(Z.reshape(-1), idx)


def uniform_mix(Z: np.ndarray, nbr: np.ndarray, valid: np.ndarray,
                transmit: np.ndarray | None = None) -> np.ndarray:
    """Average of the own estimate and every transmitting in-neighbour's, eq. (6).

    Weights are uniform over ``N_i[k] ∪ {i}`` restricted to neighbours that transmitted.
    """
    B = Z.shape[0]
    safe = np.where(valid, nbr, 0)
    use = valid if transmit is None else valid & np.take_along_axis(
        transmit[:, None, :].repeat(nbr.shape[1], 1), safe, axis=2)
    vals = Z[np.arange(B)[:, None, None], safe]  # (B, N, D, n)
    total = Z + np.einsum("bid,bidn->bin", use.astype(Z.dtype), vals)
    return total / (1.0 + use.sum(-1))[..., None]


def propagate(Z_sel: np.ndarray, Z: np.ndarray, A_diag: np.ndarray,
              A_lower: np.ndarray) -> np.ndarray:
    """Open-loop part of eqs. (7), (10), (12): ``A_jj z_sel^{(j)} + sum_{q<j} A_jq z_i^{(q)}``.

    ``Z_sel`` holds, per substate, the estimate the agent decided to propagate (its own,
    an adopted one, or a consensus mix); the couplings ``A_jq`` always act on the agent's
    own estimates of the other substates. ``A_lower`` may carry the decomposition's
    rounding-level entries above the diagonal, so the model is exact.
    """
    return Z_sel @ A_diag.T + Z @ A_lower.T


def innovation_correction(Z: np.ndarray, y: np.ndarray, arrived: np.ndarray | None,
                          C_bar_pad: np.ndarray, L_pad: np.ndarray) -> np.ndarray:
    """Output injection of eq. (7) for every source, ``L_j (y_j - C_bar_j z_j)``.

    Parameters
    ----------
    Z : (B, N, n)
    y : (B, N, r_max) padded measurements.
    arrived : (B, N) bool or None
        Agents whose measurement arrived; a missing measurement gives no correction (the
        source runs open loop for that step).
    C_bar_pad : (N, r_max, n)
        ``C_i T`` per agent, zero-padded rows.
    L_pad : (N, n, r_max) or (B, N, n, r_max)
        Gains in the rows of each agent's own block (``ObserverDesign.gain_padded``).
    """
    innov = y - np.einsum("irn,bin->bir", C_bar_pad, Z)
    if arrived is not None:
        innov = innov * arrived[..., None]
    if L_pad.ndim == 3:
        return np.einsum("inr,bir->bin", L_pad, innov)
    return np.einsum("binr,bir->bin", L_pad, innov)


def keep_own_blocks(Z_sel: np.ndarray, Z: np.ndarray, own_block: np.ndarray) -> np.ndarray:
    """Restore every source's own substate in ``Z_sel`` (sources never mix their substate).

    ``own_block`` is the ``(N, n)`` mask ``block_of[c] == i``.
    """
    return np.where(own_block[None], Z, Z_sel)
