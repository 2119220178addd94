"""The suite's statistics, on arrays of per-episode returns: rliable's IQM with stratified
bootstrap intervals, probability of improvement, normalised scores, performance profiles.

Every interval is rliable's percentile stratified bootstrap
(``rliable.library.get_interval_estimates``, :data:`REPS` resamples, 95 %) drawn with
NumPy's global generator seeded with 0 (:func:`netsense.benchmark.intervals.seeded_global_rng`),
so the same values always give the same interval. A *run* is one (training seed, episode)
pair: a learner's returns over seeds ``S`` and episodes ``E`` are ``S x E`` runs of one
task (the IQM over seeds x episodes); the aggregate stratifies the runs by task.

Needs the ``analysis`` extra (``rliable``).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping

import numpy as np

__all__ = ["CONFIDENCE", "REPS", "aggregate_iqm", "iqm", "iqm_interval", "normalise",
           "performance_profile", "probability_of_improvement"]

#: Bootstrap resamples of every interval.
REPS = 2000
CONFIDENCE = 0.95


def iqm(values) -> float:
    """Interquartile mean (rliable's ``aggregate_iqm``: the mean of the middle 50 % of the
    values, ``scipy.stats.trim_mean(values, 0.25)`` over all entries)."""
    from rliable import metrics

    v = np.asarray(values, dtype=float)
    if v.size == 0:
        raise ValueError("iqm of no values")
    return float(metrics.aggregate_iqm(v.reshape(-1, 1) if v.ndim == 1 else v))


def _matrix(values, what: str) -> np.ndarray:
    m = np.asarray(values, dtype=float)
    if m.ndim == 1:
        m = m[:, None]
    if m.ndim != 2 or m.size == 0:
        raise ValueError(f"{what} must be a non-empty (runs,) or (runs, tasks) array, got "
                         f"shape {m.shape}")
    if not np.isfinite(m).all():
        raise ValueError(f"{what} holds non-finite values")
    return m


def iqm_interval(values, reps: int = REPS, seed: int = 0) -> tuple[float, float, float]:
    """IQM of ``values`` with its 95 % stratified bootstrap interval.

    Parameters
    ----------
    values : (runs,) or (runs, tasks) array
        One task's returns over seeds x episodes (flattened), or a matrix whose columns
        are tasks (runs resampled within each task).
    reps : int
        Bootstrap resamples.
    seed : int
        Seed of the global generator rliable draws from.

    Returns
    -------
    (iqm, low, high)
    """
    from rliable import library as rly
    from rliable import metrics

    from netsense.benchmark.intervals import seeded_global_rng

    m = _matrix(values, "values")
    with seeded_global_rng(seed), warnings.catch_warnings():
        # arch (rliable's bootstrap) warns that its random_state argument is deprecated
        warnings.simplefilter("ignore", FutureWarning)
        point, ci = rly.get_interval_estimates(
            {"x": m}, lambda s: np.array([metrics.aggregate_iqm(s)]), reps=int(reps),
            confidence_interval_size=CONFIDENCE, random_state=np.random.RandomState(seed))
    return float(point["x"][0]), float(ci["x"][0, 0]), float(ci["x"][1, 0])


def aggregate_iqm(scores: Mapping[str, np.ndarray], reps: int = REPS,
                  seed: int = 0) -> dict[str, tuple[float, float, float]]:
    """:func:`iqm_interval` of every ``(runs, tasks)`` matrix of ``scores``."""
    return {k: iqm_interval(v, reps, seed) for k, v in scores.items()}


def probability_of_improvement(x, y) -> float:
    """``P(X > Y) + P(X = Y) / 2`` for a return ``X`` of ``x`` and ``Y`` of ``y``, over all
    pairs (rliable's ``probability_of_improvement``, the Mann-Whitney U statistic over
    ``len(x) len(y)``); 0.5 for equal samples."""
    from rliable import metrics

    a, b = _matrix(x, "x")[:, :1], _matrix(y, "y")[:, :1]
    if np.ndim(x) != 1 or np.ndim(y) != 1:
        raise ValueError("x and y must be 1-d arrays of returns")
    return float(metrics.probability_of_improvement(a, b))


def normalise(returns, never, bound) -> np.ndarray:
    """Normalised scores ``(R - R_never) / (UB - R_never)`` per episode.

    ``returns`` ``(..., E)`` and ``never``, ``bound`` ``(E,)``: the same episodes in the
    same order. An episode on which the bound equals ``never``'s return (nothing to gain)
    has no score: NaN.

    Raises
    ------
    ValueError
        Shapes that do not match, or a bound below ``never``'s return.
    """
    r = np.asarray(returns, dtype=float)
    n, ub = np.asarray(never, dtype=float), np.asarray(bound, dtype=float)
    if n.ndim != 1 or ub.shape != n.shape or r.shape[-1:] != n.shape:
        raise ValueError(f"returns (..., E) and never, bound (E,) must share E; got "
                         f"{r.shape}, {n.shape}, {ub.shape}")
    gap = ub - n
    if (gap < 0).any():
        raise ValueError(f"the bound is below never's return on episode "
                         f"{int(np.argmax(gap < 0))}")
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(gap > 0, (r - n) / np.where(gap > 0, gap, 1.0), np.nan)


def performance_profile(scores: Mapping[str, np.ndarray], taus,
                        reps: int = REPS, seed: int = 0) -> tuple[dict, dict]:
    """rliable's performance profiles (the fraction of runs with a normalised score above
    each ``tau``) with their stratified bootstrap intervals: ``(profiles, intervals)``."""
    from rliable import library as rly

    from netsense.benchmark.intervals import seeded_global_rng

    mats = {k: _matrix(v, k) for k, v in scores.items()}
    with seeded_global_rng(seed):
        return rly.create_performance_profile(mats, np.asarray(taus, dtype=float),
                                              reps=int(reps))
