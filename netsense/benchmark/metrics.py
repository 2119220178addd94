"""Per-episode metrics of the benchmark (the table of :mod:`netsense.benchmark`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from netsense.benchmark.records import EpisodeRecord

METRICS = ("mean_rel_error", "final_rel_error", "steps_to_eps", "msgs_per_agent_step",
           "aoi_mean", "aoi_max", "aoi_omega_frac", "reward")





def steps_to_epsilon(rel: np.ndarray, eps: float) -> float:
    """First ``k`` from which ``max_i rel[k', i] <= eps`` for all ``k' >= k``.

    Parameters
    ----------
    rel : (K + 1, N) array
        Relative errors; non-finite entries count as above ``eps``.
    eps : float
        Threshold, > 0.

    Returns
    -------
    float
        The step (as a float) or NaN when the last step is still above ``eps``.
    """
    if eps <= 0:
        raise ValueError(f"eps must be > 0, got {eps}")
    worst = np.max(np.where(np.isfinite(rel), rel, np.inf), axis=1)
    above = np.nonzero(~(worst <= eps))[0]
    if above.size == 0:
        return 0.0
    if above[-1] == worst.shape[0] - 1:
        return float("nan")
    return float(above[-1] + 1)


def aoi_statistics(aoi: np.ndarray | None, own: np.ndarray | None = None
                   ) -> dict[str, float]:
    """Age-of-information statistics of ``tau`` (``(K + 1, N, M)``, ``-1`` = omega).

    Only the entries of other agents' substates count (a source's own index is always
    0). Returns ``aoi_mean``, ``aoi_max`` over finite entries and ``aoi_omega_frac``; NaN
    when ``aoi`` is None or no entry counts (a single agent).

    Parameters
    ----------
    aoi : (K + 1, N, M) int array or None
    own : (N,) int array, optional
        Column of agent ``i``'s own substate (``-1``: none); default the diagonal, which
        needs ``M = N``.
    """
    nan = {"aoi_mean": float("nan"), "aoi_max": float("nan"), "aoi_omega_frac": float("nan")}
    if aoi is None:
        return nan
    aoi = np.asarray(aoi)
    if aoi.ndim != 3:
        raise ValueError(f"aoi must have shape (K+1, N, M), got {aoi.shape}")
    N, M = aoi.shape[1:]
    if own is None:
        if M != N:
            raise ValueError(f"aoi of shape {aoi.shape} has M != N columns: pass own")
        own = np.arange(N)
    own = np.asarray(own, dtype=np.int64)
    if own.shape != (N,) or own.max(initial=-1) >= M or own.min(initial=-1) < -1:
        raise ValueError(f"own must hold N = {N} columns in -1..{M - 1}, got {own.tolist()}")
    others = np.ones((N, M), dtype=bool)
    has = own >= 0
    others[np.flatnonzero(has), own[has]] = False
    if not others.any():
        return nan
    off = aoi[:, others]
    finite = off[off >= 0]
    return {
        "aoi_mean": float(finite.mean()) if finite.size else float("nan"),
        "aoi_max": float(finite.max()) if finite.size else float("nan"),
        "aoi_omega_frac": float(np.mean(off < 0)),
    }


def episode_metrics(rec: EpisodeRecord, eps: float = 1e-2) -> dict[str, float]:
    """Reduce one :class:`EpisodeRecord` to the metrics listed in the module docstring."""
    rel = rec.relative_errors()
    K = rel.shape[0] - 1
    if K < 1:
        raise ValueError("an episode needs at least one step")
    out = {
        "mean_rel_error": float(np.mean(rel[1:])),
        "final_rel_error": float(np.mean(rel[-1])),
        "steps_to_eps": steps_to_epsilon(rel, eps),
        "msgs_per_agent_step": (float(np.mean(rec.messages)) if rec.messages is not None
                                else float("nan")),
        "reward": (float(np.mean(np.sum(rec.rewards, axis=0))) if rec.rewards is not None
                   else float("nan")),
    }
    out.update(aoi_statistics(rec.aoi, rec.own))
    return {m: out[m] for m in METRICS}
