"""Time to design an observer (Lemma 1 decomposition + Theorem 1 / Corollary 1 gains).

Prints the median wall time over a few random structured plants for each (n, N); the
reference row is a single ``numpy.linalg.svd`` of an n x n matrix measured in the same run,
so the ratio is machine-independent.
"""

# %%
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from netsense import decompose, design_observer, random_structured


def _median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    print(f"{'n':>4} {'N':>4} {'sources':>7} {'decompose [ms]':>15} {'rho design [ms]':>16} "
          f"{'deadbeat [ms]':>14} {'svd(n x n) [ms]':>16}")
    for n, N, m in [(20, 10, 5), (50, 20, 10), (100, 20, 10)]:
        plant = random_structured(n, N, rng=0, num_sources=m)
        M = np.random.default_rng(0).standard_normal((n, n))
        t_svd = _median_time(lambda M=M: np.linalg.svd(M), args.repeats)
        t_dec = _median_time(lambda p=plant: decompose(p.A, p.C), args.repeats)
        t_rho = _median_time(lambda p=plant: design_observer(p, rho=0.9), args.repeats)
        t_db = _median_time(lambda p=plant: design_observer(p, deadbeat=True), args.repeats)
        print(f"{n:>4} {N:>4} {m:>7} {1e3 * t_dec:>15.1f} {1e3 * t_rho:>16.1f} "
              f"{1e3 * t_db:>14.1f} {1e3 * t_svd:>16.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
