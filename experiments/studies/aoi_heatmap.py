"""Age of information per agent and substate: heat maps and statistics per graph family.

The freshness index ``tau_i^{(j)}[k]`` is the age, at agent ``i``, of its newest
information about substate ``j`` (counted from the source ``j``). For six graph families
with the same ``N`` this script runs the batched freshness observer on ``--seeds`` graph
sequences and reports, over the steps after every index is triggered:

* mean AoI, average peak AoI (the age just before each refresh) and maximum AoI, per
  family (``aoi_stats.csv``) and per agent (``aoi_per_agent.csv``);
* ``aoi_heatmap.png``: ``tau_i^{(j)}[k]`` of one run per family, one row per
  (substate, agent) pair, omega in grey;
* ``aoi_matrix.png``: mean AoI as an agent x substate matrix per family.

Run: ``python experiments/studies/aoi_heatmap.py`` (a few seconds).
"""

# %%
from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense.graphs.aoi import aoi_stats, trigger_step
from netsense.graphs.families import make_graph_process
from netsense.observers.freshness import FreshnessObserver
from netsense.observers.run import run_observer
from netsense.studies.sweep import sample_graphs, write_csv
from netsense.systems.design import design_observer
from netsense.systems.plants import random_structured

RESULTS = Path(__file__).resolve().parents[1] / "results" / "studies" / "aoi_heatmap"

# family -> (T, param) at the default N
FAMILIES = {"ring": (4, 0.0), "ring_backward": (4, 0.0), "random_jsc": (2, 0.1),
            "gossip": (1, 0.0), "markov": (1, 0.4), "mobility": (1, 0.35)}


# %%
def run_family(family: str, N: int, n: int, seeds: int, steps: int, seed: int) -> np.ndarray:
    """Index history ``(K+1, B, N, N)`` of the freshness observer on one family."""
    T, param = FAMILIES[family]
    rng = np.random.default_rng(seed)
    plant = random_structured(n, N, rng=rng)
    graphs = sample_graphs(make_graph_process(family, N, T, param), seeds, steps, rng)
    obs = FreshnessObserver(design_observer(plant, deadbeat=True), batch_size=seeds)
    return run_observer(obs, plant, graphs, rng.standard_normal((seeds, n))).tau


def stats_after_trigger(tau: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`aoi_stats` per run from its own trigger step; ``(B, N, N)`` arrays."""
    trig = trigger_step(tau)
    out: dict[str, list] = {"mean": [], "peak": [], "max": []}
    for b, t in enumerate(trig):
        start = t if t >= 0 else tau.shape[0] - 1
        st = aoi_stats(tau[:, b:b + 1], int(start))
        for k in out:
            out[k].append(st[k][0])
    return {k: np.array(v) for k, v in out.items()} | {"trigger": trig}


# %%
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_heatmaps(taus: dict[str, np.ndarray], path: Path) -> None:
    plt = _plt()
    fams = list(taus)
    fig, axes = plt.subplots(len(fams), 1, figsize=(12, 2.6 * len(fams)), sharex=True)
    vmax = max(int(t[:, 0].max()) for t in taus.values())
    for ax, fam in zip(np.atleast_1d(axes), fams, strict=True):
        tau = taus[fam][:, 0]  # (K+1, N, N): first run
        K1, N, _ = tau.shape
        img = np.transpose(tau, (2, 1, 0)).reshape(N * N, K1).astype(float)  # rows (j, i)
        img = np.ma.masked_less(img, 0)
        cmap = plt.get_cmap("viridis").with_extremes(bad="0.8")
        im = ax.imshow(img, aspect="auto", interpolation="nearest", cmap=cmap, vmin=0,
                       vmax=vmax)
        for j in range(1, N):
            ax.axhline(j * N - 0.5, color="w", lw=0.4)
        ax.set_yticks([j * N + N / 2 - 0.5 for j in range(N)],
                      [f"z({j})" for j in range(N)], fontsize=7)
        ax.set_ylabel(fam, fontsize=9)
        fig.colorbar(im, ax=ax, pad=0.01, label="tau_i^(j)")
    np.atleast_1d(axes)[-1].set_xlabel("step k   (rows: substate j, then agent i; grey = omega)")
    fig.suptitle("Freshness index (age of information) of every agent and substate, one run "
                 "per family")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_matrices(stats: dict[str, dict], path: Path) -> None:
    plt = _plt()
    fams = list(stats)
    fig, axes = plt.subplots(1, len(fams), figsize=(3.2 * len(fams), 3.4))
    for ax, fam in zip(np.atleast_1d(axes), fams, strict=True):
        m = np.nanmean(stats[fam]["mean"], axis=0)
        im = ax.imshow(m, cmap="magma_r", interpolation="nearest")
        ax.set_title(f"{fam}\nmean AoI {np.nanmean(m[~np.eye(len(m), dtype=bool)]):.1f}",
                     fontsize=9)
        ax.set_xlabel("substate j")
        ax.set_ylabel("agent i")
        fig.colorbar(im, ax=ax, fraction=0.046)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# %%
def main(argv: Sequence[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--N", type=int, default=8)
    parser.add_argument("--n", type=int, default=6)
    parser.add_argument("--seeds", type=int, default=16)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--no-plot", action="store_true")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    from concurrent.futures import ProcessPoolExecutor

    from tqdm import tqdm

    jobs = [(f, args.N, args.n, args.seeds, args.steps, args.seed) for f in FAMILIES]
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = [pool.submit(run_family, *j) for j in jobs]
        taus = {j[0]: f.result() for j, f in zip(jobs, tqdm(futures, desc="families"),
                                                 strict=True)}
    off = ~np.eye(args.N, dtype=bool)
    stats, rows, per_agent = {}, [], []
    for fam, tau in taus.items():
        st = stats_after_trigger(tau)
        stats[fam] = st
        ok = st["trigger"] >= 0
        T, param = FAMILIES[fam]
        rows.append({"family": fam, "N": args.N, "T": T, "param": param,
                     "runs": int(tau.shape[1]), "runs_triggered": int(ok.sum()),
                     "trigger_median": float(np.median(st["trigger"][ok])) if ok.any()
                     else float("nan"),
                     "aoi_mean": float(np.nanmean(st["mean"][ok][:, off])),
                     "aoi_peak": float(np.nanmean(st["peak"][ok][:, off])),
                     "aoi_max": float(np.nanmax(st["max"][ok][:, off])),
                     "aoi_max_median_run": float(np.median(st["max"][ok][:, off].max(-1)))})
        for i in range(args.N):
            cols = np.arange(args.N) != i
            per_agent.append({"family": fam, "agent": i,
                              "aoi_mean": float(np.nanmean(st["mean"][ok][:, i, cols])),
                              "aoi_peak": float(np.nanmean(st["peak"][ok][:, i, cols])),
                              "aoi_max": float(np.nanmax(st["max"][ok][:, i, cols]))})
    write_csv(rows, args.out / "aoi_stats.csv")
    write_csv(per_agent, args.out / "aoi_per_agent.csv")
    if not args.no_plot:
        plot_heatmaps(taus, args.out / "aoi_heatmap.png")
        plot_matrices(stats, args.out / "aoi_matrix.png")
    print(f"\nAoI over the steps after every index is triggered (N = {args.N}, "
          f"{args.seeds} runs per family, non-source pairs)")
    print(f"{'family':<14}{'trigger':>8}{'mean':>8}{'peak':>8}{'max':>6}")
    for r in rows:
        print(f"{r['family']:<14}{r['trigger_median']:>8.0f}{r['aoi_mean']:>8.2f}"
              f"{r['aoi_peak']:>8.2f}{r['aoi_max']:>6.0f}")
    return {"rows": rows, "per_agent": per_agent, "taus": taus}


if __name__ == "__main__":
    main()
