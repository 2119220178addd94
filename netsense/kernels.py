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

from typing import NamedTuple

import numpy as np
from numba import njit, prange

from netsense.compiled import Driver

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


def advance_indices(tau: np.ndarray, src: np.ndarray, own: np.ndarray | None = None
                    ) -> np.ndarray:
    """Freshness indices at ``k+1`` given whom each agent used, eqs. (9), (11), (14).

    ``tau_i^{(j)}[k+1] = tau_{src}^{(j)}[k] + 1`` (omega stays omega), and every source
    keeps ``tau_j^{(j)} = 0``. ``own[i]`` is the substate (column) of agent ``i``, ``-1``
    if it owns none; the default is ``own[i] = i`` (one column per agent).
    """
    tau = np.asarray(tau)
    out = np.empty(tau.shape, dtype=tau.dtype)
    _advance_all.at(tau.size)(tau, _own(own, tau), np.asarray(src), out)
    return out


def average_indices(tau: np.ndarray, nbr: np.ndarray, valid: np.ndarray,
                    transmit: np.ndarray | None = None, own: np.ndarray | None = None
                    ) -> np.ndarray:
    """Freshness indices at ``k+1`` after a uniform average (eq. (6)), ``(B, N, N)``.

    The age of an average is that of its stalest contributor plus one: over ``i`` itself
    and every transmitting in-neighbour, ``max tau + 1``, or omega if any contributor's
    index is omega. Every source keeps ``tau_j^{(j)} = 0``. Companion of
    :func:`uniform_mix` (the consensus baseline's bookkeeping of the age of information).
    """
    tau = np.asarray(tau)
    out = np.empty(tau.shape, dtype=tau.dtype)
    _average_all.at(tau.size)(tau, _own(own, tau), np.asarray(nbr),
                              _usable(nbr, valid, transmit), out)
    return out


def gather_substates(Z: np.ndarray, src: np.ndarray, block_of: np.ndarray) -> np.ndarray:
    """``Zg[b, i, c] = Z[b, src[b, i, block_of[c]], c]``: each substate from its chosen agent."""
    Z = np.asarray(Z, dtype=float)
    out = np.empty(Z.shape)
    _gather_all.at(Z.size)(Z, np.asarray(src), np.asarray(block_of), out)
    return out


def uniform_mix(Z: np.ndarray, nbr: np.ndarray, valid: np.ndarray,
                transmit: np.ndarray | None = None) -> np.ndarray:
    """Average of the own estimate and every transmitting in-neighbour's, eq. (6).

    Weights are uniform over ``N_i[k] ∪ {i}`` restricted to neighbours that transmitted.
    """
    Z = np.asarray(Z, dtype=float)
    out = np.empty(Z.shape)
    _mix_all.at(Z.size)(Z, np.asarray(nbr), _usable(nbr, valid, transmit), out)
    return out


def propagate(Z_sel: np.ndarray, Z: np.ndarray, A_diag: np.ndarray,
              A_lower: np.ndarray,
              band: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Open-loop part of eqs. (7), (10), (12): ``A_jj z_sel^{(j)} + sum_{q<j} A_jq z_i^{(q)}``.

    ``Z_sel`` holds, per substate, the estimate the agent decided to propagate (its own,
    an adopted one, or a consensus mix); the couplings ``A_jq`` always act on the agent's
    own estimates of the other substates. ``A_lower`` may carry the decomposition's
    rounding-level entries above the diagonal, so the model is exact. ``band`` is
    :func:`diag_band` of ``A_diag`` (computed when not given): the multiply by the
    block-diagonal part visits only its non-zeros.
    """
    Z_sel = np.asarray(Z_sel, dtype=float)
    dq, dc, dv = diag_band(A_diag) if band is None else band
    out = np.empty(Z_sel.shape)
    _propagate_all.at(Z_sel.size * Z_sel.shape[-1])(
        Z_sel, np.asarray(Z, dtype=float), dq, dc, dv, _t(A_lower), out)
    return out


def diag_band(A_diag: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The non-zeros ``A_diag[c, q] = v`` as ``(q, c, v)`` arrays, ``q`` major.

    For the block-diagonal ``A_diag`` these are the ``sum_j n_j^2`` entries of the
    diagonal blocks, so :func:`propagate` visits only them instead of ``n^2``.
    """
    AT = np.asarray(A_diag, dtype=float).T
    q, c = np.nonzero(AT)
    return q.astype(np.int64), c.astype(np.int64), AT[q, c].copy()


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
    if L.ndim == 3:  # one gain for every member: indexed as member 0
        L = L[None]
    L = np.ascontiguousarray(L)
    arr = np.ones((B, N), bool) if arrived is None else np.asarray(arrived, dtype=bool)
    out = np.empty(Z.shape)
    C = np.asarray(C_bar_pad, dtype=float)
    _innovation_all.at(Z.size)(Z, y, arr, C, L, gain_rows(L), out, np.empty((B, C.shape[1])))
    return out


def gain_rows(L_pad: np.ndarray) -> np.ndarray:
    """``(N, 2)``: rows ``lo <= c < hi`` that hold the non-zeros of each agent's gain
    (its own block); ``lo = hi = 0`` for an agent with no gain (not a source)."""
    nz = np.asarray(L_pad) != 0  # (..., N, n, r)
    rows = nz.any(-1)
    while rows.ndim > 2:
        rows = rows.any(0)
    any_ = rows.any(1)
    lo = np.where(any_, rows.argmax(1), 0)
    hi = np.where(any_, rows.shape[1] - rows[:, ::-1].argmax(1), 0)
    return np.stack([lo, hi], 1).astype(np.int64)


def vecmat(x: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``out[b] = x[b] @ M`` for ``x (B, p)``, ``M (p, m)``, in a fixed summation order.

    Every member is computed alone (unlike one BLAS call on the stacked rows, whose
    rounding may depend on ``B``), so a member of a batch equals a ``B = 1`` run bit for
    bit. Used for the plant (eq. (1)), the outputs (eq. (2)) and ``z = T^T x``.
    """
    x = np.ascontiguousarray(x, dtype=float)
    M = np.ascontiguousarray(M, dtype=float)
    out = np.empty((x.shape[0], M.shape[1]))
    _vecmat_all.at(x.shape[0] * M.size // 8)(x, M, out)  # light: rarely worth threads
    return out


# ----------------------------------------------------------------------------- the step
#: Meaning of the entries of :func:`apply_actions`' ``status``.
STATUS_FIELDS = ("range_b", "range_i", "range_j", "masked_b", "masked_i", "masked_j")


def check_actions(act: np.ndarray, msg: np.ndarray, choice: np.ndarray,
                  masked: np.ndarray, own: np.ndarray | None = None) -> np.ndarray:
    """Validate the environment's actions ``(B, N, N + 1)`` against the slot table.

    Entry ``act[b, i, j]`` (``j < M`` substates) is ``0`` keep, ``1..D`` adopt slot
    ``d - 1``, ``D + 1`` average; ``act[b, i, M]`` is the transmit bit. A choice is
    *masked* when its slot holds no message (``msg[b, i, d]`` false) or when it is not 0
    on the agent's own substate (``j = own[i]``, default ``own[i] = i``: eq. (7) is not
    an action). Writes the sanitised choices (masked ones replaced by 0, keep) into
    ``choice (B, N, M)`` and the masked flags into
    ``masked``, and returns the ``status`` vector of :data:`STATUS_FIELDS`: the first
    (in C order) out-of-range entry and the first masked one, ``-1`` where there is none.
    """
    first = np.full((act.shape[0], 4), -1, dtype=np.int64)
    okt = np.ones((act.shape[0], msg.shape[2] + 2), dtype=np.bool_)  # allowed on others'
    _check_actions.at(act.size)(act, msg, _own(own, choice), choice, masked, first, okt)
    return _status(first)


class StepOut(NamedTuple):
    """What :func:`apply_actions` returns."""

    Z_next: np.ndarray  #: (B, N, n) estimates at k + 1
    tau_next: np.ndarray  #: (B, N, M) freshness indices at k + 1
    err: np.ndarray  #: (B, N) ||Z_next - T^T x_next|| (estimation errors)
    x_next: np.ndarray  #: (B, n) plant state at k + 1
    masked: np.ndarray  #: (B, N, M) bool, choices that were masked
    status: np.ndarray  #: (6,) first out-of-range and first masked entry (check_actions)


def apply_actions(Z: np.ndarray, tau: np.ndarray, act: np.ndarray, nbr: np.ndarray,
                  msg: np.ndarray, block_of: np.ndarray, A_lower_T: np.ndarray,
                  band: tuple[np.ndarray, np.ndarray, np.ndarray], *, x: np.ndarray,
                  A_T: np.ndarray, T: np.ndarray, w: np.ndarray | None = None,
                  W_T: np.ndarray | None = None, corr: np.ndarray | None = None,
                  luenberger: tuple | None = None, own: np.ndarray | None = None
                  ) -> StepOut:
    """One step of every member and agent, in one pass over ``(b, i)``.

    Per member: the plant ``x_next = A x (+ W w)`` (eq. (1)) and ``z = T^T x_next``. Per
    agent: validation of its actions ``act[b, i]`` (``M`` choices and the transmit bit;
    the rule of :func:`check_actions`, masked choices become 0 = keep and are flagged in
    ``masked``); then per substate ``j`` the source of the choice (itself for keep and
    average, the slot's neighbour for adopt), the index update (:func:`advance_indices`,
    or :func:`average_indices` for an average), the estimate to propagate
    (:func:`gather_substates`, or :func:`uniform_mix` for an average), then
    :func:`propagate` plus the source correction (eq. (7)). The very same row functions
    as those public kernels do the work, so results are bit-identical to calling them
    one after the other. Nothing is written to the inputs: the caller commits the outputs
    only when ``status`` reports no error it refuses.

    The correction is either given, ``corr (B, N, n)`` (any source estimator), or computed
    on the row from ``luenberger = (y, arrived, C_bar_pad, L_pad)`` exactly as
    :func:`innovation_correction` does (the fixed-gain source of eq. (7)). With
    substates restricted to the sources (``tau (B, N, M)``), ``block_of`` maps every
    coordinate to its column ``0..M-1`` and ``own`` gives each agent's column.
    """
    B, N, n = Z.shape
    M = tau.shape[2]
    Z_next = np.empty(Z.shape)
    tau_next = np.empty(tau.shape, dtype=tau.dtype)
    err = np.empty((B, N))
    x_next = np.empty((B, x.shape[1]))
    masked = np.empty((B, N, M), dtype=bool)
    first = np.full((B, 4), -1, dtype=np.int64)
    if luenberger is not None:
        y, arrived, C, L = luenberger
        rows, corr = gain_rows(L), np.zeros((1, 1, 1))
        L = np.ascontiguousarray(L[None] if L.ndim == 3 else L, dtype=float)
    else:
        if corr is None:
            raise ValueError("apply_actions needs corr or luenberger")
        y, arrived = np.zeros((1, 1, 1)), np.zeros((1, 1), bool)
        C, L, rows = np.zeros((1, 1, 1)), np.zeros((1, 1, 1, 1)), np.zeros((1, 2), np.int64)
    has_w = w is not None
    if not has_w:
        w, W_T = np.zeros((1, 1)), np.zeros((1, x.shape[1]))
    D, p = nbr.shape[2], x.shape[1]
    scratch = (np.empty((B, 1, M), np.int64), np.empty((B, 1, M), np.int64),
               np.empty((B, 1, n)), np.empty((B, 1, n)), np.empty((B, 1, M), tau.dtype),
               np.empty((B, D + 2), np.int64), np.ones((B, D + 2), np.bool_),
               np.empty((B, 1, n)), np.empty((B, C.shape[1])), np.empty((B, n)),
               np.empty((B, p)))
    _apply_all.at(Z.size * n + tau.size)(
        Z, tau, _own(own, tau), act, nbr, msg, block_of, band[0], band[1], band[2],
        A_lower_T, corr, luenberger is not None, y, arrived, C, L, rows, x, A_T, w, W_T,
        has_w, T, Z_next, tau_next, err, x_next, masked, first, *scratch)
    return StepOut(Z_next, tau_next, err, x_next, masked, _status(first))


def _status(first: np.ndarray) -> np.ndarray:
    """The first (in C order) out-of-range and masked entries from per-member records."""
    status = np.full(6, -1, dtype=np.int64)
    for k, col in ((0, 0), (3, 2)):
        hit = np.flatnonzero(first[:, col] >= 0)
        if hit.size:
            b = int(hit[0])
            status[k:k + 3] = (b, first[b, col], first[b, col + 1])
    return status


def _own(own: np.ndarray | None, tau: np.ndarray) -> np.ndarray:
    """Column of each agent's own substate (``-1``: none); default ``own[i] = i``."""
    if own is None:
        return np.arange(tau.shape[1], dtype=np.int64)
    return np.asarray(own, dtype=np.int64)


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
# Rows are addressed as (array, b, i) rather than passed as slices: a slice is a new
# array object with a reference count, which at N = 30 cost as much as the rule itself.
@njit(cache=True, inline="always")
def _advance_row(tau, b, i, own, src, sb, si, out, ob, oi):  # eqs. (9), (11), (14)
    for j in range(out.shape[2]):
        t = tau[b, src[sb, si, j], j]
        out[ob, oi, j] = OMEGA if t < 0 else t + 1
    if own[i] >= 0:  # a source keeps tau_i^{(i)} = 0
        out[ob, oi, own[i]] = 0


@njit(cache=True, inline="always")
def _average_row(tau, b, i, own, nbr, use, out, ob, oi):  # age of an average, eq. (6)
    for j in range(out.shape[2]):
        t = tau[b, i, j]
        omega = t < 0
        worst = t
        for d in range(nbr.shape[2]):
            if use[b, i, d]:
                v = tau[b, nbr[b, i, d], j]
                if v < 0:
                    omega = True
                elif v > worst:
                    worst = v
        out[ob, oi, j] = OMEGA if omega else worst + 1
    if own[i] >= 0:
        out[ob, oi, own[i]] = 0


@njit(cache=True, inline="always")
def _mix_row(Z, b, i, nbr, use, out, ob, oi):  # eq. (6)
    count = 1.0
    for d in range(nbr.shape[2]):
        if use[b, i, d]:
            count += 1.0
    for c in range(Z.shape[2]):
        s = 0.0
        for d in range(nbr.shape[2]):
            if use[b, i, d]:
                s += Z[b, nbr[b, i, d], c]
        out[ob, oi, c] = (Z[b, i, c] + s) / count


@njit(cache=True, inline="always")
def _gather_row(Z, b, src, sb, si, block_of, out, ob, oi):
    for c in range(Z.shape[2]):
        out[ob, oi, c] = Z[b, src[sb, si, block_of[c]], c]


@njit(cache=True, inline="always")
def _propagate_row(Z_sel, sb, si, Z, b, i, dq, dc, dv, ALT, out, ob, oi):
    """Row of eqs. (7), (10), (12) (see :func:`propagate`)."""
    n = Z.shape[2]
    o, z, zs = out[ob, oi], Z[b, i], Z_sel[sb, si]  # n^2 work: three views pay off
    for c in range(n):
        o[c] = 0.0
    for k in range(dv.shape[0]):  # block-diagonal part on the propagated estimate
        o[dc[k]] += dv[k] * zs[dq[k]]
    # couplings on the agent's own estimates, four columns of A_lower^T at a time (a
    # fixed association order, so the result is the same wherever this row runs)
    q = 0
    while q + 4 <= n:
        v0, v1, v2, v3 = z[q], z[q + 1], z[q + 2], z[q + 3]
        a0, a1, a2, a3 = ALT[q], ALT[q + 1], ALT[q + 2], ALT[q + 3]
        for c in range(n):
            o[c] = o[c] + a0[c] * v0 + a1[c] * v1 + a2[c] * v2 + a3[c] * v3
        q += 4
    while q < n:
        v0, a0 = z[q], ALT[q]
        for c in range(n):
            o[c] += a0[c] * v0
        q += 1


@njit(cache=True, inline="always")
def _innovation_row(Z, b, i, y, arrived, C, L, lb, lo, hi, innov, out, ob, oi):  # eq. (7)
    r, n = C.shape[1], C.shape[2]
    for c in range(n):
        out[ob, oi, c] = 0.0
    if lo >= hi:  # no gain rows: not a source (or nothing to correct)
        return
    for k in range(r):
        s = 0.0
        for c in range(n):
            s += C[i, k, c] * Z[b, i, c]
        innov[k] = (y[b, i, k] - s) if arrived[b, i] else 0.0
    for c in range(lo, hi):
        s = 0.0
        for k in range(r):
            s += L[lb, i, c, k] * innov[k]
        out[ob, oi, c] = s


@njit(cache=True, inline="always")
def _vecmat_row(x, b, M, out, ob):  # out[ob] = x[b] @ M, q-major (eqs. (1), (2))
    p, m = M.shape
    for c in range(m):
        out[ob, c] = 0.0
    for q in range(p):
        v = x[b, q]
        for c in range(m):
            out[ob, c] += v * M[q, c]


@njit(cache=True, inline="always")
def _check_row(act, b, i, msg, own, okt, ch, sb, si, masked, first):
    """Validate agent ``i``'s actions (see :func:`check_actions`); ``okt`` is a scratch
    of ``D + 2`` with ``okt[0] = okt[D + 1] = True``."""
    D = msg.shape[2]
    M = masked.shape[2]
    for d in range(D):
        okt[d + 1] = msg[b, i, d]
    bad = False
    anymask = False
    o = own[i]
    for j in range(M):
        a = act[b, i, j]
        inside = (a >= 0) & (a <= D + 1)
        ok = inside & okt[min(max(a, 0), D + 1)] & ((j != o) | (a == 0))
        bad |= not inside
        anymask |= not ok
        masked[b, i, j] = not ok
        ch[sb, si, j] = a if ok else 0
    t = act[b, i, M]
    bad |= (t < 0) | (t > 1)
    if bad and first[b, 0] < 0:
        for j in range(M + 1):
            a = act[b, i, j]
            if a < 0 or a > (D + 1 if j < M else 1):
                first[b, 0], first[b, 1] = i, j
                break
    if anymask and first[b, 2] < 0:
        for j in range(M):
            if masked[b, i, j]:
                first[b, 2], first[b, 3] = i, j
                break


# ----------------------------------------------------------------------------- drivers
def _advance_all(tau, own, src, out):
    for b in prange(tau.shape[0]):
        for i in range(tau.shape[1]):
            _advance_row(tau, b, i, own, src, b, i, out, b, i)


def _average_all(tau, own, nbr, use, out):
    for b in prange(tau.shape[0]):
        for i in range(tau.shape[1]):
            _average_row(tau, b, i, own, nbr, use, out, b, i)


def _gather_all(Z, src, block_of, out):
    for b in prange(Z.shape[0]):
        for i in range(Z.shape[1]):
            _gather_row(Z, b, src, b, i, block_of, out, b, i)


def _mix_all(Z, nbr, use, out):
    for b in prange(Z.shape[0]):
        for i in range(Z.shape[1]):
            _mix_row(Z, b, i, nbr, use, out, b, i)


def _propagate_all(Z_sel, Z, dq, dc, dv, ALT, out):
    for b in prange(Z.shape[0]):
        for i in range(Z.shape[1]):
            _propagate_row(Z_sel, b, i, Z, b, i, dq, dc, dv, ALT, out, b, i)


def _innovation_all(Z, y, arrived, C, L, rows, out, scratch):
    per_member = L.shape[0] > 1
    for b in prange(Z.shape[0]):
        innov = scratch[b]
        lb = np.int64(b) if per_member else np.int64(0)  # (prange indices are unsigned)
        for i in range(Z.shape[1]):
            _innovation_row(Z, b, i, y, arrived, C, L, lb, rows[i, 0], rows[i, 1], innov,
                            out, b, i)


def _vecmat_all(x, M, out):
    for b in prange(x.shape[0]):
        _vecmat_row(x, b, M, out, b)


def _check_actions(act, msg, own, choice, masked, first, okt):
    B, N, D = msg.shape
    for b in prange(B):
        okb = okt[b]
        for i in range(N):
            _check_row(act, b, i, msg, own, okb, choice, b, i, masked, first)


def _apply_all(Z, tau, own, act, nbr, msg, block_of, dq, dc, dv, ALT, corr, fused, y,
               arrived, C, L, rows, x, A_T, w, W_T, has_w, TT, Z_next, tau_next, err,
               x_next, masked, first, ch, src, zsel, mix, avg_tau, ext, okt, cor, innov, zt,
               wt):
    B, N, n = Z.shape
    D = nbr.shape[2]
    M = tau.shape[2]
    per_member = L.shape[0] > 1
    # scratch rows (from the wrapper): row b belongs to the thread that runs member b,
    # addressed as [b, 0, :] by the row functions
    for b in prange(B):
        okb, inb = okt[b], innov[b]  # one view per member, not per row
        lb = np.int64(b) if per_member else np.int64(0)  # (prange indices are unsigned)
        # the plant, eq. (1), and the true state in Lemma 1 coordinates
        _vecmat_row(x, b, A_T, x_next, b)
        if has_w:
            _vecmat_row(w, b, W_T, wt, b)
            for c in range(x.shape[1]):
                x_next[b, c] += wt[b, c]
        _vecmat_row(x_next, b, TT, zt, b)
        for i in range(N):
            _check_row(act, b, i, msg, own, okb, ch, b, 0, masked, first)
            # choice -> agent: keep and average use the agent itself, slot d its neighbour
            ext[b, 0] = i
            ext[b, D + 1] = i
            for d in range(D):
                ext[b, d + 1] = nbr[b, i, d] if nbr[b, i, d] >= 0 else i
            averaged = False
            for j in range(M):
                a = ch[b, 0, j]
                src[b, 0, j] = ext[b, a]
                averaged |= a == D + 1
            _advance_row(tau, b, i, own, src, b, 0, tau_next, b, i)
            _gather_row(Z, b, src, b, 0, block_of, zsel, b, 0)
            if averaged:
                _average_row(tau, b, i, own, nbr, msg, avg_tau, b, 0)
                _mix_row(Z, b, i, nbr, msg, mix, b, 0)
                for j in range(M):
                    if ch[b, 0, j] == D + 1:
                        tau_next[b, i, j] = avg_tau[b, 0, j]
                for c in range(n):
                    if ch[b, 0, block_of[c]] == D + 1:
                        zsel[b, 0, c] = mix[b, 0, c]
            _propagate_row(zsel, b, 0, Z, b, i, dq, dc, dv, ALT, Z_next, b, i)
            if fused:  # the fixed-gain source update, eq. (7), on the same row
                _innovation_row(Z, b, i, y, arrived, C, L, lb, rows[i, 0], rows[i, 1], inb,
                                cor, b, 0)
            else:
                for c in range(n):
                    cor[b, 0, c] = corr[b, i, c]
            s = 0.0
            for c in range(n):
                v = Z_next[b, i, c] + cor[b, 0, c]
                Z_next[b, i, c] = v
                e = v - zt[b, c]
                s += e * e
            err[b, i] = np.sqrt(s)


def keep_own_blocks(Z_sel: np.ndarray, Z: np.ndarray, own_block: np.ndarray) -> np.ndarray:
    """Restore every source's own substate in ``Z_sel`` (sources never mix their substate).

    ``own_block`` is the ``(N, n)`` mask ``block_of[c] == i``.
    """
    return np.where(own_block[None], Z, Z_sel)


# ----------------------------------------------------------------------------- dispatch
for _name in ("_advance_all", "_average_all", "_gather_all", "_mix_all", "_propagate_all",
              "_innovation_all", "_vecmat_all", "_check_actions", "_apply_all"):
    globals()[_name] = Driver(globals()[_name])
del _name
