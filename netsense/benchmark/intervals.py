"""Bootstrap intervals of the evaluation protocol: one mean, and a paired relative gap.

Every interval of :mod:`netsense.benchmark.protocol` and :mod:`netsense.benchmark.headroom`
is a 95 % percentile bootstrap interval from ``scipy.stats.bootstrap`` with
:data:`RESAMPLES` resamples and a generator seeded with 0, so the same values always give
the same interval. :func:`seeded_global_rng` does the same for rliable's stratified
bootstrap (the aggregates over training seeds of ``experiments/``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence

import numpy as np

__all__ = ["CONFIDENCE", "RESAMPLES", "bootstrap_ci", "paired_percent", "seeded_global_rng"]

CONFIDENCE = 0.95
RESAMPLES = 9999


def bootstrap_ci(values: Sequence[float], confidence: float = CONFIDENCE,
                 resamples: int = RESAMPLES, seed: int = 0) -> tuple[float, float, float]:
    """Mean and percentile-bootstrap confidence interval of ``values``.

    ``scipy.stats.bootstrap`` with ``resamples`` resamples from
    ``numpy.random.default_rng(seed)``. Non-finite values make all three NaN; a single
    value (or identical values) gives a zero-width interval. On per-seed differences of
    two runs over the same seeds this is the paired bootstrap of the mean difference.
    """
    from scipy import stats

    v = np.asarray(values, dtype=float).ravel()
    if v.size == 0 or not np.isfinite(v).all():
        return (float("nan"),) * 3
    mean = float(v.mean())
    if v.size == 1 or np.ptp(v) <= 1e-12 * max(abs(mean), 1e-300):
        return mean, mean, mean
    res = stats.bootstrap((v,), np.mean, confidence_level=confidence, n_resamples=resamples,
                          method="percentile", vectorized=True,
                          random_state=np.random.default_rng(seed))
    ci = res.confidence_interval
    return mean, float(ci.low), float(ci.high)


def paired_percent(values: Sequence[float], reference: Sequence[float], seed: int = 0
                   ) -> tuple[float, float, float]:
    """``100 mean(values - reference) / |mean(reference)|`` and its percentile bootstrap
    interval, resampling seeds with their pairs (``scipy.stats.bootstrap(...,
    paired=True)``)."""
    from scipy import stats

    a, b = np.asarray(values, float), np.asarray(reference, float)
    if a.shape != b.shape or a.ndim != 1 or a.size == 0:
        raise ValueError(f"values and reference must be 1-d arrays of the same length, got "
                         f"{a.shape} and {b.shape}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        return (float("nan"),) * 3

    def pct(x, y, axis=-1):
        return 100.0 * np.mean(x - y, axis=axis) / np.abs(np.mean(y, axis=axis))

    value = float(pct(a, b))
    if a.size == 1 or (np.ptp(a) == 0 and np.ptp(b) == 0):
        return value, value, value
    res = stats.bootstrap((a, b), pct, paired=True, vectorized=True,
                          confidence_level=CONFIDENCE, n_resamples=RESAMPLES,
                          method="percentile", random_state=np.random.default_rng(seed))
    ci = res.confidence_interval
    return value, float(ci.low), float(ci.high)


@contextlib.contextmanager
def seeded_global_rng(seed: int = 0) -> Iterator[None]:
    """NumPy's global generator seeded with ``seed`` inside the block, its state restored
    afterwards.

    rliable's stratified bootstrap draws its resamples from the global generator
    (``np.random.choice`` in ``StratifiedBootstrap.update_indices``; its ``random_state``
    only seeds arch's own generator), so its intervals are reproducible only with the global
    generator seeded."""
    state = np.random.get_state()  # noqa: NPY002 (the legacy global generator is the point)
    np.random.seed(seed)  # noqa: NPY002
    try:
        yield
    finally:
        np.random.set_state(state)  # noqa: NPY002
