"""Fig. 2 of Zhou, "Robust recursive state estimation with random measurements droppings".

Claim (Theorem 5 and Fig. 2): the pseudo-covariance matrix ``P_{t|t}`` of RSEIO converges to
a stationary distribution that does not depend on ``P_{0|0}``. We run RSEIO on the section IV
plant (mu = 0.8, Bernoulli arrivals with probability 0.8) from four initial
``P_{0|0} = c I_2``, c in {0.1, 1, 10, 100}, and compare the distributions of the entries of
``P_{500|500}``:

* independent arrival sequences per ``P_{0|0}`` (as in the paper), two-sample
  Kolmogorov-Smirnov tests against ``c = 1`` and a k-sample Anderson-Darling test;
* the same arrival sequences for all four (common random numbers): the Riemannian distance
  ``delta(P, P') = sqrt(sum log^2 eig(P P'^-1))`` of section III.A between runs, which the
  contraction argument says must shrink to 0.

``P_{t|t}`` of RSEIO depends only on the arrival sequence, not on the measured data, so
``delta`` (the size of the parameter error, 10 in the paper) plays no role here.

Writes ``robust_p0_independence.csv`` (test results), ``robust_p0_samples.csv`` (the
P_{T|T} samples) and ``robust_p0_independence.png`` into ``--out``.
"""

# %%
from __future__ import annotations

import argparse
import csv
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy import stats
from tqdm import tqdm

from netsense.estimators.robust import RSEIO
from netsense.sensing.drops import BernoulliArrivals

RESULTS = Path(__file__).resolve().parents[1] / "results" / "papers" / "robust_droppings_fig2"

sys.path.insert(0, str(Path(__file__).resolve().parent))
from robust_droppings_fig1 import ARRIVAL_P, MODEL, dA  # noqa: E402  (a sibling script)

P0_SCALES = (0.1, 1.0, 10.0, 100.0)
ENTRIES = (("P11", 0, 0), ("P12", 0, 1), ("P22", 1, 1))
MU = 0.8


def final_pcm(scales: Sequence[float], runs: int, steps: int, seeds: Sequence[int],
              track: bool = False, progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """RSEIO's ``P_{steps|steps}`` per scale, shape (len(scales), runs, 2, 2), and (if
    ``track``) the largest Riemannian distance to the first scale's run at every t, shape
    (steps + 1, len(scales)); NaN when not tracked.

    ``seeds[i]`` seeds the arrivals of scale ``i``; equal seeds mean common arrivals.
    """
    filters, samplers = [], []
    for c, seed in zip(scales, seeds, strict=True):
        f = RSEIO(MODEL, MU, dA=dA)
        f.reset(np.zeros(2), c * np.eye(2), batch=runs)
        filters.append(f)
        samplers.append(BernoulliArrivals(ARRIVAL_P).sampler(np.random.default_rng(seed),
                                                             (runs,)))
    y = np.zeros((runs, 1))
    dist = np.full((steps + 1, len(scales)), np.nan)
    for t in tqdm(range(steps + 1), disable=not progress, desc="RSEIO P_t|t"):
        if t > 0:
            for f, s in zip(filters, samplers, strict=True):
                f.step(y, s.next())
        if track:
            dist[t] = [riemann_distance(f.P, filters[0].P).max() for f in filters]
    return np.stack([f.P for f in filters]), dist


def riemann_distance(P: np.ndarray, Pp: np.ndarray) -> np.ndarray:
    """``sqrt(sum_i log^2 lambda_i(P Pp^-1))`` (section III.A) for batches of SPD matrices."""
    L = np.linalg.cholesky(Pp)
    Li = np.linalg.inv(L)                      # 2x2 triangular factors: cheap and exact enough
    lam = np.linalg.eigvalsh(Li @ P @ np.swapaxes(Li, -1, -2))
    return np.sqrt(np.sum(np.log(lam) ** 2, axis=-1))


def _anderson(groups: list[np.ndarray]):
    """k-sample Anderson-Darling (midrank variant, permutation p-value: the tabulated one is
    clipped to [0.001, 0.25])."""
    method = stats.PermutationMethod(n_resamples=199, random_state=np.random.default_rng(0))
    try:
        return stats.anderson_ksamp(groups, variant="midrank", method=method)
    except TypeError:  # scipy < 1.17 has no `variant`; midrank is its default
        return stats.anderson_ksamp(groups, method=method)


def tests(samples: np.ndarray) -> list[dict]:
    """KS (each scale vs c = 1) and k-sample Anderson-Darling per entry of P."""
    ref = P0_SCALES.index(1.0)
    rows = []
    for name, i, j in ENTRIES:
        groups = [samples[k, :, i, j] for k in range(len(P0_SCALES))]
        for k, c in enumerate(P0_SCALES):
            if k == ref:
                continue
            r = stats.ks_2samp(groups[k], groups[ref])
            rows.append({"entry": name, "test": f"KS c={c:g} vs c=1",
                         "statistic": r.statistic, "p_value": r.pvalue})
        ad = _anderson(groups)
        rows.append({"entry": name, "test": "Anderson-Darling 4 samples",
                     "statistic": ad.statistic, "p_value": ad.pvalue})
    return rows


# %%
def main(argv: Sequence[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5000)
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--seed", type=int, default=2014)
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--no-plot", action="store_true")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    t0 = time.perf_counter()
    seeds = [args.seed + 1 + k for k in range(len(P0_SCALES))]
    indep, _ = final_pcm(P0_SCALES, args.runs, args.steps, seeds, progress=True)
    common, dist = final_pcm(P0_SCALES, args.runs, args.steps, [args.seed] * 4, track=True,
                             progress=True)
    seconds = time.perf_counter() - t0
    rows = tests(indep)

    with open(args.out / "robust_p0_independence.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, ["entry", "test", "statistic", "p_value"])
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in r.items()})
        for k, c in enumerate(P0_SCALES):
            w.writerow({"entry": "all", "test": f"max Riemannian distance at t={args.steps}, "
                        f"common arrivals, c={c:g} vs c={P0_SCALES[0]:g}",
                        "statistic": f"{dist[-1, k]:.3g}", "p_value": ""})
    with open(args.out / "robust_p0_samples.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["P0_scale", "run"] + [e[0] for e in ENTRIES])
        for k, c in enumerate(P0_SCALES):
            for r in range(args.runs):
                w.writerow([c, r] + [f"{indep[k, r, i, j]:.8g}" for _, i, j in ENTRIES])
    if not args.no_plot:
        _plot(indep, dist, args.out / "robust_p0_independence.png")

    print(f"\nRSEIO P_{{{args.steps}|{args.steps}}} from P_0|0 = c I, c in {P0_SCALES}, "
          f"{args.runs} runs each ({seconds:.1f} s)")
    for k, c in enumerate(P0_SCALES):
        m = indep[k].reshape(args.runs, 4)[:, [0, 1, 3]].mean(axis=0)
        print(f"  c={c:<5g} mean P11 {m[0]:.4f}  P12 {m[1]:.4f}  P22 {m[2]:.4f}")
    print("Paper: the distribution of P_500|500 does not depend on P_0|0. Two-sample tests "
          "(independent arrivals):")
    for r in rows:
        print(f"  {r['entry']:4s} {r['test']:28s} stat {r['statistic']:.4f}  p {r['p_value']:.3f}")
    below = np.flatnonzero(dist.max(axis=1) < 1e-8)
    print(f"Common arrivals: max Riemannian distance to c={P0_SCALES[0]:g} at t=0: "
          f"{dist[0].max():.2f}, at t={args.steps}: {dist[-1].max():.1e}; below 1e-8 from "
          f"t = {below[0] if below.size else 'never'}")
    return {"samples": indep, "common": common, "dist": dist, "tests": rows,
            "seconds": seconds}


def _plot(samples: np.ndarray, dist: np.ndarray, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(16, 3.8))
    for ax, (name, i, j) in zip(axes[:3], ENTRIES, strict=True):
        lo, hi = np.quantile(samples[:, :, i, j], [0.001, 0.999])
        grid = np.linspace(lo, hi, 300)
        for k, (c, mk) in enumerate(zip(P0_SCALES, "xos^", strict=True)):
            dens = stats.gaussian_kde(samples[k, :, i, j])(grid)
            ax.plot(grid, dens, lw=0.8, marker=mk, markevery=30, ms=4, label=f"P0={c:g} I")
        ax.set_title(f"EPDF of {name} at t = T")
        ax.legend(fontsize=7)
    ax = axes[3]
    for k, c in enumerate(P0_SCALES[1:], start=1):
        ax.semilogy(np.maximum(dist[:, k], 1e-17), lw=0.8, label=f"c={c:g} vs {P0_SCALES[0]:g}")
    ax.set_title("common arrivals: max Riemannian distance")
    ax.set_xlabel("t")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
