"""The update rules of the distributed observers, one compiled row function each.

A row function computes one agent's row of one rule, addressed as ``(array, b, i)``
rather than as a slice, and is inlined (``inline="always"``) into the batched drivers of
:mod:`netsense.kernels.drivers`: the public kernels (:mod:`netsense.kernels.update`), the
observers, the
environment's fused step and the benchmarks all run this code, so there is one
implementation of every rule. No fastmath: the arithmetic is IEEE in program order, hence
bit-identical wherever a row runs.

==================  ==============================================================
row function        rule
==================  ==============================================================
``advance_row``     freshness index after keep/adopt, eqs. (9), (11), (14)
``average_row``     index of a uniform average: stalest contributor + 1 (eq. (6))
``mix_row``         uniform average of the own and the received estimates, eq. (6)
``gather_row``      each substate's estimate from the agent chosen for it
``propagate_rows``  ``A_jj z_sel^{(j)} + sum_{q<j} A_jq z^{(q)}``, eqs. (7), (10), (12)
``innovation_row``  fixed-gain source correction ``L_j (y_j - C_bar_j z_j)``, eq. (7)
``vecmat_row``      ``x[b] @ M`` in a fixed order (plant eq. (1), outputs eq. (2))
``check_row``       the action rule: range, message present, own substate only keep
``message_row``     which slots hold a message (neighbour present, sent, delivered)
``freshness_row``   whom to adopt each substate from: the freshest slot, eqs. (8)-(13)
==================  ==============================================================
"""

from __future__ import annotations

from netsense.kernels.jit import njit_cached
from netsense.kernels.lanes import block_triangular_pair, block_triangular_row, row_times_matrix

#: Encoding of the freshness index's dummy value omega (eq. (8)ff.).
OMEGA = -1


# One agent's row of each rule. The drivers of netsense.kernels.drivers loop over (b, i) and call
# these (for the public kernels of netsense.kernels.update, apply_actions and the environment's
# other passes), so there is one implementation of every rule. No fastmath: the
# arithmetic is IEEE in program order, hence identical wherever a row function runs.
# Rows are addressed as (array, b, i) rather than passed as slices (a slice is a new array
# object per call; with reference counting, at N = 30, it cost as much as the rule).
@njit_cached(inline="always")
def advance_row(tau, b, i, own, src, sb, si, out, ob, oi):  # eqs. (9), (11), (14)
    for j in range(out.shape[2]):
        t = tau[b, src[sb, si, j], j]
        out[ob, oi, j] = OMEGA if t < 0 else t + 1
    if own[i] >= 0:  # a source keeps tau_i^{(i)} = 0
        out[ob, oi, own[i]] = 0


@njit_cached(inline="always")
def average_row(tau, b, i, own, nbr, use, out, ob, oi):  # age of an average, eq. (6)
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


@njit_cached(inline="always")
def mix_row(Z, b, i, nbr, use, out, ob, oi):  # eq. (6)
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


@njit_cached(inline="always")
def gather_row(Z, b, src, sb, si, block_of, out, ob, oi):
    for c in range(Z.shape[2]):
        out[ob, oi, c] = Z[b, src[sb, si, block_of[c]], c]


@njit_cached(inline="always")
def propagate_rows(Z_sel, sb, Z, b, ADT, ALT, out, ob):
    """Every agent's row of eqs. (7), (10), (12) for one member (see
    :func:`netsense.kernels.update.propagate`): ``out[ob, i] = A_diag z_sel + A_lower z`` with
    ``z_sel = Z_sel[sb, i]``, ``z = Z[b, i]``, ``ADT = A_diag^T``, ``ALT = A_lower^T``,
    each row in the fixed order of :func:`netsense.kernels.lanes.block_triangular_row`. The
    agents go two at a time (:func:`netsense.kernels.lanes.block_triangular_pair`, the same
    bits), whose independent chains of adds overlap."""
    N = Z.shape[1]
    for i in range(0, N - 1, 2):
        block_triangular_pair(out, ob, i, Z_sel, sb, i, ADT, Z, b, i, ALT)
    if N % 2:
        block_triangular_row(out, ob, N - 1, Z_sel, sb, N - 1, ADT, Z, b, N - 1, ALT)


@njit_cached(inline="always")
def innovation_row(Z, b, i, y, arrived, C, L, lb, lo, hi, innov, out, ob, oi):  # eq. (7)
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


@njit_cached(inline="always")
def vecmat_row(x, b, M, out, ob):  # out[ob] = x[b] @ M (eqs. (1), (2))
    """``out[ob] = x[b] @ M``: every column from ``0.0``, ``+ x[b, q] * M[q, c]`` for ``q``
    ascending (in lanes, :func:`netsense.kernels.lanes.row_times_matrix`; C-contiguous 2-d
    float64 arrays)."""
    row_times_matrix(out, ob, x, b, M)


@njit_cached(inline="always")
def check_row(act, b, i, msg, own, okt, ch, sb, si, masked, first):
    """Validate agent ``i``'s actions (see :func:`netsense.kernels.update.check_actions`);
    ``okt`` is a scratch of ``D + 2`` with ``okt[0] = okt[D + 1] = True``."""
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


@njit_cached(inline="always")
def message_row(nbr, b, i, transmit, link, lb, lp, has_link, out, ob, oi):
    """Slot ``d`` of agent ``i`` holds a message: its neighbour ``l = nbr[b, i, d] >= 0``
    transmitted (``transmit[b, l]``) and the link ``l -> i`` delivered
    (``link[lb, lp, i, l]``, when ``has_link``: member ``lb``'s link draws at chunk
    position ``lp``)."""
    for d in range(nbr.shape[2]):
        v = nbr[b, i, d]
        ok = v >= 0
        if ok:
            ok = transmit[b, v]
            if ok and has_link:
                ok = link[lb, lp, i, v]
        out[ob, oi, d] = ok


@njit_cached(inline="always")
def freshness_row(keys, kb, out, ob, oi):  # eqs. (8)-(13)
    """The freshness choice of one agent: ``out[ob, oi, j]`` is the slot to adopt
    substate ``j`` from, ``-1`` to keep the own estimate.

    ``keys[kb, 0, j]`` is the agent's own index ``tau_i^{(j)}`` and ``keys[kb, 1 + d, j]``
    the index its slot ``d`` offers, as float64 with ``+inf`` for omega and for a slot that
    holds no message (so such slots never win: the set ``M_i^{(j)}[k]`` of eq. (8)). The
    slot with the smallest key is adopted iff that key is strictly smaller than the own
    key (eq. (13); an own omega is beaten by any finite index, Case 1); among equal keys
    the first slot wins (slots are in ascending node order: smallest node id). Callers
    fill ``keys`` from the indices (:func:`netsense.kernels.update.freshness_choice`) or from an
    observation (:class:`netsense.env.policies.FreshnessPolicy`).
    """
    for j in range(keys.shape[2]):
        best = -1
        bk = keys[kb, 0, j]
        for d in range(keys.shape[1] - 1):
            v = keys[kb, 1 + d, j]
            if v < bk:  # strictly: the first of equal keys stays, ties to the own index keep
                best, bk = d, v
        out[ob, oi, j] = best
