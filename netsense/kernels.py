"""Batched update rules of the distributed observers — the public API of the one
implementation.

Every function works on a leading batch axis ``B`` and an agent axis ``N`` and contains
no Python loop over agents or substates, so the scripted observers, the environment and
the batched simulator all call exactly this code. The rules themselves are the compiled
row functions of :mod:`netsense.rules`; the compiled loops over members and agents are in
:mod:`netsense.drivers`; the functions here check and allocate, then call a driver.
:func:`apply_actions` is the environment's whole step in one pass over the same rows.

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

from netsense import drivers
from netsense.observation import slot_messages
from netsense.rules import OMEGA  # noqa: F401  (re-exported: kernels.OMEGA)


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
    tau, nbr = np.asarray(tau), np.asarray(nbr)
    if tau.ndim != 3 or nbr.ndim != 3 or nbr.shape[:2] != tau.shape[:2]:
        raise ValueError(f"tau must be (B, N, M) and nbr (B, N, D) with the same B, N; got "
                         f"{tau.shape} and {nbr.shape}")
    if np.shape(valid) != nbr.shape:
        raise ValueError(f"valid must have the shape of nbr {nbr.shape}, got "
                         f"{np.shape(valid)}")
    if transmit is not None and np.shape(transmit) != tau.shape[:2]:
        raise ValueError(f"transmit must have shape {tau.shape[:2]}, got {np.shape(transmit)}")
    use = usable_slots(nbr, valid, transmit)
    B, N, M = tau.shape
    if use.any() and not (0 <= nbr[use].min() and nbr[use].max() < N):
        raise ValueError(f"a usable slot names no agent 0..{N - 1}")
    D = nbr.shape[2]
    slot = np.empty((B, N, M), dtype=np.int64)
    src = np.empty((B, N, M), dtype=np.int64)
    drivers.freshness_all.at(B * N * M * (D + 1), runs=B)(
        tau, nbr, use, np.empty((B, D + 1, M)), slot, src)
    return src, slot


def advance_indices(tau: np.ndarray, src: np.ndarray, own: np.ndarray | None = None
                    ) -> np.ndarray:
    """Freshness indices at ``k+1`` given whom each agent used, eqs. (9), (11), (14).

    ``tau_i^{(j)}[k+1] = tau_{src}^{(j)}[k] + 1`` (omega stays omega), and every source
    keeps ``tau_j^{(j)} = 0``. ``own[i]`` is the substate (column) of agent ``i``, ``-1``
    if it owns none; the default is ``own[i] = i`` (one column per agent).
    """
    tau = np.asarray(tau)
    out = np.empty(tau.shape, dtype=tau.dtype)
    drivers.advance_all.at(tau.size, runs=tau.shape[0])(tau, _own(own, tau), np.asarray(src), out)
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
    drivers.average_all.at(tau.size, runs=tau.shape[0])(
        tau, _own(own, tau), np.asarray(nbr), usable_slots(nbr, valid, transmit), out)
    return out


def gather_substates(Z: np.ndarray, src: np.ndarray, block_of: np.ndarray) -> np.ndarray:
    """``Zg[b, i, c] = Z[b, src[b, i, block_of[c]], c]``: each substate from its chosen agent."""
    Z = np.asarray(Z, dtype=float)
    out = np.empty(Z.shape)
    drivers.gather_all.at(Z.size, runs=Z.shape[0])(Z, np.asarray(src), np.asarray(block_of), out)
    return out


def uniform_mix(Z: np.ndarray, nbr: np.ndarray, valid: np.ndarray,
                transmit: np.ndarray | None = None) -> np.ndarray:
    """Average of the own estimate and every transmitting in-neighbour's, eq. (6).

    Weights are uniform over ``N_i[k] ∪ {i}`` restricted to neighbours that transmitted.
    """
    Z = np.asarray(Z, dtype=float)
    out = np.empty(Z.shape)
    drivers.mix_all.at(Z.size, runs=Z.shape[0])(Z, np.asarray(nbr),
                                                usable_slots(nbr, valid, transmit), out)
    return out


def propagate(Z_sel: np.ndarray, Z: np.ndarray, A_diag: np.ndarray,
              A_lower: np.ndarray) -> np.ndarray:
    """Open-loop part of eqs. (7), (10), (12): ``A_jj z_sel^{(j)} + sum_{q<j} A_jq z_i^{(q)}``.

    ``Z_sel`` holds, per substate, the estimate the agent decided to propagate (its own,
    an adopted one, or a consensus mix); the couplings ``A_jq`` always act on the agent's
    own estimates of the other substates. ``A_lower`` may carry the decomposition's
    rounding-level entries above the diagonal, so the model is exact. The block-diagonal
    part visits only the non-zeros of ``A_diag`` (the order of the sums is that of
    :func:`netsense.lanes.block_triangular_row`).
    """
    Z_sel = np.ascontiguousarray(Z_sel, dtype=float)
    Z = np.ascontiguousarray(Z, dtype=float)
    ADT, ALT = _t(A_diag), _t(A_lower)
    n = Z.shape[-1] if Z.ndim == 3 else -1
    if Z.ndim != 3 or Z_sel.shape != Z.shape or ADT.shape != (n, n) or ALT.shape != (n, n):
        raise ValueError(f"propagate needs Z_sel and Z of one shape (B, N, n) and n x n "
                         f"A_diag, A_lower; got {Z_sel.shape}, {Z.shape}, "
                         f"{np.shape(A_diag)}, {np.shape(A_lower)}")
    out = np.empty(Z_sel.shape)
    drivers.propagate_all.at(Z_sel.size * n, runs=Z_sel.shape[0])(Z_sel, Z, ADT, ALT, out)
    return out


def innovation_correction(Z: np.ndarray, y: np.ndarray, arrived: np.ndarray | None,
                          C_bar_pad: np.ndarray, L_pad: np.ndarray,
                          rows: np.ndarray | None = None) -> np.ndarray:
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
    rows : (N, 2) int, optional
        :func:`gain_rows` of ``L_pad`` (computed when not given; fixed gains can pass it
        once computed).
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
    rows = gain_rows(L) if rows is None else np.asarray(rows, dtype=np.int64)
    drivers.innovation_all.at(Z.size, runs=B)(Z, y, arr, C, L, rows, out, np.empty((B, C.shape[1])))
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
    bit. The rule of the plant (eq. (1)), the outputs (eq. (2)) and ``z = T^T x``; the
    environment's compiled passes call its row function (``rules.vecmat_row``) directly.
    """
    x = np.ascontiguousarray(x, dtype=float)
    M = np.ascontiguousarray(M, dtype=float)
    out = np.empty((x.shape[0], M.shape[1]))
    drivers.vecmat_all.at(x.shape[0] * M.size // 8, runs=x.shape[0])(x, M, out)  # light
    return out


# ----------------------------------------------------------------------------- the step
#: Meaning of the entries of :func:`apply_actions`' ``status``.
STATUS_FIELDS = ("range_b", "range_i", "range_j", "masked_b", "masked_i", "masked_j")


def check_actions(act: np.ndarray, msg: np.ndarray, choice: np.ndarray,
                  masked: np.ndarray, own: np.ndarray | None = None) -> np.ndarray:
    """Validate the environment's actions ``(B, N, M + 1)`` against the slot table.

    Entry ``act[b, i, j]`` (``j < M`` substates) is ``0`` keep, ``1..D`` adopt slot
    ``d - 1``, ``D + 1`` average; ``act[b, i, M]`` is the transmit bit. A choice is
    *masked* when its slot holds no message (``msg[b, i, d]`` false) or when it is not 0
    on the agent's own substate (``j = own[i]``, default ``own[i] = i``: eq. (7) is not
    an action). Writes the sanitised choices (masked ones replaced by 0, keep) into
    ``choice (B, N, M)`` and the masked flags into
    ``masked``, and returns the ``status`` vector of :data:`STATUS_FIELDS`: the first
    (in C order) out-of-range entry and the first masked one, ``-1`` where there is none.
    """
    first = np.empty((act.shape[0], 4), dtype=np.int64)  # (both set per member by the
    okt = np.empty((act.shape[0], msg.shape[2] + 2), dtype=np.bool_)  # driver's threads)
    drivers.check_actions.at(act.size, runs=act.shape[0])(act, msg, _own(own, choice), choice,
                                                          masked, first, okt)
    return _status(first)


class StepBuffers:
    """The outputs and scratch rows of :func:`apply_actions` for one problem size, for a
    caller that steps many times (``apply_actions(..., work=buffers)``).

    Allocated once, written in place at every call: the arrays of the returned
    :class:`StepOut` *are* these buffers, valid until the next call with the same
    buffers. :class:`netsense.envcore.BatchedCore` keeps two sets and alternates
    (a call reads the state the other set holds). Why: fresh outputs of a threaded pass
    come from recycled memory that the other thread may have written last, and on the
    benchmark VM, whose two vCPUs sometimes sit far apart, every such cache line crossing
    costs (measured ~15 % of a step at ``(1024, 10, 10)`` then); a buffer written by the same
    thread at every step stays in that thread's caches.

    ``B, N, n`` estimates, ``M`` substates, ``D`` slots, ``p`` plant states, ``r``
    outputs per agent (the rows of ``C_bar``; 1 without the fused source),
    ``tau_dtype`` the indices' dtype. ``share_scratch``: another set of this size whose
    scratch rows this one uses too (they live only during a call; one set stays warmer).
    """

    def __init__(self, B: int, N: int, n: int, M: int, D: int, p: int, r: int,
                 tau_dtype=np.int64, share_scratch: StepBuffers | None = None) -> None:
        tau_dtype = np.dtype(tau_dtype)
        self.key = (B, N, n, M, D, p, r, tau_dtype)
        self.Z_next = np.empty((B, N, n))
        self.tau_next = np.empty((B, N, M), dtype=tau_dtype)
        self.err = np.empty((B, N))
        self.x_next = np.empty((B, p))
        self.masked = np.empty((B, N, M), dtype=bool)
        self.first = np.empty((B, 4), dtype=np.int64)
        # scratch rows of the fused pass, one per member (row b: the thread of member b)
        if share_scratch is not None:
            if share_scratch.key != self.key:
                raise ValueError(f"share_scratch holds buffers for {share_scratch.key}, "
                                 f"not {self.key}")
            self.scratch = share_scratch.scratch
            return
        self.scratch = (np.empty((B, 1, M), np.int64), np.empty((B, 1, M), np.int64),
                        np.empty((B, N, n)), np.empty((B, 1, n)),
                        np.empty((B, 1, M), tau_dtype), np.empty((B, D + 2), np.int64),
                        np.empty((B, D + 2), np.bool_), np.empty((B, 1, n)),
                        np.empty((B, r)), np.empty((B, n)), np.empty((B, p)))


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
                  A_diag_T: np.ndarray, *, x: np.ndarray,
                  A_T: np.ndarray, T: np.ndarray, w: np.ndarray | None = None,
                  W_T: np.ndarray | None = None, corr: np.ndarray | None = None,
                  luenberger: tuple | None = None, own: np.ndarray | None = None,
                  work: StepBuffers | None = None) -> StepOut:
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
    on the row from ``luenberger = (y, arrived, C_bar_pad, L_pad[, gain_rows(L_pad)])``
    exactly as
    :func:`innovation_correction` does (the fixed-gain source of eq. (7)). With
    substates restricted to the sources (``tau (B, N, M)``), ``block_of`` maps every
    coordinate to its column ``0..M-1`` and ``own`` gives each agent's column.

    ``work``: :class:`StepBuffers` of this size to write the outputs and scratch rows
    into (the returned arrays are then those buffers); default fresh arrays.
    """
    Z = np.ascontiguousarray(Z, dtype=float)
    B, N, n = Z.shape
    M = tau.shape[2]
    A_diag_T = np.ascontiguousarray(A_diag_T, dtype=float)
    A_lower_T = np.ascontiguousarray(A_lower_T, dtype=float)
    if A_diag_T.shape != (n, n) or A_lower_T.shape != (n, n):
        raise ValueError(f"A_diag_T and A_lower_T must be n x n = {(n, n)}, got "
                         f"{A_diag_T.shape} and {A_lower_T.shape}")
    if luenberger is not None:
        y, arrived, C, L = luenberger[:4]
        rows = luenberger[4] if len(luenberger) > 4 else gain_rows(L)
        corr = np.zeros((1, 1, 1))
        L = np.ascontiguousarray(L[None] if L.ndim == 3 else L, dtype=float)
    else:
        if corr is None:
            raise ValueError("apply_actions needs corr or luenberger")
        y, arrived = np.zeros((1, 1, 1)), np.zeros((1, 1), bool)
        C, L, rows = np.zeros((1, 1, 1)), np.zeros((1, 1, 1, 1)), np.zeros((1, 2), np.int64)
    has_w = w is not None
    if not has_w:
        w, W_T = np.zeros((1, 1)), np.zeros((1, x.shape[1]))
    # the row products take C-contiguous float64 rows (no copy when they already are)
    x, A_T, T, w, W_T = (np.ascontiguousarray(a, dtype=float) for a in (x, A_T, T, w, W_T))
    key = (B, N, n, M, nbr.shape[2], x.shape[1], C.shape[1], tau.dtype)
    if work is None:
        work = StepBuffers(*key)
    elif work.key != key:
        raise ValueError(f"work holds buffers for (B, N, n, M, D, p, r, tau dtype) = "
                         f"{work.key}, this call needs {key}")
    elif any(np.may_share_memory(a, o) for a, o in
             ((Z, work.Z_next), (tau, work.tau_next), (x, work.x_next))):
        raise ValueError("work's outputs overlap the inputs Z, tau or x (a step reads the "
                         "state while it writes the next one: alternate two StepBuffers)")
    drivers.apply_all.at(Z.size * n + tau.size, runs=B)(
        Z, tau, _own(own, tau), act, nbr, msg, block_of, A_diag_T, A_lower_T, corr,
        luenberger is not None, y, arrived, C, L, rows, x, A_T, w, W_T, has_w, T,
        work.Z_next, work.tau_next, work.err, work.x_next, work.masked, work.first,
        *work.scratch)
    return StepOut(work.Z_next, work.tau_next, work.err, work.x_next, work.masked,
                   _status(work.first))


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


def usable_slots(nbr: np.ndarray, valid: np.ndarray,
                 transmit: np.ndarray | None = None) -> np.ndarray:
    """Slots whose neighbour is present and (if given) transmitted, ``(B, N, D)`` bool.

    The message rule of :func:`netsense.rules.message_row` (without link drops) on the
    slots ``valid`` marks; ``transmit`` is ``(B, N)``.
    """
    valid = np.asarray(valid, dtype=bool)
    if transmit is None:
        return valid
    return slot_messages(np.where(valid, nbr, -1), np.asarray(transmit, bool))


def keep_own_blocks(Z_sel: np.ndarray, Z: np.ndarray, own_block: np.ndarray) -> np.ndarray:
    """Restore every source's own substate in ``Z_sel`` (sources never mix their substate).

    ``own_block`` is the ``(N, n)`` mask ``block_of[c] == i``.
    """
    return np.where(own_block[None], Z, Z_sel)
