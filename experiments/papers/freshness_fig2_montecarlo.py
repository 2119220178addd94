"""Fig. 2 of the freshness-index paper as a Monte Carlo over random initial estimates.

Paper's claim (Section III, Fig. 2): on the switching graphs of Fig. 1 with ``a = 2``,
consensus with uniform weights and consensus along the tree rooted at node 1 both give
unbounded errors, while the freshness-index observer's errors vanish. The paper shows one
run; here ``--runs`` initial estimates (node 1 exact, nodes 2 and 3 at ``x0 + U(-1, 1)``,
as in :func:`netsense.studies.examples.run_fig2`) run **as one batch** per observer
(``FreshnessObserver(design, batch_size=B)`` / ``ConsensusObserver(...)``, no Python loop
over runs). Run 0 uses exactly the draws of ``run_fig2(seed)`` and is checked against it.

Measured per observer: quantiles over runs of ``max_i |x_hat_i[k] - x[k]|`` and of the
relative error, the fraction of runs that converge (relative error < 1e-9 at the end) and
that diverge (worst error over the last two steps grows by more than 1 % per step), and the
wall time of the batch vs a Python loop over single runs (``--loop-runs`` of them).

Writes, into ``experiments/results/papers/freshness_fig2_montecarlo/``, ``fig2_montecarlo.csv``
(quantiles per k), ``fig2_montecarlo_summary.csv`` and ``fig2_montecarlo.png``.

Run: ``python experiments/papers/freshness_fig2_montecarlo.py`` (seconds).
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

from netsense.graphs.processes import fig1_graphs
from netsense.studies.examples import FIG2_OBSERVERS, run_fig2
from netsense.systems.design import design_observer
from netsense.systems.plants import fig1_scalar

RESULTS = Path(__file__).resolve().parents[1] / "results" / "papers" / "freshness_fig2_montecarlo"
QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)


# %% The batched Monte Carlo
def initial_estimates(runs: int, seed: int, x0: float = 1.0) -> np.ndarray:
    """``(runs, 3, 1)``: node 1 exact, nodes 2-3 at ``x0 + U(-1, 1)``; run 0 = run_fig2(seed)."""
    first = np.random.default_rng(seed).uniform(-1, 1, size=2)  # the draws of run_fig2
    rest = np.random.default_rng([seed, 1]).uniform(-1, 1, size=(runs - 1, 2))
    offs = np.concatenate([first[None], rest])
    X = np.full((runs, 3, 1), x0)
    X[:, 1:, 0] += offs
    return X


def run_montecarlo(runs: int = 10_000, steps: int = 30, a: float = 2.0, seed: int = 0
                   ) -> dict[str, np.ndarray]:
    """Every observer of Fig. 2 on ``runs`` initial estimates at once.

    Returns
    -------
    dict
        ``"k"``, ``"x"`` (true state, ``(steps + 1,)``), ``"x0_hat"`` and, per observer
        label, the absolute errors ``(steps + 1, runs, 3)``; ``"seconds"`` per label.
    """
    if runs < 1 or steps < 1:
        raise ValueError(f"runs and steps must be >= 1, got {runs}, {steps}")
    plant = fig1_scalar(a)
    design = design_observer(plant, deadbeat=True)
    graphs = fig1_graphs().sequence(steps)
    xs = [np.array([1.0])]
    for _ in range(steps):
        xs.append(plant.step(xs[-1]))
    X0 = initial_estimates(runs, seed, float(xs[0][0]))
    out: dict = {"k": np.arange(steps + 1), "x": np.array(xs)[:, 0], "x0_hat": X0,
                 "seconds": {}}
    for label, (cls, kwargs) in FIG2_OBSERVERS.items():
        t0 = time.perf_counter()
        obs = cls(design, batch_size=runs, **kwargs)
        obs.reset(X0)
        errs = np.empty((steps + 1, runs, 3))
        errs[0] = obs.errors(xs[0])
        for k in range(steps):  # one batched step for all runs (graphs/measurements shared)
            obs.step(plant.measure(xs[k]), graphs[k])
            errs[k + 1] = obs.errors(xs[k + 1])
        out["seconds"][label] = time.perf_counter() - t0
        out[label] = errs
    return out


def loop_seconds(runs: int, steps: int, seed: int) -> float:
    """Wall time of ``runs`` single (unbatched) Fig. 2 runs in a Python loop."""
    t0 = time.perf_counter()
    for r in range(runs):
        run_fig2(steps=steps, seed=seed + r)
    return time.perf_counter() - t0


def summarize(res: dict) -> list[dict]:
    """Per observer: converged / diverged fractions, final-error quantiles, growth."""
    rows = []
    K = int(res["k"][-1])
    xK = float(abs(res["x"][-1]))
    for label in FIG2_OBSERVERS:
        worst = res[label].max(-1)  # (K + 1, runs)
        final = worst[-2:].max(0)
        mid = worst[K // 2 - 1: K // 2 + 1].max(0)
        with np.errstate(divide="ignore", invalid="ignore"):
            growth = np.where((mid > 0) & (final > 0),
                              (final / mid) ** (1.0 / (K - K // 2)), 0.0)
        rel = worst[-1] / xK
        rows.append({"observer": label, "runs": worst.shape[1],
                     "converged_frac": float(np.mean(rel < 1e-9)),
                     "diverged_frac": float(np.mean(growth > 1.01)),
                     "median_growth_per_step": float(np.median(growth)),
                     **{f"final_err_q{int(q * 100):02d}": float(np.quantile(worst[-1], q))
                        for q in QUANTILES},
                     "seconds_batched": float(res["seconds"][label])})
    return rows


# %% Output
def save(res: dict, rows: list[dict], out: Path, stem: str = "fig2_montecarlo"
         ) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    labels = list(FIG2_OBSERVERS)
    csv_path = out / f"{stem}.csv"
    with open(csv_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["k", "x"] + [f"{lab} q{int(q * 100):02d}" for lab in labels
                                 for q in QUANTILES])
        qs = {lab: np.quantile(res[lab].max(-1), QUANTILES, axis=1) for lab in labels}
        for k in res["k"]:
            w.writerow([int(k), f"{res['x'][k]:.6g}"] +
                       [f"{qs[lab][j, k]:.6g}" for lab in labels for j in range(len(QUANTILES))])
    sum_path = out / f"{stem}_summary.csv"
    with open(sum_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
    k = res["k"]
    for ax, lab, row in zip(axes, labels, rows, strict=True):
        worst = np.maximum(res[lab].max(-1), 1e-16)
        q = np.quantile(worst, QUANTILES, axis=1)
        ax.fill_between(k, q[0], q[-1], alpha=0.25, label="5-95 %")
        ax.fill_between(k, q[1], q[-2], alpha=0.4, label="25-75 %")
        ax.semilogy(k, q[2], lw=1.5, label="median")
        for r in range(min(5, worst.shape[1])):
            ax.semilogy(k, worst[:, r], lw=0.5, color="gray", alpha=0.6)
        ax.set_title(f"{lab}\nconverged {row['converged_frac']:.0%}, "
                     f"diverged {row['diverged_frac']:.0%}", fontsize=10)
        ax.set_xlabel("k")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel(r"$\max_i |\hat x_i[k] - x[k]|$ (floor 1e-16)")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Fig. 2 Monte Carlo: {worst.shape[1]} random initial estimates, a = 2, "
                 "graphs of Fig. 1 (one batch per observer)")
    fig.tight_layout()
    png = out / f"{stem}.png"
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return [csv_path, sum_path, png]


# %% Main
def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=10_000)
    p.add_argument("--steps", type=int, default=30)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--loop-runs", type=int, default=200,
                   help="single runs timed in a Python loop for comparison (0: skip)")
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--stem", default="fig2_montecarlo")
    args = p.parse_args(argv)
    res = run_montecarlo(args.runs, args.steps, seed=args.seed)
    # run 0 is the paper-style single run of netsense.studies.examples.run_fig2
    single = run_fig2(steps=args.steps, seed=args.seed)
    for lab in FIG2_OBSERVERS:
        np.testing.assert_allclose(res[lab][:, 0], single[lab], rtol=1e-12, atol=1e-12)
    rows = summarize(res)
    paths = save(res, rows, Path(args.out), args.stem)
    for r in rows:
        print(f"{r['observer']:20s} converged {r['converged_frac']:7.2%}  diverged "
              f"{r['diverged_frac']:7.2%}  median growth/step "
              f"{r['median_growth_per_step']:.3f}  final error median "
              f"{r['final_err_q50']:.3g}  ({r['seconds_batched']:.3f} s for {r['runs']} runs)")
    if args.loop_runs:
        lt = loop_seconds(args.loop_runs, args.steps, args.seed)
        loop_rate = args.loop_runs / lt
        batch_rate = args.runs / sum(r["seconds_batched"] for r in rows)
        print(f"Python loop: {loop_rate:.1f} runs/s (all three observers); batched: "
              f"{batch_rate:.1f} runs/s -> {batch_rate / loop_rate:.0f}x")
    print("run 0 equals netsense.studies.examples.run_fig2(seed) for every observer")
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


if __name__ == "__main__":
    sys.exit(main())
