"""Moving agents: when does joint strong connectivity break, and what does that do?

``N`` agents move in the unit square (random waypoint or reflected random walk) and can
send to every agent within their communication radius
(:mod:`netsense.graphs.mobility`). For a range of radii and ``--seeds`` runs each, we check
Assumption 1 window by window with ``T = --period``
(:func:`netsense.graphs.families.window_connectivity`; the first failing window is what
:func:`netsense.graphs.processes.check_joint_connectivity` reports) and run the freshness observer

* noiseless with deadbeat gains: does every estimate become exact, and when (steps to a
  relative error ``1e-6``; Corollary 1 needs Assumption 1);
* with process and measurement noise (std ``--noise``) and Theorem 1 gains (rho = 0.5)
  on a mildly unstable plant (spectral radius 1.05, so the state stays in floating-point
  range over the run):
  the steady-state error of the worst agent (mean over the last half of the run), which
  grows with the age of the information it holds.

Writes ``mobility_sweep.csv`` (per run), ``mobility_summary.csv`` (per model and radius),
``mobility_summary.png`` (everything vs radius) and ``mobility_timeline.png`` (one run at
a radius where connectivity comes and goes: connected windows, worst index, error).

Run: ``python experiments/studies/mobility.py`` (well under a minute on 2 cores).
"""

# %%
from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense.graphs.aoi import aoi_stats, trigger_step, worst_index
from netsense.graphs.families import window_connectivity
from netsense.graphs.mobility import RandomWalk, RandomWaypoint
from netsense.graphs.processes import check_joint_connectivity
from netsense.observers.freshness import FreshnessObserver
from netsense.observers.run import relative_error, run_observer, steps_to_tolerance
from netsense.sensing.noise import GaussianNoise
from netsense.studies.sweep import write_csv
from netsense.systems.design import design_observer
from netsense.systems.plants import random_structured

RESULTS = Path(__file__).resolve().parents[1] / "results" / "studies" / "mobility"

RADII = (0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.7)
MODELS = ("random_waypoint", "random_walk")


def make_process(model: str, N: int, radius: float):
    if model == "random_waypoint":
        return RandomWaypoint(N, radius=radius, speed_min=0.01, speed_max=0.04)
    return RandomWalk(N, radius=radius, step_std=0.02)


def _nanmean(values, reduce=np.mean) -> float:
    """``reduce`` over the finite values, NaN when there are none (no warning)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(reduce(v)) if v.size else float("nan")


# %%
def run_point(model: str, radius: float, N: int, n: int, seeds: int, steps: int, period: int,
              noise: float, seed: int) -> dict:
    """All runs of one (model, radius): per-run rows and the histories of run 0."""
    rng = np.random.default_rng([seed, MODELS.index(model), int(round(radius * 1000))])
    plant = random_structured(n, N, rng=np.random.default_rng(seed), spectral_radius=1.05)
    proc = make_process(model, N, radius)
    graphs = np.stack([proc.sequence(steps, c) for c in rng.spawn(seeds)])
    x0 = rng.standard_normal((seeds, n))
    # noiseless, deadbeat gains (Corollary 1)
    obs = FreshnessObserver(design_observer(plant, deadbeat=True), batch_size=seeds)
    exact = run_observer(obs, plant, graphs, x0)
    # noisy, Theorem 1 gains
    noisy = dataclasses.replace(plant, process_noise=GaussianNoise(noise),
                                measurement_noise=GaussianNoise(noise))
    obs = FreshnessObserver(design_observer(plant, rho=0.5), batch_size=seeds)
    tr = run_observer(obs, noisy, graphs, x0, noise_rng=rng)
    trig = trigger_step(exact.tau)
    to_eps = steps_to_tolerance(relative_error(exact), 1e-6)
    worst_err = tr.errors.max(-1)  # (K+1, B)
    half = steps // 2
    rows = []
    for b in range(seeds):
        wc = window_connectivity(graphs[b], period)
        rep = check_joint_connectivity(graphs[b], period)
        st = aoi_stats(tr.tau[:, b:b + 1], half)
        off = ~np.eye(N, dtype=bool)
        rows.append({
            "model": model, "radius": radius, "N": N, "n": n, "batch": b,
            "links_per_step": float(graphs[b].sum((-1, -2)).mean()),
            "strongly_connected_steps": float(np.mean(
                window_connectivity(graphs[b], 1))),
            "windows_connected": float(wc.mean()),
            "assumption1_T": rep.holds,
            "first_failure": -1 if rep.holds else rep.first_failure[0],
            "trigger": int(trig[b]),
            "worst_index_after_half": int(worst_index(tr.tau[:, b:b + 1], half)[0]),
            "aoi_mean_after_half": _nanmean(st["mean"][0][off]),
            "steps_to_eps_deadbeat": int(to_eps[b]),
            "converged": bool(to_eps[b] >= 0),
            "noisy_error_last_half": float(worst_err[half:, b].mean()),
        })
    history = {"graphs": graphs[0], "tau_max": tr.tau[:, 0].max((-1, -2)),
               "error": worst_err[:, 0], "exact_rel": relative_error(exact)[:, 0]}
    return {"rows": rows, "history": history}


# %%
def summarize(rows: list[dict]) -> list[dict]:
    out = []
    keys = sorted({(r["model"], r["radius"]) for r in rows}, key=lambda t: (t[0], t[1]))
    for model, radius in keys:
        rs = [r for r in rows if r["model"] == model and r["radius"] == radius]
        conv = [r["steps_to_eps_deadbeat"] for r in rs if r["converged"]]
        trig = [r["trigger"] for r in rs if r["trigger"] >= 0]
        out.append({
            "model": model, "radius": radius, "runs": len(rs),
            "links_per_step": float(np.mean([r["links_per_step"] for r in rs])),
            "strongly_connected_steps": float(np.mean([r["strongly_connected_steps"]
                                                       for r in rs])),
            "windows_connected": float(np.mean([r["windows_connected"] for r in rs])),
            "assumption1_frac": float(np.mean([r["assumption1_T"] for r in rs])),
            "triggered_frac": len(trig) / len(rs),
            "trigger_median": float(np.median(trig)) if trig else float("nan"),
            "converged_frac": float(np.mean([r["converged"] for r in rs])),
            "steps_to_eps_median": float(np.median(conv)) if conv else float("nan"),
            "worst_index_median": float(np.median([r["worst_index_after_half"] for r in rs])),
            "aoi_mean_median": _nanmean([r["aoi_mean_after_half"] for r in rs], np.median),
            "noisy_error_median": float(np.median([r["noisy_error_last_half"] for r in rs])),
        })
    return out


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_summary(summary: list[dict], period: int, path: Path) -> None:
    plt = _plt()
    fig, axes = plt.subplots(1, 4, figsize=(17, 4))
    for model, style in zip(MODELS, ("o-", "s--"), strict=True):
        ss = [s for s in summary if s["model"] == model]
        r = [s["radius"] for s in ss]
        axes[0].plot(r, [s["windows_connected"] for s in ss], style,
                     label=f"{model}: windows of T={period} connected")
        axes[0].plot(r, [s["assumption1_frac"] for s in ss], style, alpha=0.5,
                     label=f"{model}: runs with Assumption 1 (T={period})")
        axes[1].plot(r, [s["converged_frac"] for s in ss], style, label=model)
        axes[2].plot(r, [s["worst_index_median"] for s in ss], style, label=model)
        axes[3].plot(r, [s["noisy_error_median"] for s in ss], style, label=model)
    axes[0].set_title("joint strong connectivity")
    axes[1].set_title("runs whose deadbeat estimates became exact")
    axes[2].set_title("worst freshness index, 2nd half (median)")
    axes[3].set_title("worst-agent error with noise, 2nd half (median)")
    axes[2].set_yscale("log")
    axes[3].set_yscale("log")
    for ax in axes:
        ax.set_xlabel("communication radius")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_timeline(history: dict, radius: float, period: int, path: Path) -> None:
    plt = _plt()
    wc = window_connectivity(history["graphs"], period)
    K1 = history["tau_max"].size
    fig, axes = plt.subplots(3, 1, figsize=(11, 7), sharex=True)
    for ax in axes:
        for w, ok in enumerate(wc):
            if not ok:
                ax.axvspan(w * period, (w + 1) * period, color="tab:red", alpha=0.15, lw=0)
    axes[0].step(np.arange(len(wc)) * period, wc.astype(int), where="post")
    axes[0].set_ylabel(f"window of T={period}\nstrongly connected")
    axes[1].plot(np.arange(K1), history["tau_max"])
    axes[1].set_ylabel("max_i,j tau_i^(j)")
    axes[2].semilogy(np.arange(K1), history["error"], label="noisy, Theorem 1 gains")
    axes[2].semilogy(np.arange(K1), history["exact_rel"], label="noiseless deadbeat (relative)")
    axes[2].set_ylabel("worst-agent error")
    axes[2].set_xlabel("step k (red: windows whose union is not strongly connected)")
    axes[2].legend(fontsize=8)
    fig.suptitle(f"Random waypoint, radius {radius}: one run")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# %%
def main(argv: Sequence[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--N", type=int, default=8)
    parser.add_argument("--n", type=int, default=6)
    parser.add_argument("--radii", type=str, default=",".join(map(str, RADII)))
    parser.add_argument("--seeds", type=int, default=16)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--period", type=int, default=10, help="T of the Assumption-1 check")
    parser.add_argument("--noise", type=float, default=1e-3)
    parser.add_argument("--timeline-radius", type=float, default=0.25)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--no-plot", action="store_true")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    radii = [float(v) for v in args.radii.split(",")]
    if args.timeline_radius not in radii:
        radii.append(args.timeline_radius)
    from concurrent.futures import ProcessPoolExecutor

    from tqdm import tqdm

    jobs = [(m, r, args.N, args.n, args.seeds, args.steps, args.period, args.noise, args.seed)
            for m in MODELS for r in radii]
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = [pool.submit(run_point, *j) for j in jobs]
        results = [f.result() for f in tqdm(futures, desc="mobility")]
    rows = [r for res in results for r in res["rows"]]
    summary = summarize(rows)
    write_csv(rows, args.out / "mobility_sweep.csv")
    write_csv(summary, args.out / "mobility_summary.csv")
    if not args.no_plot:
        plot_summary(summary, args.period, args.out / "mobility_summary.png")
        idx = jobs.index(("random_waypoint", args.timeline_radius, args.N, args.n, args.seeds,
                          args.steps, args.period, args.noise, args.seed))
        plot_timeline(results[idx]["history"], args.timeline_radius, args.period,
                      args.out / "mobility_timeline.png")
    print(f"\nN = {args.N}, n = {args.n}, {args.seeds} runs per point, Assumption 1 checked "
          f"with T = {args.period}")
    print(f"{'model':<16}{'radius':>7}{'links':>7}{'win ok':>8}{'A1':>6}{'exact':>7}"
          f"{'steps':>7}{'worst tau':>10}{'noisy err':>11}")
    for s in summary:
        print(f"{s['model']:<16}{s['radius']:>7.2f}{s['links_per_step']:>7.1f}"
              f"{s['windows_connected']:>8.2f}{s['assumption1_frac']:>6.2f}"
              f"{s['converged_frac']:>7.2f}{s['steps_to_eps_median']:>7.0f}"
              f"{s['worst_index_median']:>10.0f}{s['noisy_error_median']:>11.2e}")
    return {"rows": rows, "summary": summary}


if __name__ == "__main__":
    main()
