"""How the freshness observer degrades under network and sensor faults, vs consensus.

One plant (``random_structured``, n = 6, N = 8, spectral radius 1.05), process and
measurement noise (std ``--noise``), random jointly strongly connected graphs (T = 2),
Theorem 1 gains (rho = 0.5) shared by both observers; ``--seeds`` runs per scenario in
one batch. Faults (:mod:`netsense.observers.faults`) start at step ``--at``:

* message loss on every link: Bernoulli 20 % and 50 %, Gilbert-Elliott 50 % in bursts
  of mean length 10 (a Markov link-failure channel);
* a relay (an agent that owns no substate) crashes; a source crashes;
* a source's sensor gets stuck, or reports 5-step-old values;
* an agent lies, claiming freshness index 0 for every substate it does not own, and
  never refreshes (lowest index: wins the ties; highest-index relay: loses them).

For every scenario and observer: the error of the worst honest, alive agent averaged over
the second half of the run (median over runs, and its ratio to the observer's fault-free
value); for the freshness observer also the worst index and, for the liar, the fraction of
(agent, substate) pairs whose information comes from the liar.

Writes ``faults_summary.csv``, ``faults_errors.png`` (bars) and ``faults_timeline.png``
(median worst-agent error over time) into ``--out``.

Run: ``python experiments/studies/faults.py`` (well under a minute on 2 cores).
"""

# %%
from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense.graphs.aoi import worst_index
from netsense.graphs.families import make_graph_process
from netsense.observers.faults import (
    CrashedAgents,
    LinkDrops,
    LyingAgent,
    StuckSensor,
    captured_fraction,
    run_with_faults,
)
from netsense.sensing.drops import BernoulliArrivals, GilbertElliottArrivals
from netsense.sensing.noise import GaussianNoise
from netsense.studies.sweep import sample_graphs, write_csv
from netsense.systems.design import design_observer
from netsense.systems.plants import random_structured

RESULTS = Path(__file__).resolve().parents[1] / "results" / "studies" / "faults"

OBSERVERS = ("freshness", "consensus")


# %% Setup and scenarios
def setup(N: int, n: int, noise: float, seed: int):
    plant = random_structured(n, N, rng=np.random.default_rng(seed), spectral_radius=1.05)
    noisy = dataclasses.replace(plant, process_noise=GaussianNoise(noise),
                                measurement_noise=GaussianNoise(noise))
    design = design_observer(plant, rho=0.5)
    return noisy, design


def scenarios(design, at: int) -> dict[str, list]:
    """Named fault lists; the faulty agents are picked from the plant's decomposition."""
    sizes = design.decomposition.sizes
    sources = [j for j, s in enumerate(sizes) if s > 0]
    relays = [j for j, s in enumerate(sizes) if s == 0]
    src = sources[0]  # every later substate depends on it (Lemma 1's triangular structure)
    return {
        "none": [],
        "drops_bernoulli_20%": [LinkDrops(BernoulliArrivals(0.8), at=at)],
        "drops_bernoulli_50%": [LinkDrops(BernoulliArrivals(0.5), at=at)],
        "drops_gilbert_elliott_50%": [LinkDrops(GilbertElliottArrivals(0.1, 0.1), at=at)],
        f"crash_relay_{relays[0]}": [CrashedAgents(relays[0], at=at)],
        f"crash_source_{src}": [CrashedAgents(src, at=at)],
        f"stuck_sensor_{src}": [StuckSensor(src, at=at, mode="stuck")],
        f"stale_sensor_{src}_delay5": [StuckSensor(src, at=at, mode="stale", delay=5)],
        "liar_agent_0_claim0": [LyingAgent(0, claim=0, at=at)],
        f"liar_relay_{relays[-1]}_claim0": [LyingAgent(relays[-1], claim=0, at=at)],
    }


# %% One scenario
def run_scenario(name: str, observer: str, N: int, n: int, noise: float, seeds: int,
                 steps: int, at: int, seed: int) -> dict:
    plant, design = setup(N, n, noise, seed)
    faults = scenarios(design, at)[name]
    rng = np.random.default_rng([seed, 1])
    graphs = sample_graphs(make_graph_process("random_jsc", N, 2, 0.1), seeds, steps, rng)
    x0 = rng.standard_normal((seeds, n))
    tr, obs = run_with_faults(plant, design, graphs, x0, faults, observer=observer,
                              rng=np.random.default_rng([seed, 2]))
    worst = tr.errors[:, :, tr.alive].max(-1)  # (K+1, B)
    half = steps // 2
    out = {"scenario": name, "observer": observer,
           "error_2nd_half": worst[half:].mean(0),
           "curve": np.median(worst, axis=1),
           "messages_per_step": float(tr.messages.mean())}
    if observer == "freshness":
        out["worst_index"] = worst_index(tr.tau, half)
        out["captured"] = captured_fraction(obs) if hasattr(obs, "origin") else None
    return out


# %% Plots
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_bars(rows: list[dict], path: Path) -> None:
    plt = _plt()
    names = list(dict.fromkeys(r["scenario"] for r in rows))
    fig, ax = plt.subplots(figsize=(12, 4.5))
    w = 0.38
    for k, (obs, color) in enumerate(zip(OBSERVERS, ("tab:blue", "tab:gray"), strict=True)):
        med = [next(r["error_median"] for r in rows if r["scenario"] == s
                    and r["observer"] == obs) for s in names]
        q1 = [next(r["error_q25"] for r in rows if r["scenario"] == s
                   and r["observer"] == obs) for s in names]
        q3 = [next(r["error_q75"] for r in rows if r["scenario"] == s
                   and r["observer"] == obs) for s in names]
        x = np.arange(len(names)) + (k - 0.5) * w
        ax.bar(x, med, w, color=color, label=obs)
        ax.errorbar(x, med, yerr=[np.subtract(med, q1), np.subtract(q3, med)], fmt="none",
                     color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(names)), names, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("worst honest-agent error, 2nd half\n(median over runs, IQR)")
    ax.legend()
    ax.grid(alpha=0.3, axis="y", which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_timeline(results: list[dict], at: int, path: Path) -> None:
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.2), sharey=True)
    for ax, obs in zip(axes, OBSERVERS, strict=True):
        for r in results:
            if r["observer"] == obs:
                ax.semilogy(r["curve"], lw=1, label=r["scenario"])
        ax.axvline(at, color="k", ls=":", lw=1)
        ax.set_title(f"{obs} observer")
        ax.set_xlabel("step k (faults from the dotted line)")
        ax.grid(alpha=0.3, which="both")
    axes[0].set_ylabel("worst honest-agent error (median over runs)")
    axes[1].legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# %%
def main(argv: Sequence[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--N", type=int, default=8)
    parser.add_argument("--n", type=int, default=6)
    parser.add_argument("--noise", type=float, default=1e-3)
    parser.add_argument("--seeds", type=int, default=32)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--at", type=int, default=50, help="step at which faults start")
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--no-plot", action="store_true")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    from concurrent.futures import ProcessPoolExecutor

    from tqdm import tqdm

    _, design = setup(args.N, args.n, args.noise, args.seed)
    names = list(scenarios(design, args.at))
    jobs = [(s, o, args.N, args.n, args.noise, args.seeds, args.steps, args.at, args.seed)
            for s in names for o in OBSERVERS]
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = [pool.submit(run_scenario, *j) for j in jobs]
        results = [f.result() for f in tqdm(futures, desc="fault scenarios")]
    nominal = {r["observer"]: float(np.median(r["error_2nd_half"]))
               for r in results if r["scenario"] == "none"}
    rows = []
    for r in results:
        e = r["error_2nd_half"]
        med = float(np.median(e))
        row = {"scenario": r["scenario"], "observer": r["observer"], "runs": e.size,
               "error_median": med, "error_q25": float(np.quantile(e, 0.25)),
               "error_q75": float(np.quantile(e, 0.75)),
               "ratio_to_fault_free": med / nominal[r["observer"]],
               "messages_per_step": r["messages_per_step"],
               "worst_index_median": float(np.median(r["worst_index"]))
               if "worst_index" in r else float("nan"),
               "captured_fraction": float(np.mean(r["captured"]))
               if r.get("captured") is not None else float("nan")}
        rows.append(row)
    write_csv(rows, args.out / "faults_summary.csv")
    if not args.no_plot:
        plot_bars(rows, args.out / "faults_errors.png")
        plot_timeline(results, args.at, args.out / "faults_timeline.png")
    sizes = design.decomposition.sizes
    print(f"\nsubstate sizes per agent {sizes}; faults from step {args.at}; "
          f"{args.seeds} runs; error = worst honest agent, mean over steps "
          f"{args.steps // 2}..{args.steps}, median over runs")
    print(f"{'scenario':<30}{'freshness':>11}{'x free':>9}{'consensus':>11}{'x free':>9}"
          f"{'worst tau':>10}{'captured':>9}")
    for s in names:
        f = next(r for r in rows if r["scenario"] == s and r["observer"] == "freshness")
        c = next(r for r in rows if r["scenario"] == s and r["observer"] == "consensus")
        cap = "" if np.isnan(f["captured_fraction"]) else f"{f['captured_fraction']:.2f}"
        print(f"{s:<30}{f['error_median']:>11.3g}{f['ratio_to_fault_free']:>9.3g}"
              f"{c['error_median']:>11.3g}{c['ratio_to_fault_free']:>9.3g}"
              f"{f['worst_index_median']:>10.0f}{cap:>9}")
    return {"rows": rows}


if __name__ == "__main__":
    main()
