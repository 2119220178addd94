"""Certified upper bounds of the communication tasks, and every scripted policy held to them.

``python experiments/rl/upper_bounds.py`` (nine tasks x 20 protocol episodes; about 25
minutes on two cores; ``--tasks``/``--episodes``/``--workers`` change it) writes into
``experiments/results/rl/upper_bounds/``:

* ``episodes.csv``: per task and episode seed (``10^6 ..``), the certified bound
  (:func:`netsense.benchmark.upper_bound.upper_bound`: the perfect-information LP
  relaxation solved by HiGHS, its Lagrangian dual bound), the bound of each cutting-plane
  round, the program's size and the solve time;
* ``policies.csv``: the return of every policy of the task's frontier
  (``experiments/results/rl/comm_tasks/frontier_<task>.csv``: every decentralised,
  informed, privileged and centralised point) on the same episodes, so that
  ``tests/test_upper_bound.py`` holds each of them, the lookahead references and the
  committed learned policies below the bound, episode by episode;
* ``summary.csv`` / ``summary.md`` / ``summary.png``: per task the mean bound with its 95 %
  bootstrap interval beside the best decentralised rule, the best privileged rule and the
  best full-information reference on the same episodes, and the tightness (bound minus
  the best achieved return).
"""

# %%
from __future__ import annotations

import argparse
import csv
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments/results/rl/upper_bounds"
FRONTIER = ROOT / "experiments/results/rl/comm_tasks"
REFERENCES = ROOT / "experiments/results/rl/comm_bounds/episodes.csv"
TASKS = ("comm_process_noise-v0", "comm_substates-v0", "comm_channel_k2-v0",
         "message_cost-v0", "message_cost-v1", "comm_announced-v0", "comm_fading-v0",
         "comm_schedule-v0", "comm_schedule-v1")
WINDOW = 8
ROUNDS = 3


# %%
def _frontier_policies(task: str) -> list[tuple[str, str]]:
    with open(FRONTIER / f"frontier_{task}.csv") as fh:
        return [(r["policy"], r["kind"]) for r in csv.DictReader(fh)
                if r["kind"] in ("decentralised", "privileged", "centralised")]


def run_task(task: str, episodes: int) -> tuple[list[dict], list[dict]]:
    """Bounds and policy returns of one task on the first ``episodes`` protocol seeds."""
    from netsense.benchmark.protocol import eval_seeds, evaluate, frontier_overrides
    from netsense.benchmark.upper_bound import episode_data, upper_bound

    seeds = eval_seeds(episodes)
    bounds = []
    for d in episode_data(task, seeds):
        ub = upper_bound(d, window=WINDOW, rounds=ROUNDS)
        bounds.append({"scenario": task, "seed": d.seed, "upper_bound": ub.value,
                       "lp_rounds": " ".join(f"{v:.6f}" for v in ub.rounds),
                       "window": ub.window, "variables": ub.variables,
                       "constraints": ub.constraints, "seconds": round(ub.seconds, 2)})
    rows = []
    for policy, kind in _frontier_policies(task):
        rew = evaluate(task, policy, seeds, frontier_overrides(task))["reward"]
        rows += [{"scenario": task, "policy": policy, "kind": kind, "seed": s,
                  "reward": float(r)} for s, r in zip(seeds, rew, strict=True)]
    return bounds, rows


def _write(path: Path, rows: list[dict]) -> None:
    from netsense.rl.atomic import atomic_path

    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def summarise(bounds: list[dict], rows: list[dict], refs: list[dict]) -> list[dict]:
    """Per task: mean bound [95 % CI] and the best of each kind on the bound's seeds."""
    from netsense.benchmark.intervals import bootstrap_ci

    out = []
    for task in dict.fromkeys(b["scenario"] for b in bounds):
        ub = {int(b["seed"]): float(b["upper_bound"]) for b in bounds if b["scenario"] == task}
        seeds = sorted(ub)
        m, lo, hi = bootstrap_ci(np.array([ub[s] for s in seeds]))
        best = {}
        for kind in ("decentralised", "privileged", "centralised", "reference"):
            src = refs if kind == "reference" else rows
            per: dict[str, dict[int, float]] = {}
            for r in src:
                if r["scenario"] == task and (kind == "reference" or r["kind"] == kind):
                    per.setdefault(r["policy"], {})[int(r["seed"])] = float(r["reward"])
            scored = {p: np.mean([v[s] for s in seeds]) for p, v in per.items()
                      if all(s in v for s in seeds)}
            if scored:
                p = max(scored, key=scored.get)
                best[kind] = (p, float(scored[p]))
        achieved = max(v for _, v in best.values())
        out.append({"scenario": task, "episodes": len(seeds), "bound_mean": m,
                    "bound_ci_low": lo, "bound_ci_high": hi,
                    **{f"best_{k}": best[k][0] if k in best else "" for k in
                       ("decentralised", "privileged", "centralised", "reference")},
                    **{f"best_{k}_mean": best[k][1] if k in best else float("nan") for k in
                       ("decentralised", "privileged", "centralised", "reference")},
                    "best_achieved": achieved, "tightness": m - achieved})
    return out


def _number(v: str):
    try:
        return float(v) if v not in ("", "True", "False") else v
    except ValueError:
        return v


def add_to_frontier(bounds: list[dict], folder: Path = FRONTIER) -> None:
    """Put each task's bound (mean [95 % CI] over its episodes) into the frontier's CSV,
    Markdown and PNG as a row of kind ``upper_bound`` (replacing an earlier one)."""
    from netsense.benchmark.intervals import bootstrap_ci
    from netsense.benchmark.protocol import CSV_COLUMNS, write_frontiers

    rows: list[dict] = []
    with open(folder / "frontier.csv") as fh:
        for r in csv.DictReader(fh):
            if r["kind"] != "upper_bound":
                rows.append({k: (_number(v) if k.endswith(("_mean", "_low", "_high"))
                                 or k in ("seconds",) else v) for k, v in r.items()})
    out = []
    for task in dict.fromkeys(r["scenario"] for r in rows):
        mine = [r for r in rows if r["scenario"] == task]
        out += mine
        bs = [b for b in bounds if b["scenario"] == task]
        if not bs:
            continue
        seeds = [int(b["seed"]) for b in bs]
        m, lo, hi = bootstrap_ci(np.array([float(b["upper_bound"]) for b in bs]))
        row = {c: float("nan") for c in CSV_COLUMNS}
        row.update({"scenario": task, "control": mine[0]["control"], "kind": "upper_bound",
                    "family": "upper_bound", "policy": "upper bound (certified)", "knob": "",
                    "evaluation": "bound", "episodes": len(bs), "seed_first": min(seeds),
                    "seed_last": max(seeds), "pareto": "False",
                    "seconds": float(sum(float(b["seconds"]) for b in bs)),
                    "reward_mean": m, "reward_ci_low": lo, "reward_ci_high": hi})
        out.append(row)
    write_frontiers(out, folder)


def markdown(summary: list[dict]) -> str:
    lines = ["| task | upper bound [95 % CI] | best decentralised | best privileged | "
             "best full-information reference | bound - best achieved |",
             "|---|---|---|---|---|---|"]
    def cell(s, k):
        return f"`{s[f'best_{k}']}` {s[f'best_{k}_mean']:.1f}" if s[f"best_{k}"] else "–"

    for s in summary:
        lines.append(f"| `{s['scenario']}` | {s['bound_mean']:.1f} [{s['bound_ci_low']:.1f}, "
                     f"{s['bound_ci_high']:.1f}] | {cell(s, 'decentralised')} | "
                     f"{cell(s, 'privileged')} | {cell(s, 'reference')} | {s['tightness']:.1f} |")
    return "\n".join(lines) + "\n"


def plot(summary: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5))
    y = np.arange(len(summary))
    for off, key, label, marker in ((0.0, "bound_mean", "certified upper bound", "^"),
                                    (0.0, "best_reference_mean",
                                     "best full-information reference", "s"),
                                    (0.0, "best_privileged_mean", "best privileged", "x"),
                                    (0.0, "best_decentralised_mean", "best decentralised",
                                     "o")):
        ax.scatter([s[key] for s in summary], y + off, marker=marker, label=label)
    ax.errorbar([s["bound_mean"] for s in summary], y,
                xerr=[[s["bound_mean"] - s["bound_ci_low"] for s in summary],
                      [s["bound_ci_high"] - s["bound_mean"] for s in summary]],
                fmt="none", ecolor="k")
    ax.set_yticks(y, [s["scenario"] for s in summary])
    ax.set_xlabel("return (mean over the bound's episodes)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tasks", nargs="+", default=list(TASKS))
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--frontier-only", action="store_true",
                    help="only put the bounds of OUT/episodes.csv into the frontier's files")
    args = ap.parse_args(argv)
    if args.frontier_only:
        with open(args.out / "episodes.csv") as fh:
            add_to_frontier(list(csv.DictReader(fh)))
        return []
    from tqdm import tqdm

    bounds, rows = [], []
    with ProcessPoolExecutor(args.workers) as pool:
        futures = [pool.submit(run_task, t, args.episodes) for t in args.tasks]
        for f in tqdm(futures, desc="tasks", unit="task"):
            b, r = f.result()
            bounds += b
            rows += r
    with open(REFERENCES) as fh:
        refs = list(csv.DictReader(fh))
    summary = summarise(bounds, rows, refs)
    args.out.mkdir(parents=True, exist_ok=True)
    _write(args.out / "episodes.csv", bounds)
    _write(args.out / "policies.csv", rows)
    _write(args.out / "summary.csv", summary)
    (args.out / "summary.md").write_text(markdown(summary))
    plot(summary, args.out / "summary.png")
    add_to_frontier(bounds)
    print(markdown(summary))
    return summary


if __name__ == "__main__":
    main()
