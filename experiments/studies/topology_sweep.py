"""How tight are the freshness paper's bounds on different switching patterns?

For six graph families (round-robin directed ring, the same ring on its slowest
"backward" schedule, random jointly strongly connected graphs with period T, gossip on the
complete graph, Markov link failures on the bidirectional ring, random-waypoint agents with a
communication radius), several N, T and plant dimensions n, the batched freshness observer
is run on ``--seeds`` graph sequences per case (:func:`netsense.studies.sweep.run_case`) and
we measure

* the step after which every freshness index is triggered vs Lemma 3's ``(N-1)T``;
* the worst index from ``(N-1)T`` on vs Lemma 5's ``2(N-1)T`` and vs ``NT - 1``, the
  sharper bound the proof of Lemma 3 gives (:func:`netsense.graphs.bounds.sharp_index_bound`);
* steps to a relative error ``eps`` with deadbeat gains vs Corollary 1's ``n + 2N(N-1)T``
  and with Theorem 1's rho-ordered gains vs the onset ``(2N-1)(N-1)T`` of eq. (33);
* messages per step (links carrying a message) and adoptions per step.

For gossip, Markov and mobility, ``T`` is the smallest period for which Assumption 1 holds
on the realised sequence (:func:`netsense.graphs.processes.smallest_period`); a run where none does
counts as "Assumption 1 fails" and is left out of the ratios.

Writes ``topology_sweep.csv`` (one row per run), ``topology_summary.csv`` (per case),
``topology_bounds.png`` (measured vs bound), ``topology_ratio_vs_N.png`` and
``topology_markov.png`` (vs failure probability) into ``--out``.

Run: ``python experiments/studies/topology_sweep.py`` (about 1-2 minutes on 2 cores).
"""

# %%
from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense.studies.sweep import SweepCase, run_sweep, summarize, write_csv

RESULTS = Path(__file__).resolve().parents[1] / "results" / "studies" / "topology_sweep"

FAMILY_STYLE = {"ring": ("tab:blue", "o"), "ring_backward": ("tab:purple", "v"),
                "random_jsc": ("tab:green", "s"), "gossip": ("tab:orange", "D"),
                "markov": ("tab:red", "^"), "mobility": ("tab:brown", "P")}
MARKOV_P = (0.05, 0.2, 0.4, 0.6, 0.8)
RADII = (0.25, 0.35, 0.5)


# %% The grid
def build_cases(Ns: Sequence[int], ns: Sequence[int], seeds: int, seed: int,
                max_steps: int) -> list[SweepCase]:
    """Every case of the sweep; horizons scale with the period so bounds can be reached."""
    cases = []

    def add(family, N, T, n, param, steps):
        cases.append(SweepCase(family, N, T, n=n, param=param, seeds=seeds,
                               steps=min(max_steps, steps), seed=seed))

    for N in Ns:
        for n in ns:
            for T in (1, 2, 4):
                if T <= N:
                    add("ring", N, T, n, 0.0, 4 * (N - 1) * T + 2 * n + 80)
                    add("random_jsc", N, T, n, 0.1, 4 * (N - 1) * T + 2 * n + 80)
            for T in sorted({3, N}):
                add("ring_backward", N, T, n, 0.0, 4 * (N - 1) * T + 2 * n + 80)
            add("gossip", N, 1, n, 0.0, 40 * N + 2 * n + 80)
            for p in MARKOV_P:
                add("markov", N, 1, n, p, 300)
            for r in RADII:
                add("mobility", N, 1, n, r, 300)
    return cases


# %% Figures
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


PAIRS = (("trigger", "bound_lemma3", "Lemma 3: all indices triggered", "(N-1)T",
          "trigger_ratio"),
         ("worst_after_lemma3", "bound_lemma5", "Lemma 5: worst index after (N-1)T",
          "2(N-1)T", "worst_after_lemma3_ratio"),
         ("worst_after_lemma3", "bound_index_sharp", "Sharpened: worst index after (N-1)T",
          "NT - 1", "worst_sharp_ratio"),
         ("steps_deadbeat", "bound_corollary1", "Corollary 1: deadbeat, steps to eps",
          "n + 2N(N-1)T", "steps_deadbeat_ratio"),
         ("steps_rho", "onset_theorem1", "Theorem 1 gains: steps to eps",
          "(2N-1)(N-1)T (onset of eq. (33))", "steps_rho_ratio"))

#: Column stems of the tightness table: measured / bound for each entry of PAIRS.
RATIO_NAMES = ("trigger_over_lemma3", "worst_over_lemma5", "worst_over_NT_minus_1",
               "deadbeat_over_corollary1", "rho_steps_over_theorem1_onset")


def plot_bounds(summary: list[dict], path: Path) -> None:
    plt = _plt()
    fig, axes = plt.subplots(2, 3, figsize=(16, 9))
    for ax, (q, b, title, label, _r) in zip(axes.ravel(), PAIRS, strict=False):
        lo, hi = np.inf, 0.0
        for fam, (color, marker) in FAMILY_STYLE.items():
            ss = [s for s in summary if s["family"] == fam and np.isfinite(s[f"{q}_median"])
                  and np.isfinite(s[f"{b}_median"])]
            if not ss:
                continue
            x = np.array([s[f"{b}_median"] for s in ss])
            y = np.array([s[f"{q}_median"] for s in ss])
            ymax = np.array([s[f"{q}_max"] for s in ss])
            ax.errorbar(x, y, yerr=[np.zeros_like(y), ymax - y], fmt=marker, color=color,
                        ms=5, alpha=0.8, lw=0.6, label=fam)
            lo, hi = min(lo, x.min(), max(y.min(), 1)), max(hi, x.max(), ymax.max())
        grid = np.array([max(lo, 1) / 1.5, hi * 1.5])
        ax.plot(grid, grid, "k-", lw=1, label="measured = bound")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(f"bound {label}")
        ax.set_ylabel("measured (median over seeds; bar to max)")
        ax.set_title(title)
        ax.grid(alpha=0.3, which="both")
    axes[0, 0].legend(fontsize=8)
    ax = axes[1, 2]
    for fam, (color, marker) in FAMILY_STYLE.items():
        Ns = sorted({s["N"] for s in summary if s["family"] == fam})
        m = [np.median([s["messages_per_step"] for s in summary
                        if s["family"] == fam and s["N"] == N]) for N in Ns]
        ax.plot(Ns, m, marker=marker, color=color, label=fam)
    ax.set_xlabel("N")
    ax.set_ylabel("messages per step (median over cases)")
    ax.set_title("Communication cost")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_ratio_vs_N(summary: list[dict], path: Path) -> None:
    plt = _plt()
    fig, axes = plt.subplots(1, 5, figsize=(20, 4))
    for ax, (_q, _b, title, label, ratio) in zip(axes, PAIRS, strict=True):
        for fam, (color, marker) in FAMILY_STYLE.items():
            Ns = sorted({s["N"] for s in summary if s["family"] == fam})
            r = [np.nanmax([s[ratio] for s in summary
                            if s["family"] == fam and s["N"] == N] + [np.nan]) for N in Ns]
            ax.plot(Ns, r, marker=marker, color=color, label=fam)
        ax.axhline(1.0, color="k", lw=1)
        ax.set_yscale("log")
        ax.set_xlabel("N")
        ax.set_ylabel(f"measured / {label}")
        ax.set_title(title + "\n(largest case median)", fontsize=9)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_markov(summary: list[dict], path: Path) -> None:
    plt = _plt()
    ss = [s for s in summary if s["family"] == "markov"]
    Ns = sorted({s["N"] for s in ss})
    n0 = min(s["n"] for s in ss)
    fig, axes = plt.subplots(1, 4, figsize=(16, 4))
    for N in Ns:
        rows = sorted((s for s in ss if s["N"] == N and s["n"] == n0), key=lambda s: s["param"])
        p = [s["param"] for s in rows]
        axes[0].plot(p, [s["assumption1_frac"] for s in rows], "o-", label=f"N={N}")
        axes[1].plot(p, [s["T_used_median"] for s in rows], "o-", label=f"N={N}")
        axes[2].plot(p, [s["worst_index"] for s in rows], "o-", label=f"N={N}")
        axes[3].plot(p, [s["steps_deadbeat_median"] for s in rows], "o-", label=f"N={N}")
    titles = ("runs where Assumption 1 holds", "measured T (median)",
              "worst index after trigger (median)", "deadbeat steps to eps (median)")
    for ax, t in zip(axes, titles, strict=True):
        ax.set_xlabel("link failure probability p_fail (p_recover = 0.2)")
        ax.set_title(t)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# %%
def tightness_table(summary: list[dict]) -> list[dict]:
    """Per family and bound: median and max over cases of (measured / bound)."""
    out = []
    for fam in FAMILY_STYLE:
        ss = [s for s in summary if s["family"] == fam]
        if not ss:
            continue
        row = {"family": fam, "cases": len(ss)}
        for (_q, _b, _t, _label, ratio), name in zip(PAIRS, RATIO_NAMES, strict=True):
            r = np.array([s[ratio] for s in ss], dtype=float)
            r = r[np.isfinite(r)]
            row[f"{name}_median"] = float(np.median(r)) if r.size else np.nan
            row[f"{name}_max"] = float(np.max(r)) if r.size else np.nan
        row["assumption1_frac"] = float(np.mean([s["assumption1_frac"] for s in ss]))
        row["messages_per_step_median"] = float(np.median([s["messages_per_step"] for s in ss]))
        out.append(row)
    return out


def main(argv: Sequence[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--N", type=str, default="4,6,8,10", help="agent counts")
    parser.add_argument("--n", type=str, default="4,8", help="plant dimensions")
    parser.add_argument("--seeds", type=int, default=8, help="runs per case (batched)")
    parser.add_argument("--max-steps", type=int, default=600, help="horizon cap")
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--no-plot", action="store_true")
    args = parser.parse_args(argv)
    Ns = [int(v) for v in args.N.split(",")]
    ns = [int(v) for v in args.n.split(",")]
    args.out.mkdir(parents=True, exist_ok=True)

    cases = build_cases(Ns, ns, args.seeds, args.seed, args.max_steps)
    t0 = time.perf_counter()
    rows = run_sweep(cases, workers=args.workers)
    seconds = time.perf_counter() - t0
    summary = summarize(rows)
    write_csv(rows, args.out / "topology_sweep.csv")
    write_csv(summary, args.out / "topology_summary.csv")
    table = tightness_table(summary)
    write_csv(table, args.out / "topology_tightness.csv")
    if not args.no_plot:
        plot_bounds(summary, args.out / "topology_bounds.png")
        plot_ratio_vs_N(summary, args.out / "topology_ratio_vs_N.png")
        plot_markov(summary, args.out / "topology_markov.png")

    print(f"\n{len(cases)} cases x {args.seeds} seeds in {seconds:.1f} s")
    print("measured / bound, median [max] over cases (per case: median over seeds)")
    print(f"{'family':<14}{'Lemma 3':>16}{'Lemma 5':>16}{'NT - 1':>16}{'Corollary 1':>16}"
          f"{'rho / onset':>16}{'A1 held':>9}{'msgs':>7}")
    for r in table:
        cells = [f"{r[f'{m}_median']:.2f} [{r[f'{m}_max']:.2f}]" for m in RATIO_NAMES]
        print(f"{r['family']:<14}" + "".join(f"{c:>16}" for c in cells)
              + f"{r['assumption1_frac']:>9.2f}{r['messages_per_step_median']:>7.1f}")
    violations = [r for r in rows if r["assumption1"] and (
        r["trigger"] > r["bound_lemma3"] or r["worst_after_lemma3"] > r["bound_lemma5"]
        or r["worst_after_lemma3"] > r["bound_index_sharp"]
        or r["steps_deadbeat"] > r["bound_corollary1"] or r["trigger"] < 0)]
    print(f"bound violations among runs satisfying Assumption 1: {len(violations)}")
    return {"rows": rows, "summary": summary, "table": table, "violations": violations,
            "seconds": seconds}


if __name__ == "__main__":
    main()
