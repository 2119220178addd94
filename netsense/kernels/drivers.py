"""Batched drivers: compiled loops over members and agents that call :mod:`netsense.kernels.rules`.

Every driver is a :class:`netsense.kernels.jit.Driver` (a serial and a threaded build of one
source, without reference counting); its caller (the wrappers in :mod:`netsense.kernels.update`
and :mod:`netsense.engine.observation`, or :class:`netsense.engine.core.BatchedCore`) allocates the
outputs and scratch rows and picks the build with ``Driver.at(work, runs=B)``. ``apply_all`` is
the environment's update in one pass (plant, validation, indices, estimates, errors; see
:func:`netsense.kernels.update.apply_actions`); ``load_all`` loads a step's slots, outputs and
messages. The rest of a step is :func:`netsense.engine.rewards.finish_step` and
:func:`netsense.engine.observation.fill`.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from netsense.kernels.jit import Driver, njit_cached
from netsense.kernels.lanes import square_sums
from netsense.kernels.rules import (
    advance_row,
    average_row,
    check_row,
    freshness_row,
    gather_row,
    innovation_row,
    message_row,
    mix_row,
    propagate_rows,
    vecmat_row,
)


def advance_all(tau, own, src, out):
    for b in prange(tau.shape[0]):
        for i in range(tau.shape[1]):
            advance_row(tau, b, i, own, src, b, i, out, b, i)


def average_all(tau, own, nbr, use, out):
    for b in prange(tau.shape[0]):
        for i in range(tau.shape[1]):
            average_row(tau, b, i, own, nbr, use, out, b, i)


def gather_all(Z, src, block_of, out):
    for b in prange(Z.shape[0]):
        for i in range(Z.shape[1]):
            gather_row(Z, b, src, b, i, block_of, out, b, i)


def mix_all(Z, nbr, use, out):
    for b in prange(Z.shape[0]):
        for i in range(Z.shape[1]):
            mix_row(Z, b, i, nbr, use, out, b, i)


def propagate_all(Z_sel, Z, ADT, ALT, out):
    for b in prange(Z.shape[0]):
        propagate_rows(Z_sel, b, Z, b, ADT, ALT, out, b)


def innovation_all(Z, y, arrived, C, L, rows, out, scratch):
    per_member = L.shape[0] > 1
    for b in prange(Z.shape[0]):
        innov = scratch[b]
        lb = np.int64(b) if per_member else np.int64(0)  # (prange indices are unsigned)
        for i in range(Z.shape[1]):
            innovation_row(Z, b, i, y, arrived, C, L, lb, rows[i, 0], rows[i, 1], innov,
                            out, b, i)


def vecmat_all(x, M, out):
    for b in prange(x.shape[0]):
        vecmat_row(x, b, M, out, b)


def messages_all(nbr, transmit, link, has_link, out):
    for b in prange(nbr.shape[0]):
        for i in range(nbr.shape[1]):
            message_row(nbr, b, i, transmit, link, b, 0, has_link, out, b, i)


def load_all(buf_nbr, ptr, x, C_T, has_v, buf_v, transmit, has_link, buf_msg, nbr, y, msg):
    """The environment's step ``k`` from its pre-drawn chunk, member ``b`` at position
    ``ptr[b]``: the slot table ``nbr`` (widened to int64), the outputs ``y = C x (+ v)``
    (eq. (2); ``y`` and ``buf_v`` flat over ``(N, r)``) and the message table ``msg``."""
    N, D = nbr.shape[1], nbr.shape[2]
    for b in prange(nbr.shape[0]):
        p = ptr[b]
        for i in range(N):
            for d in range(D):
                nbr[b, i, d] = buf_nbr[b, p, i, d]
        vecmat_row(x, b, C_T, y, b)
        if has_v:
            for c in range(y.shape[1]):
                y[b, c] += buf_v[b, p, c]
        for i in range(N):
            message_row(nbr, b, i, transmit, buf_msg, b, p, has_link, msg, b, i)


def freshness_all(tau, nbr, use, keys, slot, src):
    """:func:`netsense.kernels.rules.freshness_row` on the indices: ``use (B, N, D, S)`` the
    usable slots (``S = 1``) or usable (slot, substate) pairs (``S = M``: per-substate
    messages, a substate the neighbour did not send is not offered); writes the chosen
    slot (``-1``: keep) and the agent adopted from (``i`` itself)."""
    B, N, M = tau.shape
    D = nbr.shape[2]
    per_sub = use.shape[3] > 1
    for b in prange(B):
        for i in range(N):
            for j in range(M):
                t = tau[b, i, j]
                keys[b, 0, j] = np.inf if t < 0 else np.float64(t)
            for d in range(D):
                l = nbr[b, i, d]
                for j in range(M):
                    ok = use[b, i, d, j if per_sub else 0]
                    t = tau[b, l, j] if ok else -1
                    keys[b, 1 + d, j] = np.inf if t < 0 else np.float64(t)
            freshness_row(keys, b, slot, b, i)
            for j in range(M):
                d = slot[b, i, j]
                src[b, i, j] = nbr[b, i, d] if d >= 0 else i


def freshness_obs_all(obs, o_om, o_age, o_sarr, o_som, o_sage, keys, act):
    """:func:`netsense.kernels.rules.freshness_row` on observations (the layout's field offsets):
    an index is omega when its flag is set (> 0.5), a slot usable when its message
    arrived; ``act[b, i, j]`` = chosen slot + 1 (0 = keep), then the transmit bit 1."""
    B, N = obs.shape[0], obs.shape[1]
    D, M = keys.shape[1] - 1, keys.shape[2]
    for b in prange(B):
        for i in range(N):
            for j in range(M):
                keys[b, 0, j] = np.inf if obs[b, i, o_om + j] > 0.5 else obs[b, i, o_age + j]
            for d in range(D):
                got = obs[b, i, o_sarr + d] > 0.5
                for j in range(M):
                    e = d * M + j
                    keys[b, 1 + d, j] = (obs[b, i, o_sage + e]
                                         if got and not obs[b, i, o_som + e] > 0.5 else np.inf)
            freshness_row(keys, b, act, b, i)
            for j in range(M):
                act[b, i, j] += 1
            act[b, i, M] = 1


@njit_cached(inline="always")
def _start_member(first, b, okb):
    """A member's validation records: none found yet (``first[b] = -1``); keep and
    average always allowed (``okb[0] = okb[D + 1] = True``, see ``check_row``). Set by
    the member's own thread, so the buffers need no initialisation by the caller."""
    for c in range(first.shape[1]):
        first[b, c] = -1
    okb[0] = True
    okb[okb.shape[0] - 1] = True


def check_actions(act, msg, own, choice, masked, first, okt):
    B, N, D = msg.shape
    for b in prange(B):
        okb = okt[b]
        _start_member(first, b, okb)
        for i in range(N):
            check_row(act, b, i, msg, own, okb, choice, b, i, masked, first)


def apply_all(Z, tau, own, act, nbr, msg, block_of, ADT, ALT, corr, fused, y,
               arrived, C, L, rows, x, A_T, w, W_T, has_w, TT, Z_next, tau_next, err,
               x_next, masked, first, ch, src, zsel, mix, avg_tau, ext, okt, cor, innov, zt,
               wt):
    B, N, n = Z.shape
    D = nbr.shape[2]
    M = tau.shape[2]
    per_member = L.shape[0] > 1
    # scratch rows (from the wrapper): row b belongs to the thread that runs member b,
    # addressed as [b, 0, :] by the row functions (zsel: [b, i, :], one row per agent)
    for b in prange(B):
        okb, inb = okt[b], innov[b]  # one view per member, not per row
        _start_member(first, b, okb)
        lb = np.int64(b) if per_member else np.int64(0)  # (prange indices are unsigned)
        # the plant, eq. (1), and the true state in Lemma 1 coordinates
        vecmat_row(x, b, A_T, x_next, b)
        if has_w:
            vecmat_row(w, b, W_T, wt, b)
            for c in range(x.shape[1]):
                x_next[b, c] += wt[b, c]
        vecmat_row(x_next, b, TT, zt, b)
        for i in range(N):
            check_row(act, b, i, msg, own, okb, ch, b, 0, masked, first)
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
            advance_row(tau, b, i, own, src, b, 0, tau_next, b, i)
            gather_row(Z, b, src, b, 0, block_of, zsel, b, i)
            if averaged:
                average_row(tau, b, i, own, nbr, msg, avg_tau, b, 0)
                mix_row(Z, b, i, nbr, msg, mix, b, 0)
                for j in range(M):
                    if ch[b, 0, j] == D + 1:
                        tau_next[b, i, j] = avg_tau[b, 0, j]
                for c in range(n):
                    if ch[b, 0, block_of[c]] == D + 1:
                        zsel[b, i, c] = mix[b, 0, c]
        # the propagation of every agent after the gathers, two rows at a time (their
        # chains of 2n adds per column overlap)
        propagate_rows(zsel, b, Z, b, ADT, ALT, Z_next, b)
        for i in range(N):
            if fused:  # the fixed-gain source update, eq. (7)
                innovation_row(Z, b, i, y, arrived, C, L, lb, rows[i, 0], rows[i, 1], inb,
                                cor, b, 0)
            else:
                for c in range(n):
                    cor[b, 0, c] = corr[b, i, c]
            for c in range(n):
                Z_next[b, i, c] += cor[b, 0, c]
        # errors ||z_hat_i - z||, each summed over c ascending (the agents' sums are
        # independent chains)
        square_sums(err, b, Z_next, b, zt, b)
        for i in range(N):
            err[b, i] = np.sqrt(err[b, i])


for _name in ("advance_all", "average_all", "gather_all", "mix_all", "propagate_all",
              "innovation_all", "vecmat_all", "messages_all", "load_all",
              "check_actions", "apply_all", "freshness_all", "freshness_obs_all"):
    globals()[_name] = Driver(globals()[_name])
del _name
