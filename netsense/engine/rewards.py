"""Rewards, transmissions, termination and truncation of one environment step (numba).

:func:`finish_step` is the tail of :meth:`netsense.engine.core.BatchedCore.step`: one compiled
pass over the members instead of a dozen numpy passes over ``(B, N)`` arrays (at
``B = 1024``, ``N = 10`` those cost about 5 % of a step). The reward is the one of
:class:`netsense.engine.model.RewardConfig`:

.. math:: r_i = -w_e \\big((1 - w_t) e_i + w_t \\bar e\\big) - c\\, t_i, \\qquad
          e_i = \\min\\Big(\\frac{\\|\\hat z_i[k+1] - z[k+1]\\|}{\\max(\\|x[k+1]\\|, f)},
          e_{\\max}\\Big),

with ``\\bar e`` the mean of ``e_i`` over the agents that count (``alive``); agents that do
not count get ``r_i = -c t_i``. A non-finite error (the estimates blew up) is clipped to
``e_max``; a member terminates when an agent that counts has a raw normalised error above
the divergence limit or not a number.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import prange

from netsense.engine.model import RewardConfig
from netsense.kernels.jit import Driver

__all__ = ["StepTail", "finish_step"]


class StepTail(NamedTuple):
    """What :func:`finish_step` returns (leading batch axis everywhere)."""

    reward: np.ndarray  #: (B, N) float64
    raw_errors: np.ndarray  #: (B, N) normalised errors before clipping
    errors: np.ndarray  #: (B, N) normalised errors clipped at ``error_clip``
    transmit: np.ndarray  #: (B, N) bool, transmit flags of the next step
    terminated: np.ndarray  #: (B,) bool
    truncated: np.ndarray  #: (B,) bool


def finish_step(x: np.ndarray, err: np.ndarray, act: np.ndarray, M: int,
                silenced: np.ndarray | None, alive: np.ndarray, reward: RewardConfig,
                divergence_limit: float | None, k: np.ndarray, horizon: int,
                messages_sent: np.ndarray, out: StepTail | None = None) -> StepTail:
    """Rewards and episode flags after the step ``k - 1 -> k``.

    Parameters
    ----------
    x : (B, n)
        True state ``x[k]``.
    err : (B, N)
        ``||z_hat_i[k] - z[k]||`` (:func:`netsense.kernels.update.apply_actions`).
    act : (B, N, M + 1) int
        The validated actions; ``act[..., M]`` is the transmit bit for step ``k``.
    M : int
        Number of substates (the transmit bit's column).
    silenced : (B, N) bool or None
        Agents that cannot transmit at ``k`` (crashed).
    alive : (N,) bool
        Agents whose errors count (team mean, rewards, divergence).
    reward : RewardConfig
    divergence_limit : float or None
    k : (B,) int
        Time index after the step.
    horizon : int
    messages_sent : (B,) int
        Running count of transmissions, incremented in place.
    out : StepTail, optional
        Arrays to write the results into (C-contiguous, the shapes and dtypes of
        :class:`StepTail`); default fresh ones. The core passes its own buffers for
        ``raw_errors``, ``errors`` and ``transmit``.

    Raises
    ------
    ValueError
        If an array's shape does not match ``err``'s ``(B, N)`` (checked before anything
        is written).
    """
    if np.ndim(err) != 2:
        raise ValueError(f"err must have shape (B, N), got {np.shape(err)}")
    B, N = err.shape
    M = int(M)
    alive = np.asarray(alive, bool)
    _expect("x", x, (B, None))
    _expect("act", act, (B, N, None))
    if act.shape[2] <= M:
        raise ValueError(f"act must have more than M = {M} columns, got {act.shape}")
    _expect("alive", alive, (N,))
    _expect("k", k, (B,))
    _expect("messages_sent", messages_sent, (B,))
    if silenced is not None:
        _expect("silenced", silenced, (B, N))
    want = StepTail((B, N), (B, N), (B, N), (B, N), (B,), (B,))
    if out is None:
        out = StepTail(*(np.empty(s, bool if f in ("transmit", "terminated", "truncated")
                                  else float) for f, s in zip(StepTail._fields, want,
                                                              strict=True)))
    else:
        for f, a, s in zip(StepTail._fields, out, want, strict=True):
            kind = "b" if f in ("transmit", "terminated", "truncated") else "f"
            if (not isinstance(a, np.ndarray) or a.shape != s or a.dtype.kind != kind
                    or a.dtype.itemsize != (1 if kind == "b" else 8)
                    or not a.flags.c_contiguous):
                raise ValueError(f"out.{f} must be a C-contiguous "
                                 f"{'bool' if kind == 'b' else 'float64'} array of shape "
                                 f"{s}, got {getattr(a, 'dtype', type(a))} "
                                 f"{getattr(a, 'shape', '')}")
    has_sil = silenced is not None
    sil = np.asarray(silenced, bool) if has_sil else np.zeros((1, 1), bool)
    has_lim = divergence_limit is not None
    _finish.at(x.size + err.size * (5 + act.shape[2]), runs=x.shape[0])(  # elements r/w
        x, err, act, M, sil, has_sil, alive, float(reward.error_floor),
        float(reward.error_clip), float(reward.team_weight), float(reward.error_weight),
        float(reward.message_cost), float(divergence_limit) if has_lim else 0.0, has_lim,
        k, int(horizon), messages_sent, *out)
    return out


def _expect(name: str, a: np.ndarray, shape: tuple) -> None:
    """Raise unless ``a.shape`` matches ``shape`` (``None``: any length)."""
    if a.ndim != len(shape) or any(w is not None and s != w
                                   for s, w in zip(a.shape, shape, strict=True)):
        want = tuple("any" if w is None else w for w in shape)
        raise ValueError(f"{name} must have shape {want}, got {a.shape}")


def _finish(x, err, act, M, sil, has_sil, alive, floor, clip, team_w, err_w, cost, lim,
            has_lim, k, horizon, sent, reward, raw, errors, tx, terminated, truncated):
    B, N = err.shape
    n = x.shape[1]
    count = 0
    for i in range(N):
        count += alive[i]
    for b in prange(B):
        s = 0.0
        for c in range(n):
            s += x[b, c] * x[b, c]
        scale = np.sqrt(s)
        if not scale >= floor and not np.isnan(scale):  # max(||x||, f); nan stays nan
            scale = floor
        for i in range(N):  # (separate loops: the divisions and clips vectorise)
            raw[b, i] = err[b, i] / scale  # nan only if the estimates blew up (inf - inf)
        for i in range(N):
            v = raw[b, i]
            errors[b, i] = v if v <= clip else clip  # np.fmin(v, clip): nan -> clip
        total = 0.0
        diverged = False
        for i in range(N):
            if alive[i]:
                total += errors[b, i]
                diverged |= not raw[b, i] <= lim  # nan counts as diverged
        mean = total / count if count else 0.0
        sent_b = 0
        for i in range(N):
            t = act[b, i, M] != 0 and not (has_sil and sil[b, i])
            tx[b, i] = t
            sent_b += t
            if alive[i]:
                e = errors[b, i]
                r = -err_w * ((1 - team_w) * e + team_w * mean) if team_w else -err_w * e
            else:
                r = 0.0  # faulty agents' errors are not rewarded
            if cost:
                r -= cost * t
            reward[b, i] = r
        sent[b] += sent_b
        terminated[b] = has_lim and diverged
        truncated[b] = k[b] >= horizon and not terminated[b]


_finish = Driver(_finish)
