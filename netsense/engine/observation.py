"""Observations and action masks of the environment, written in one pass (numba).

The layout of the flat per-agent vector is :class:`netsense.engine.model.ObsLayout` (and the
table in :mod:`netsense.env.pettingzoo_env`). :func:`fill`
writes the observations of every member and
agent of a :class:`~netsense.engine.core.BatchedCore` and their action masks straight into
their output arrays, with no temporaries of size ``obs_dim``: at ``B = 1024``,
``N = 30`` the observation is ~33 MB per step, so the number of passes over it is what
costs. :func:`netsense.kernels.slot_messages` is the message table as a public function (the
core builds it in :func:`netsense.kernels.drivers.load_all`, from the same row rule).

Values (per agent ``i`` of member ``b``; ``H`` the horizon):

* ``time = k / H``; ``y = symlog(y_i)`` (0 when the measurement did not arrive),
  ``y_arrived``;
* ``own_omega[j] = [tau_i^{(j)} = omega]``, ``own_age[j] = max(tau_i^{(j)}, 0) / H``
  (computed in float32; exact below ``2^24``, see :func:`fill`);
* ``z_dir = z_hat_i / ||z_hat_i||`` (0 for a zero estimate), ``z_lognorm =
  log(1 + ||z_hat_i||)``;
* per slot ``d``: ``slot_arrived``, ``slot_id = (l + 1) / N`` (0 for an empty slot), and
  the neighbour's ``omega`` and ``age`` rows (``1`` and ``0`` when no message arrived);
* a non-finite ``y`` or estimate (numerical blow-up) is written as 0 (nan) or
  ``+-1e3`` (inf); every other field is bounded by construction.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from netsense.kernels.jit import Driver, njit_cached
from netsense.kernels.lanes import copy_span, square_sums

__all__ = ["MASK_TABLE_BYTES", "FillBuffers", "fill"]




#: Largest table of mask rows (:class:`FillBuffers`) kept, in bytes.
MASK_TABLE_BYTES = 128 * 2**10


class FillBuffers:
    """Scratch rows of :func:`fill` for ``B`` members of ``N`` agents, ``M`` substates and
    mask rows of ``mask_size``, kept by a caller that fills at every step (``fill(...,
    work=buffers)``; the reason is that of :class:`netsense.kernels.update.StepBuffers`).

    With ``D`` slots, an agent's mask row depends only on its own substate and on which
    of its ``D`` slots hold a message: when the ``N x 2^D`` possible rows take at most
    :data:`MASK_TABLE_BYTES`, they are kept here (built by the mask rule itself, once per
    ``own``) and the pass copies each agent's row from the table instead of clearing
    slots one by one (a branch per slot, mispredicted about half the time under link
    drops: 0.41 -> 0.36 ms for the pass at ``(1024, 10, 10)``, one thread).
    """

    def __init__(self, B: int, N: int, M: int, mask_size: int) -> None:
        self.key = (B, N, M, mask_size)
        self.om = np.empty((B, N + 1, M), np.float32)  # each member's (omega, age) rows
        self.age = np.empty((B, N + 1, M), np.float32)
        self.own_rows = np.empty((N, mask_size), np.int8)
        self.zz = np.empty((B, N))  # squared norms of the estimates
        D = (mask_size - 2) // max(M, 1) - 2
        small = 0 <= D <= 16 and N * mask_size << D <= MASK_TABLE_BYTES
        self.mask_table = np.empty((N if small else 0, 1 << D if small else 1, mask_size),
                                   np.int8)
        self.slots = np.empty(max(D, 0), np.bool_)  # one pattern's slots (table building)
        self.table_own: np.ndarray | None = None  # the own columns the table was built for


def fill(obs: np.ndarray, mask: np.ndarray, starts: np.ndarray, k: np.ndarray,
         horizon: float, y: np.ndarray, y_arrived: np.ndarray, tau: np.ndarray,
         Z: np.ndarray, nbr: np.ndarray, msg: np.ndarray, exact_f32: bool, *,
         observations: bool = True, masks: bool = True,
         own: np.ndarray | None = None, work: FillBuffers | None = None) -> None:
    """Write observations ``obs (B, N, size)`` float32 and masks ``mask (B, N, M)`` int8.

    ``starts`` holds the offsets of the layout's fields in the order of
    :meth:`netsense.engine.model.ObsLayout.table`. ``exact_f32`` (every index and the horizon
    below ``2^24``) selects float32 arithmetic for the ages, equal to the float64
    quotient rounded to float32 (both operands are exact in float32 and double rounding of
    a quotient through float64 is innocuous); otherwise the quotient is taken in float64.

    The mask block of substate ``j`` is ``[keep, slot 0 .. slot D-1, average]``: keep is
    always allowed, a slot only when its message arrived, average always, and an agent's
    own substate allows only keep; the last two entries (transmit 0/1) are 1.
    ``observations=False`` or ``masks=False`` skips that output (its array is not
    touched). ``own[i]``: column of agent ``i``'s own substate (``-1``: none; default
    ``i``), when the substates are the sources only (``tau (B, N, M)``). ``work``:
    :class:`FillBuffers` of this size for the scratch rows (default fresh ones).

    Internal to the engine: the outputs' shapes are checked, but not the index ranges of
    ``nbr``, ``own`` and ``starts`` (the core's own arrays; checking them would cost every
    step). Observations for users come from :meth:`netsense.engine.core.BatchedCore.observe`.
    """
    for name, a, dtype in (("obs", obs, np.float32), ("mask", mask, np.int8)):
        if a.dtype != dtype or a.ndim != 3 or not a.flags.c_contiguous:
            raise ValueError(f"{name} must be a C-contiguous 3-d {np.dtype(dtype).name} "
                             f"array (written in place), got {a.dtype} {a.shape}")
    if own is None:
        own = np.arange(Z.shape[1], dtype=np.int64)
    Z = np.ascontiguousarray(Z, dtype=float)  # (the norms' lanes read C rows)
    size = (obs.size if observations else 0) + (mask.size if masks else 0)
    B, N, M = tau.shape
    D = nbr.shape[2]
    # the pass writes rows without bounds checks: the outputs' shapes are checked here
    if observations and (obs.shape[:2] != (B, N) or obs.shape[2] < int(starts[10]) + D * M):
        raise ValueError(f"obs must have shape (B, N, >= {int(starts[10]) + D * M}) with "
                         f"(B, N) = {(B, N)}, got {obs.shape}")
    if masks and mask.shape != (B, N, M * (D + 2) + 2):
        raise ValueError(f"mask must have shape {(B, N, M * (D + 2) + 2)}, got {mask.shape}")
    if work is None:
        work = FillBuffers(B, N, M, mask.shape[2])  # (np.empty: unused rows cost nothing)
    elif work.key[:3] != (B, N, M) or (masks and work.key[3] != mask.shape[2]):
        raise ValueError(f"work holds buffers for (B, N, M, mask size) = {work.key}, this "
                         f"call needs {(B, N, M, mask.shape[2])}")
    own = np.asarray(own, dtype=np.int64)
    if masks and work.mask_table.shape[0] and not (
            work.table_own is not None and np.array_equal(work.table_own, own)):
        _mask_table(work.mask_table, own, M, D, work.slots)
        work.table_own = own.copy()
    _fill.at(size, runs=B)(obs, mask, starts, k, float(horizon), y, y_arrived, tau, Z, nbr, msg,
                   bool(exact_f32), bool(observations), bool(masks), own, work.om,
                   work.age, work.own_rows, work.zz, work.mask_table)


@njit_cached(inline="always")
def _log1p(x):
    """``log(1 + x)`` for ``x >= 0`` (nan and inf pass through), within a few float64 ulps.

    ``log(u) * (x / (u - 1))`` with ``u = 1 + x`` rounded (Goldberg, "What every computer
    scientist should know about floating-point arithmetic", 1991, Thm. 4): the rounding
    of ``u`` cancels in the quotient, so small ``x`` keeps full relative accuracy. Half
    the cost of libm's ``log1p`` here (measured 16 % of this pass at N = n = 10); the
    float32 observation is the float32 rounding of ``log1p`` except when ``log1p`` lies
    within a few float64 ulps of a float32 rounding boundary.
    """
    u = 1.0 + x
    if u == 1.0 or u == np.inf:  # x below half an ulp of 1 (log1p(x) = x), or inf
        return x
    return np.log(u) * (x / (u - 1.0))


@njit_cached(inline="always")
def _finite_or_repair(v):
    if np.isnan(v):
        return 0.0
    if np.isinf(v):
        return 1e3 if v > 0 else -1e3
    return v


def _fill(obs, mask, starts, k, H, y, y_arrived, tau, Z, nbr, msg, exact_f32, do_obs, do_mask,
          own, om_all, age_all, own_rows, zz_all, mask_table):
    B, N, n = Z.shape
    r = y.shape[2]
    D = nbr.shape[2]
    M = tau.shape[2]
    (o_time, o_y, o_yarr, o_om, o_age, o_zdir, o_zlog, o_sarr, o_sid, o_som,
     o_sage) = (starts[0], starts[1], starts[2], starts[3], starts[4], starts[5],
                starts[6], starts[7], starts[8], starts[9], starts[10])
    by_table = mask_table.shape[0] == N  # every (agent, slot pattern) row built ahead
    if do_mask and not by_table:  # each agent's row when every message arrives
        for i in range(N):
            _own_row(own_rows[i], own[i], D)
    S, W = own_rows.size, own_rows.shape[1]
    P = mask_table.shape[1]
    for b in prange(B):
        if do_mask and by_table:  # each agent's row by the pattern of its slots
            for i in range(N):
                pattern = 0
                for d in range(D):
                    pattern |= np.int64(msg[b, i, d]) << d
                copy_span(mask, (b * N + i) * W, mask_table, (i * P + pattern) * W, W)
        elif do_mask:  # the member's N rows at once, then clear the slots without a message
            copy_span(mask, b * S, own_rows, 0, S)
            for i in range(N):
                _clear_slots(mask[b, i], msg[b, i], M, D)
        if not do_obs:
            continue
        # every agent's (omega, age) row once per member; own and slot fields copy rows
        om_tab, age_tab = om_all[b], age_all[b]  # (N + 1, M) scratch of this member
        _index_tables(tau[b], H, exact_f32, om_tab, age_tab)
        t_b = np.float32(k[b] / H)
        square_sums(zz_all, b, Z, b, None, 0)  # squared norms, summed over c ascending
        zz_b = zz_all[b]
        for i in range(N):
            o = obs[b, i]
            o[o_time] = t_b
            arr = y_arrived[b, i]
            for q in range(r):
                v = y[b, i, q] if arr else 0.0
                o[o_y + q] = _finite_or_repair(np.sign(v) * _log1p(np.abs(v)))
            o[o_yarr] = 1.0 if arr else 0.0
            copy_span(o, o_om, om_tab[i], 0, M)
            copy_span(o, o_age, age_tab[i], 0, M)
            z = Z[b, i]
            norm = np.sqrt(zz_b[i])
            den = norm if norm > 0 else 1.0
            if np.isfinite(norm):  # then every entry is finite: no repair needed
                inv = 1.0 / den  # one division per agent (float32 output: same values
                for c in range(n):  # as z / den up to one float64 ulp)
                    o[o_zdir + c] = z[c] * inv
                o[o_zlog] = _log1p(norm)
            else:
                for c in range(n):
                    o[o_zdir + c] = _finite_or_repair(z[c] / den)
                o[o_zlog] = _finite_or_repair(_log1p(norm))
            for d in range(D):
                got = msg[b, i, d]
                l = nbr[b, i, d]
                o[o_sarr + d] = 1.0 if got else 0.0
                o[o_sid + d] = np.float32((l + 1) / N) if l >= 0 else 0.0
                row = l if got else N  # row N: no message (omega 1, age 0)
                copy_span(o, o_som + d * M, om_tab[row], 0, M)
                copy_span(o, o_sage + d * M, age_tab[row], 0, M)


@njit_cached(inline="always")
def _index_tables(tau_b, H, exact_f32, om_tab, age_tab):
    N, M = tau_b.shape
    H32 = np.float32(H)
    for l in range(N):
        for j in range(M):
            t = tau_b[l, j]
            om_tab[l, j] = np.float32(1.0) if t < 0 else np.float32(0.0)
            tt = t if t > 0 else 0
            if exact_f32:
                age_tab[l, j] = np.float32(tt) / H32
            else:
                age_tab[l, j] = np.float32(tt / H)
    for j in range(M):
        om_tab[N, j] = 1.0
        age_tab[N, j] = 0.0


@njit_cached(inline="always")
def _own_row(m, o, D):
    W = D + 2
    for t in range(m.shape[0]):  # everything allowed, then clear what is not
        m[t] = 1
    if o >= 0:  # the own substate allows only keep
        for w in range(1, W):
            m[o * W + w] = 0


@njit_cached(inline="always")
def _clear_slots(m, msg_row, M, D):
    W = D + 2
    for d in range(D):
        if not msg_row[d]:  # a slot without a message cannot be adopted
            for j in range(M):
                m[j * W + 1 + d] = 0


@njit_cached(_nrt=False)
def _mask_table(table, own, M, D, slots):
    """``table[i, p]``: agent ``i``'s mask row when slot ``d`` holds a message iff bit
    ``d`` of ``p`` is set (the rule of :func:`_own_row` and :func:`_clear_slots`)."""
    for i in range(table.shape[0]):
        for p in range(table.shape[1]):
            _own_row(table[i, p], own[i], D)
            for d in range(D):
                slots[d] = (p >> d) & 1 == 1
            _clear_slots(table[i, p], slots, M, D)


_fill = Driver(_fill)
