"""Age of information read off a freshness-index history.

The freshness index ``tau_i^{(j)}[k]`` *is* the age, at node ``i``, of its newest
information about substate ``j`` measured from that substate's source. From a history
``tau (K+1, B, N, N)``: :func:`trigger_step` (first step from which every index is finite;
Lemma 3 bounds it), :func:`worst_index` (largest index from a step on; Lemma 5 bounds it)
and :func:`aoi_stats` (time-average, average peak and maximum age).
"""

from __future__ import annotations

import warnings

import numpy as np

from netsense.kernels.rules import OMEGA

__all__ = ["aoi_stats", "trigger_step", "worst_index"]


# ----------------------------------------------------------------------------- measures
def trigger_step(tau: np.ndarray) -> np.ndarray:
    """First step from which every index is finite (triggered), per batch member.

    Parameters
    ----------
    tau : (K+1, B, N, N) int
        Index history (``Trajectory.tau``).

    Returns
    -------
    (B,) int
        The smallest ``k`` with ``tau_i^{(j)}[k'] != omega`` for all ``i, j`` and all
        ``k' >= k`` in the horizon; ``-1`` if some index is still omega at the end.
        Lemma 3: ``<= (N-1)T`` under Assumption 1.
    """
    done = (tau != OMEGA).all((-1, -2))  # (K+1, B)
    K1 = done.shape[0]
    # last step that is not done, per batch member
    not_done = ~done
    last_bad = np.where(not_done.any(0), K1 - 1 - np.argmax(not_done[::-1], axis=0), -1)
    return np.where(done[-1], last_bad + 1, -1)


def worst_index(tau: np.ndarray, start: np.ndarray | int) -> np.ndarray:
    """Largest freshness index over ``k >= start`` (per batch member), ``(B,)`` int.

    ``start`` may differ per batch member (e.g. :func:`trigger_step`); a negative start
    gives ``-1``. Lemma 5: ``<= 2(N-1)T`` for ``start >= (N-1)T``.
    """
    K1, B = tau.shape[:2]
    start = np.broadcast_to(np.asarray(start), (B,))
    per_step = tau.max((-1, -2))  # (K+1, B); omega (-1) never wins against 0
    mask = np.arange(K1)[:, None] >= start[None, :]
    out = np.where(mask, per_step, -1).max(0)
    return np.where((start >= 0) & (start < K1), out, -1)


def aoi_stats(tau: np.ndarray, start: int = 0) -> dict[str, np.ndarray]:
    """Age-of-information statistics of every index over ``k >= start``.

    The freshness index ``tau_i^{(j)}[k]`` is the age, at node ``i``, of its newest
    information about substate ``j`` (measured from the source ``j``). Steps where the
    index is still omega are excluded from the averages.

    Returns
    -------
    dict of (B, N, N) arrays
        ``mean`` -- time-average age; ``peak`` -- average peak age (the age just before
        each refresh, i.e. each step where the age does not grow by one; NaN if the index
        is never refreshed in the window); ``max`` -- largest age (``-1`` if always omega);
        ``omega_fraction`` -- fraction of the window spent at omega.
    """
    a = tau[start:].astype(float)
    a[tau[start:] == OMEGA] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(a, axis=0)
        refresh = a[1:] <= a[:-1]  # NaN comparisons are False
        peaks = np.where(refresh, a[:-1], np.nan)
        peak = np.nanmean(peaks, axis=0)
    return {"mean": mean, "peak": peak, "max": tau[start:].max(0).astype(float),
            "omega_fraction": np.isnan(a).mean(0)}
