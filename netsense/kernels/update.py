"""Batched update rules of the distributed observers — the public API of the one
implementation.

Every function works on a leading batch axis ``B`` and an agent axis ``N`` and contains
no Python loop over agents or substates, so the scripted observers, the environment and
the batched simulator all call exactly this code. The rules themselves are the compiled
row functions of :mod:`netsense.kernels.rules`; the compiled loops over members and agents are in
:mod:`netsense.kernels.drivers`; the functions here check and allocate, then call a driver.
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

from netsense.kernels import checks, drivers
from netsense.kernels.rules import OMEGA  # noqa: F401  (re-exported: kernels.OMEGA)


def freshness_choice(tau: np.ndarray, nbr: np.ndarray, valid: np.ndarray,
                     transmit: np.ndarray | None = None, sent: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The freshness rule: whom each agent adopts each substate from, eqs. (8)-(14).

    For agent ``i`` and substate ``j``, among the transmitting in-neighbours ``l`` with
    ``tau_l^{(j)} != omega`` (the set ``M_i^{(j)}[k]`` of eq. (8)) take the one with the
    smallest index. With per-substate messages (``sent (B, N, M)``: agent ``l`` sent
    substate ``j``), only neighbours that sent ``j`` count for substate ``j``
    (:func:`usable_slots` on (slot, substate) pairs). Adopt it if ``tau_i^{(j)} = omega``
    (Case 1) or if it is strictly fresher, ``tau_l^{(j)} < tau_i^{(j)}`` (the set
    ``F_i^{(j)}[k]`` of eq. (13), Case 2); otherwise keep the own estimate. The source
    ``j`` has ``tau_j^{(j)} = 0`` and so never adopts. **Tie-break:** among equally fresh
    neighbours the one with the smallest node index wins (slots are in ascending node
    order and ``argmin`` returns the first).

    Returns
    -------
    src : (B, N, N) int
        Agent whose estimate of substate ``j`` agent ``i`` uses.
    slot : (B, N, N) int
        Chosen slot ``d`` (``-1`` when keeping the own estimate).
    """
    tau, nbr, valid, transmit = _slots_in(tau, nbr, valid, transmit)
    if sent is not None:
        sent = checks.mask("sent", sent, tau.shape)
    slots = usable_slots(nbr, valid, transmit)
    B, N, M = tau.shape
    if slots.any() and not (0 <= nbr[slots].min() and nbr[slots].max() < N):
        raise ValueError(f"a usable slot names no agent 0..{N - 1}")
    use = slots[..., None] if sent is None else substate_messages(nbr, slots, sent)
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
    tau = checks.array("tau", tau, (None, None, None), kind="i")
    src = _sources_in(src, tau.shape)
    own = _own_in(own, tau)
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
    tau, nbr, valid, transmit = _slots_in(tau, nbr, valid, transmit)
    own = _own_in(own, tau)
    out = np.empty(tau.shape, dtype=tau.dtype)
    drivers.average_all.at(tau.size, runs=tau.shape[0])(
        tau, _own(own, tau), np.asarray(nbr), usable_slots(nbr, valid, transmit), out)
    return out


def gather_substates(Z: np.ndarray, src: np.ndarray, block_of: np.ndarray) -> np.ndarray:
    """``Zg[b, i, c] = Z[b, src[b, i, block_of[c]], c]``: each substate from its chosen agent.

    ``Z (B, N, n)``; ``src (B, N, M)`` agents ``0..N-1``; ``block_of (n,)`` substates
    ``0..M-1``.
    """
    Z = checks.array("Z", Z, (None, None, None), kind="f")
    src = _sources_in(src, Z.shape[:2] + (None,))
    block_of = checks.array("block_of", block_of, (Z.shape[2],), kind="i")
    checks.index_range("block_of", block_of, 0, src.shape[2])
    out = np.empty(Z.shape)
    drivers.gather_all.at(Z.size, runs=Z.shape[0])(Z, np.asarray(src), np.asarray(block_of), out)
    return out


def uniform_mix(Z: np.ndarray, nbr: np.ndarray, valid: np.ndarray,
                transmit: np.ndarray | None = None) -> np.ndarray:
    """Average of the own estimate and every transmitting in-neighbour's, eq. (6).

    Weights are uniform over ``N_i[k] ∪ {i}`` restricted to neighbours that transmitted.
    """
    Z = checks.array("Z", Z, (None, None, None), kind="f")
    _, nbr, valid, transmit = _slots_in(np.empty(Z.shape[:2] + (0,), np.int64), nbr, valid,
                                        transmit)
    out = np.empty(Z.shape)
    drivers.mix_all.at(Z.size, runs=Z.shape[0])(Z, np.asarray(nbr),
                                                usable_slots(nbr, valid, transmit), out)
    return out


def propagate(Z_sel: np.ndarray, Z: np.ndarray, A_diag: np.ndarray,
              A_lower: np.ndarray) -> np.ndarray:
    """Open-loop part of eqs. (7), (10), (12): ``A_jj z_sel^{(j)} + sum_{q<j} A_jq z_i^{(q)}``.

    ``Z_sel`` holds, per substate, the estimate the agent decided to propagate (its own,
    an adopted one, or a consensus mix); the couplings ``A_jq`` always act on the agent's
    own estimates of the other substates. ``A_lower`` is the strictly lower block part of
    ``A_bar`` (Lemma 1's zeros above the diagonal are exact, see
    :func:`netsense.systems.decomposition.refine_structure`). The block-diagonal
    part visits only the non-zeros of ``A_diag`` (the order of the sums is that of
    :func:`netsense.kernels.lanes.block_triangular_row`).
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
    Z, y, arrived, C_bar_pad, L_pad, rows = _luenberger_in(Z, y, arrived, C_bar_pad, L_pad,
                                                           rows)
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
    if np.ndim(L_pad) < 3:
        raise ValueError(f"L_pad must have shape (..., N, n, r), got {np.shape(L_pad)}")
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
    x = checks.array("x", x, (None, None), kind="f")
    M = checks.array("M", M, (x.shape[1], None), kind="f")
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

    ``choice`` must be a writable int64 array and ``masked`` a writable bool array, both
    ``(B, N, M)``; ``msg (B, N, D)`` bool.
    """
    choice = checks.array("choice", choice, (None, None, None), kind="i")
    B, N, M = choice.shape
    act = checks.array("act", act, (B, N, M + 1), kind="i")
    msg = checks.mask("msg", msg, (B, N, None))
    for name, a, dt in (("choice", choice, np.int64), ("masked", masked, np.bool_)):
        if not (isinstance(a, np.ndarray) and a.dtype == dt and a.shape == (B, N, M)
                and a.flags.writeable):
            raise ValueError(f"{name} must be a writable {np.dtype(dt).name} array of shape "
                             f"{(B, N, M)} (an output), got {getattr(a, 'dtype', type(a))} "
                             f"{np.shape(a)}")
    own = _own_in(own, choice)
    return _check_actions(act, msg, choice, masked, own)


def _check_actions(act: np.ndarray, msg: np.ndarray, choice: np.ndarray,
                   masked: np.ndarray, own: np.ndarray | None = None) -> np.ndarray:
    """:func:`check_actions` without checks (the core's path: its arrays are its own)."""
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
    buffers. :class:`netsense.engine.core.BatchedCore` keeps two sets and alternates
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
        for name, v in zip(("B", "N", "n", "M", "D", "p", "r"), (B, N, n, M, D, p, r),
                           strict=True):
            checks.integer(name, v, 0)
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

    Shapes (checked, with index ranges, before anything runs): ``Z (B, N, n)``, ``tau (B,
    N, M)`` and ``act (B, N, M + 1)`` integers, ``nbr (B, N, D)`` agents ``-1..N-1``,
    ``msg (B, N, D)`` bool (only on slots that hold a neighbour), ``block_of (n,)``
    substates ``0..M-1``, ``A_lower_T, A_diag_T (n, n)``, ``x (B, p)``, ``A_T (p, p)``,
    ``T (p, n)``, ``w (B, q)`` with ``W_T (q, p)``, ``corr (B, N, n)``, ``own (N,)``
    substates ``-1..M-1``, ``luenberger`` as :func:`innovation_correction` takes them.
    """
    Z = checks.array("Z", Z, (None, None, None), kind="f")
    B, N, n = Z.shape
    tau = checks.array("tau", tau, (B, N, None), kind="i")
    M = tau.shape[2]
    act = checks.array("act", act, (B, N, M + 1), kind="i")
    nbr = checks.array("nbr", nbr, (B, N, None), kind="i")
    checks.index_range("nbr", nbr, -1, N)
    msg = checks.mask("msg", msg, nbr.shape)
    if (msg & (nbr < 0)).any():
        raise ValueError("msg must be false on empty slots (nbr = -1)")
    block_of = checks.array("block_of", block_of, (n,), kind="i")
    checks.index_range("block_of", block_of, 0, M)
    A_lower_T = checks.array("A_lower_T", A_lower_T, (n, n), kind="f")
    A_diag_T = checks.array("A_diag_T", A_diag_T, (n, n), kind="f")
    x = checks.array("x", x, (B, None), kind="f")
    p = x.shape[1]
    A_T = checks.array("A_T", A_T, (p, p), kind="f")
    T = checks.array("T", T, (p, n), kind="f")
    if w is not None:
        if W_T is None:
            raise ValueError("W_T is needed with w (the process noise's input matrix)")
        w = checks.array("w", w, (B, None), kind="f")
        W_T = checks.array("W_T", W_T, (w.shape[1], p), kind="f")
    if (corr is None) == (luenberger is None):
        raise ValueError("apply_actions needs exactly one of corr and luenberger")
    if corr is not None:
        corr = checks.array("corr", corr, (B, N, n), kind="f")
    else:
        if not isinstance(luenberger, tuple) or len(luenberger) not in (4, 5):
            raise ValueError("luenberger must be a tuple (y, arrived, C_bar_pad, L_pad[, "
                             "rows])")
        y, arrived, C, L, rows = _luenberger_in(Z, *luenberger)[1:]
        arrived = np.ones((B, N), bool) if arrived is None else arrived
        luenberger = (y, arrived, C, L) if rows is None else (y, arrived, C, L, rows)
    own = _own_in(own, tau)
    if work is not None and not isinstance(work, StepBuffers):
        raise ValueError(f"work must be StepBuffers or None, got {type(work).__name__}")
    return _apply_actions(Z, tau, act, nbr, msg, block_of, A_lower_T, A_diag_T, x=x, A_T=A_T,
                          T=T, w=w, W_T=W_T, corr=corr, luenberger=luenberger, own=own,
                          work=work)


def _apply_actions(Z: np.ndarray, tau: np.ndarray, act: np.ndarray, nbr: np.ndarray,
                   msg: np.ndarray, block_of: np.ndarray, A_lower_T: np.ndarray,
                   A_diag_T: np.ndarray, *, x: np.ndarray,
                   A_T: np.ndarray, T: np.ndarray, w: np.ndarray | None = None,
                   W_T: np.ndarray | None = None, corr: np.ndarray | None = None,
                   luenberger: tuple | None = None, own: np.ndarray | None = None,
                   work: StepBuffers | None = None) -> StepOut:
    """:func:`apply_actions` without the checks of its arguments' index ranges: the
    core's path (:class:`netsense.engine.core.BatchedCore` builds every array itself)."""
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


def _own_in(own, tau: np.ndarray) -> np.ndarray | None:
    """Check ``own (N,)``: substates ``-1..M-1`` for ``tau (B, N, M)``."""
    if own is None:
        if tau.shape[1] > tau.shape[2]:
            raise ValueError(f"own is needed when there are fewer substates ({tau.shape[2]}) "
                             f"than agents ({tau.shape[1]})")
        return None
    own = checks.array("own", own, (tau.shape[1],), kind="i")
    checks.index_range("own", own, -1, tau.shape[2])
    return own


def _sources_in(src, shape: tuple) -> np.ndarray:
    """Check ``src`` (``shape``; ``None`` = any length): agents ``0..N-1``."""
    src = checks.array("src", src, shape, kind="i")
    checks.index_range("src", src, 0, src.shape[1])
    return src


def _slots_in(tau, nbr, valid, transmit):
    """Check ``tau (B, N, M)``, ``nbr (B, N, D)`` (agents ``0..N-1`` where ``valid``),
    ``valid`` like ``nbr`` and ``transmit (B, N)``, both bool."""
    tau = checks.array("tau", tau, (None, None, None), kind="i")
    B, N = tau.shape[:2]
    nbr = checks.array("nbr", nbr, (B, N, None), kind="i")
    valid = checks.mask("valid", valid, nbr.shape)
    checks.index_range("nbr", nbr, 0, N, where=valid)
    if transmit is not None:
        transmit = checks.mask("transmit", transmit, (B, N))
    return tau, nbr, valid, transmit


def _luenberger_in(Z, y, arrived, C_bar_pad, L_pad, rows=None):
    """Check the arguments of :func:`innovation_correction` (see there for the shapes)."""
    Z = checks.array("Z", Z, (None, None, None), kind="f")
    B, N, n = Z.shape
    C = checks.array("C_bar_pad", C_bar_pad, (N, None, n), kind="f")
    r = C.shape[1]
    y = checks.array("y", y, (B, N, r), kind="f")
    if arrived is not None:
        arrived = checks.mask("arrived", arrived, (B, N))
    L = checks.array("L_pad", L_pad, (N, n, r) if np.ndim(L_pad) == 3 else (None, N, n, r),
                     kind="f")
    if L.ndim == 4 and L.shape[0] not in (1, B):
        raise ValueError(f"L_pad must have shape (N, n, r), (1, N, n, r) or (B, N, n, r) = "
                         f"{(B, N, n, r)}, got {L.shape}")
    if rows is not None:
        rows = checks.array("rows", rows, (N, 2), kind="i")
        checks.index_range("rows", rows, 0, n + 1)
    return Z, y, arrived, C, L, rows


def _own(own: np.ndarray | None, tau: np.ndarray) -> np.ndarray:
    """Column of each agent's own substate (``-1``: none); default ``own[i] = i``."""
    if own is None:
        return np.arange(tau.shape[1], dtype=np.int64)
    return np.asarray(own, dtype=np.int64)


def _t(A: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(A, dtype=float).T)


def usable_slots(nbr: np.ndarray, valid: np.ndarray,
                 transmit: np.ndarray | None = None, sent: np.ndarray | None = None
                 ) -> np.ndarray:
    """Slots whose neighbour is present and (if given) transmitted, ``(B, N, D)`` bool.

    The message rule of :func:`netsense.kernels.rules.message_row` (without link drops) on the
    slots ``valid`` marks; ``transmit`` is ``(B, N)``. With per-substate messages,
    ``sent (B, N, M)`` (agent ``l`` sent substate ``j``), the result is the ``(B, N, D,
    M)`` table of usable (slot, substate) pairs (:func:`substate_messages`).
    """
    nbr = checks.array("nbr", nbr, (None, None, None), kind="i")
    _, nbr, valid, transmit = _slots_in(np.empty(nbr.shape[:2] + (0,), np.int64), nbr, valid,
                                        transmit)
    use = valid if transmit is None else slot_messages(np.where(valid, nbr, -1), transmit)
    return use if sent is None else substate_messages(nbr, use, sent)


def substate_messages(nbr: np.ndarray, msg: np.ndarray, sent: np.ndarray) -> np.ndarray:
    """``(B, N, D, M)`` bool: slot ``d`` of agent ``i`` carries substate ``j``.

    Per-substate messages: the slot holds a message (``msg[b, i, d]``, e.g.
    :func:`slot_messages`) and its neighbour ``l = nbr[b, i, d]`` put substate ``j`` in it
    (``sent[b, l, j]``). A substate that was not sent cannot be adopted (or averaged).
    """
    nbr = checks.array("nbr", nbr, (None, None, None), kind="i")
    B, N = nbr.shape[:2]
    msg = checks.mask("msg", msg, nbr.shape)
    sent = checks.mask("sent", sent, (B, N, None))
    checks.index_range("nbr", nbr, 0, N, where=msg)
    who = np.where(msg, nbr, 0)
    return sent[np.arange(B)[:, None, None], who] & msg[..., None]


def keep_own_blocks(Z_sel: np.ndarray, Z: np.ndarray, own_block: np.ndarray) -> np.ndarray:
    """Restore every source's own substate in ``Z_sel`` (sources never mix their substate).

    ``own_block`` is the ``(N, n)`` mask ``block_of[c] == i``.
    """
    Z = checks.array("Z", Z, (None, None, None))
    checks.array("Z_sel", Z_sel, Z.shape)
    checks.array("own_block", own_block, Z.shape[1:])
    return np.where(own_block[None], Z, Z_sel)


def slot_messages(nbr: np.ndarray, transmit: np.ndarray,
                  link: np.ndarray | None = None) -> np.ndarray:
    """``(B, N, D)`` bool: slot ``d`` of agent ``i`` holds a message at this step.

    The slot holds a neighbour ``l = nbr[b, i, d] >= 0`` that transmitted
    (``transmit[b, l]``) and whose link ``l -> i`` delivered (``link[b, i, l]``, when
    given).
    """
    nbr = checks.array("nbr", nbr, (None, None, None), kind="i")
    B, N = nbr.shape[:2]
    checks.index_range("nbr", nbr, -1, N)
    transmit = checks.mask("transmit", transmit, (B, N))
    if link is not None:
        link = checks.mask("link", link, (B, N, N))
    out = np.empty(nbr.shape, dtype=bool)
    if link is None:
        drivers.messages_all.at(out.size, runs=out.shape[0])(
            nbr, transmit, np.ones((1, 1, 1, 1), bool), False, out)
    else:
        drivers.messages_all.at(out.size, runs=out.shape[0])(
            nbr, transmit, np.asarray(link, bool)[:, None], True, out)
    return out
