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
from numba import njit

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
    tau = np.asarray(tau)
    out = np.empty(tau.shape, dtype=tau.dtype)
    _advance_all(tau, np.asarray(src), out)
    return out


def average_indices(tau: np.ndarray, nbr: np.ndarray, valid: np.ndarray,
                    transmit: np.ndarray | None = None) -> np.ndarray:
    """Freshness indices at ``k+1`` after a uniform average (eq. (6)), ``(B, N, N)``.

    The age of an average is that of its stalest contributor plus one: over ``i`` itself
    and every transmitting in-neighbour, ``max tau + 1``, or omega if any contributor's
    index is omega. Every source keeps ``tau_j^{(j)} = 0``. Companion of
    :func:`uniform_mix` (the consensus baseline's bookkeeping of the age of information).
    """
    tau = np.asarray(tau)
    out = np.empty(tau.shape, dtype=tau.dtype)
    _average_all(tau, np.asarray(nbr), _usable(nbr, valid, transmit), out)
    return out


def gather_substates(Z: np.ndarray, src: np.ndarray, block_of: np.ndarray) -> np.ndarray:
    """``Zg[b, i, c] = Z[b, src[b, i, block_of[c]], c]``: each substate from its chosen agent."""
    Z = np.asarray(Z, dtype=float)
    out = np.empty(Z.shape)
    _gather_all(Z, np.asarray(src), np.asarray(block_of), out)
    return out


def uniform_mix(Z: np.ndarray, nbr: np.ndarray, valid: np.ndarray,
                transmit: np.ndarray | None = None) -> np.ndarray:
    """Average of the own estimate and every transmitting in-neighbour's, eq. (6).

    Weights are uniform over ``N_i[k] ∪ {i}`` restricted to neighbours that transmitted.
    """
    Z = np.asarray(Z, dtype=float)
    out = np.empty(Z.shape)
    _mix_all(Z, np.asarray(nbr), _usable(nbr, valid, transmit), out)
    return out


def propagate(Z_sel: np.ndarray, Z: np.ndarray, A_diag: np.ndarray,
              A_lower: np.ndarray, band: tuple[np.ndarray, np.ndarray] | None = None
              ) -> np.ndarray:
    """Open-loop part of eqs. (7), (10), (12): ``A_jj z_sel^{(j)} + sum_{q<j} A_jq z_i^{(q)}``.

    ``Z_sel`` holds, per substate, the estimate the agent decided to propagate (its own,
    an adopted one, or a consensus mix); the couplings ``A_jq`` always act on the agent's
    own estimates of the other substates. ``A_lower`` may carry the decomposition's
    rounding-level entries above the diagonal, so the model is exact. ``band`` is
    :func:`diag_band` of ``A_diag`` (computed when not given): the multiply by the
    block-diagonal part visits only the non-zero rows of each column.
    """
    Z_sel = np.asarray(Z_sel, dtype=float)
    lo, hi = diag_band(A_diag) if band is None else band
    out = np.empty(Z_sel.shape)
    _propagate_all(Z_sel, np.asarray(Z, dtype=float), _t(A_diag), _t(A_lower), lo, hi, out)
    return out


def diag_band(A_diag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``lo[q] <= c < hi[q]`` that hold the non-zeros of column ``q`` of ``A_diag``.

    For a block-diagonal matrix these are the rows of column ``q``'s own block, so
    :func:`propagate` costs ``sum_j n_j^2`` for ``A_diag`` instead of ``n^2``.
    """
    nz = np.asarray(A_diag) != 0
    any_ = nz.any(0)
    lo = np.where(any_, nz.argmax(0), 0).astype(np.int64)
    hi = np.where(any_, nz.shape[0] - nz[::-1].argmax(0), 0).astype(np.int64)
    return lo, hi


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
    Z = np.asarray(Z, dtype=float)
    B, N, n = Z.shape
    y = np.asarray(y, dtype=float)
    L = np.asarray(L_pad, dtype=float)
    if L.ndim == 3:
        L = np.broadcast_to(L, (B,) + L.shape)
    arr = np.ones((B, N), bool) if arrived is None else np.asarray(arrived, dtype=bool)
    out = np.empty(Z.shape)
    _innovation_all(Z, y, arr, np.asarray(C_bar_pad, dtype=float), L, out)
    return out


# ----------------------------------------------------------------------------- the step
#: Meaning of the entries of :func:`apply_actions`' ``status``.
STATUS_FIELDS = ("range_b", "range_i", "range_j", "masked_b", "masked_i", "masked_j")


def check_actions(act: np.ndarray, msg: np.ndarray, choice: np.ndarray,
                  masked: np.ndarray) -> np.ndarray:
    """Validate the environment's actions ``(B, N, N + 1)`` against the slot table.

    Entry ``act[b, i, j]`` (``j < N``) is ``0`` keep, ``1..D`` adopt slot ``d - 1``,
    ``D + 1`` average; ``act[b, i, N]`` is the transmit bit. A choice is *masked* when its
    slot holds no message (``msg[b, i, d]`` false) or when it is not 0 on the agent's own
    substate (``j = i``: eq. (7) is not an action). Writes the sanitised choices (masked
    ones replaced by 0, keep) into ``choice (B, N, N)`` and the masked flags into
    ``masked``, and returns the ``status`` vector of :data:`STATUS_FIELDS`: the first
    (in C order) out-of-range entry and the first masked one, ``-1`` where there is none.
    """
    status = np.full(6, -1, dtype=np.int64)
    _check_actions(act, msg, choice, masked, status)
    return status


def apply_actions(Z: np.ndarray, tau: np.ndarray, choice: np.ndarray, nbr: np.ndarray,
                  msg: np.ndarray, block_of: np.ndarray, A_diag_T: np.ndarray,
                  A_lower_T: np.ndarray, band: tuple[np.ndarray, np.ndarray],
                  corr: np.ndarray, z_true: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One step of every agent under validated choices, in one pass over ``(b, i)``.

    Per agent and substate ``j``: the source ``src`` of the choice (itself for keep and
    average, the slot's neighbour for adopt), the index update (:func:`advance_indices`,
    or :func:`average_indices` for an average), the estimate to propagate
    (:func:`gather_substates`, or :func:`uniform_mix` for an average), then
    :func:`propagate` plus the source correction ``corr`` (eq. (7)). The very same row
    functions as those public kernels do the work, so results are bit-identical to calling
    them one after the other.

    Returns
    -------
    Z_next : (B, N, n)
    tau_next : (B, N, N)
    err : (B, N)
        ``||Z_next[b, i] - z_true[b]||`` (the estimation error in Lemma 1 coordinates).
    """
    Z_next = np.empty(Z.shape)
    tau_next = np.empty(tau.shape, dtype=tau.dtype)
    err = np.empty(Z.shape[:2])
    _apply_all(Z, tau, choice, nbr, msg, block_of, A_diag_T, A_lower_T, band[0], band[1],
               corr, z_true, Z_next, tau_next, err)
    return Z_next, tau_next, err


def _t(A: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(A, dtype=float).T)


def _usable(nbr: np.ndarray, valid: np.ndarray, transmit: np.ndarray | None) -> np.ndarray:
    """Slots whose neighbour is present and (if given) transmitted, ``(B, N, D)``."""
    valid = np.asarray(valid, dtype=bool)
    if transmit is None:
        return valid
    B = valid.shape[0]
    return valid & np.asarray(transmit, bool)[np.arange(B)[:, None, None],
                                              np.where(valid, nbr, 0)]


# ----------------------------------------------------------------------------- row rules
# One agent's row of each rule. The public kernels above and apply_actions loop over
# (b, i) and call these, so there is one implementation of every rule. No fastmath: the
# arithmetic is IEEE in program order, hence identical wherever a row function runs.
@njit(cache=True)
def _advance_row(tau_b, src_row, i, out_row):  # eqs. (9), (11), (14)
    for j in range(out_row.shape[0]):
        t = tau_b[src_row[j], j]
        out_row[j] = OMEGA if t < 0 else t + 1
    out_row[i] = 0


@njit(cache=True)
def _average_row(tau_b, nbr_row, use_row, i, out_row):  # age of an average, eq. (6)
    for j in range(out_row.shape[0]):
        t = tau_b[i, j]
        omega = t < 0
        worst = t
        for d in range(nbr_row.shape[0]):
            if use_row[d]:
                v = tau_b[nbr_row[d], j]
                if v < 0:
                    omega = True
                elif v > worst:
                    worst = v
        out_row[j] = OMEGA if omega else worst + 1
    out_row[i] = 0


@njit(cache=True)
def _mix_row(Z_b, nbr_row, use_row, i, out_row):  # eq. (6)
    count = 1.0
    for d in range(nbr_row.shape[0]):
        if use_row[d]:
            count += 1.0
    for c in range(out_row.shape[0]):
        s = 0.0
        for d in range(nbr_row.shape[0]):
            if use_row[d]:
                s += Z_b[nbr_row[d], c]
        out_row[c] = (Z_b[i, c] + s) / count


@njit(cache=True)
def _gather_row(Z_b, src_row, block_of, out_row):
    for c in range(out_row.shape[0]):
        out_row[c] = Z_b[src_row[block_of[c]], c]


@njit(cache=True)
def _propagate_row(zsel, z, ADT, ALT, lo, hi, out_row):  # eqs. (7), (10), (12)
    n = out_row.shape[0]
    for c in range(n):
        out_row[c] = 0.0
    for q in range(n):  # block-diagonal part on the propagated estimate
        v = zsel[q]
        for c in range(lo[q], hi[q]):
            out_row[c] += ADT[q, c] * v
    for q in range(n):  # couplings on the agent's own estimates
        v = z[q]
        for c in range(n):
            out_row[c] += ALT[q, c] * v


@njit(cache=True)
def _innovation_row(z, y_row, arrived, C_i, L_i, innov, out_row):  # eq. (7)
    r, n = C_i.shape
    for k in range(r):
        s = 0.0
        for c in range(n):
            s += C_i[k, c] * z[c]
        innov[k] = (y_row[k] - s) if arrived else 0.0
    for c in range(n):
        s = 0.0
        for k in range(r):
            s += L_i[c, k] * innov[k]
        out_row[c] = s


# ----------------------------------------------------------------------------- drivers
@njit(cache=True)
def _advance_all(tau, src, out):
    for b in range(tau.shape[0]):
        for i in range(tau.shape[1]):
            _advance_row(tau[b], src[b, i], i, out[b, i])


@njit(cache=True)
def _average_all(tau, nbr, use, out):
    for b in range(tau.shape[0]):
        for i in range(tau.shape[1]):
            _average_row(tau[b], nbr[b, i], use[b, i], i, out[b, i])


@njit(cache=True)
def _gather_all(Z, src, block_of, out):
    for b in range(Z.shape[0]):
        for i in range(Z.shape[1]):
            _gather_row(Z[b], src[b, i], block_of, out[b, i])


@njit(cache=True)
def _mix_all(Z, nbr, use, out):
    for b in range(Z.shape[0]):
        for i in range(Z.shape[1]):
            _mix_row(Z[b], nbr[b, i], use[b, i], i, out[b, i])


@njit(cache=True)
def _propagate_all(Z_sel, Z, ADT, ALT, lo, hi, out):
    for b in range(Z.shape[0]):
        for i in range(Z.shape[1]):
            _propagate_row(Z_sel[b, i], Z[b, i], ADT, ALT, lo, hi, out[b, i])


@njit(cache=True)
def _innovation_all(Z, y, arrived, C, L, out):
    innov = np.empty(C.shape[1])
    for b in range(Z.shape[0]):
        for i in range(Z.shape[1]):
            _innovation_row(Z[b, i], y[b, i], arrived[b, i], C[i], L[b, i], innov,
                            out[b, i])


@njit(cache=True)
def _check_actions(act, msg, choice, masked, status):
    B, N, D = msg.shape
    for b in range(B):
        for i in range(N):
            for j in range(N + 1):
                a = act[b, i, j]
                top = D + 1 if j < N else 1
                if (a < 0 or a > top) and status[0] < 0:
                    status[0], status[1], status[2] = b, i, j
            for j in range(N):
                a = act[b, i, j]
                ok = a == 0 or (j != i and (a == D + 1 or (1 <= a <= D and msg[b, i, a - 1])))
                masked[b, i, j] = not ok
                if ok:
                    choice[b, i, j] = a
                else:
                    choice[b, i, j] = 0
                    if status[3] < 0:
                        status[3], status[4], status[5] = b, i, j


@njit(cache=True)
def _apply_all(Z, tau, choice, nbr, msg, block_of, ADT, ALT, lo, hi, corr, z_true,
               Z_next, tau_next, err):
    B, N, n = Z.shape
    D = nbr.shape[2]
    src = np.empty(N, dtype=np.int64)
    zsel = np.empty(n)
    mix = np.empty(n)
    avg_tau = np.empty(tau.shape[2], dtype=tau.dtype)
    for b in range(B):
        for i in range(N):
            ch = choice[b, i]
            averaged = False
            for j in range(N):
                a = ch[j]
                if 1 <= a <= D:
                    src[j] = nbr[b, i, a - 1]
                else:
                    src[j] = i
                    averaged = averaged or a == D + 1
            _advance_row(tau[b], src, i, tau_next[b, i])
            _gather_row(Z[b], src, block_of, zsel)
            if averaged:
                _average_row(tau[b], nbr[b, i], msg[b, i], i, avg_tau)
                _mix_row(Z[b], nbr[b, i], msg[b, i], i, mix)
                for j in range(N):
                    if ch[j] == D + 1:
                        tau_next[b, i, j] = avg_tau[j]
                for c in range(n):
                    if ch[block_of[c]] == D + 1:
                        zsel[c] = mix[c]
            out = Z_next[b, i]
            _propagate_row(zsel, Z[b, i], ADT, ALT, lo, hi, out)
            s = 0.0
            for c in range(n):
                out[c] += corr[b, i, c]
                e = out[c] - z_true[b, c]
                s += e * e
            err[b, i] = np.sqrt(s)


def keep_own_blocks(Z_sel: np.ndarray, Z: np.ndarray, own_block: np.ndarray) -> np.ndarray:
    """Restore every source's own substate in ``Z_sel`` (sources never mix their substate).

    ``own_block`` is the ``(N, n)`` mask ``block_of[c] == i``.
    """
    return np.where(own_block[None], Z, Z_sel)
