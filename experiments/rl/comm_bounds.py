"""Full-information reference schedulers on the communication tasks: headroom over the
scripted frontier, and what the references' search settings buy.

The references (:mod:`netsense.benchmark.lookahead`) are centralised full-information
lookahead schedulers, not deployable policies, and their returns are achieved, not bounds:
``reference:causal`` (rollouts on futures resampled from the current state) and
``reference:clairvoyant`` (the realised future). This script

1. runs the protocol's frontier of every task (all scripted families, the informed and
   privileged rules that apply, on ``--episodes`` evaluation seeds) with both references on
   the first ``--reference-episodes`` of those seeds, at the default search settings:
   ``frontier.csv``/``.md``, ``frontier_<task>.png``, ``headroom.csv``/``.md`` (reference
   minus the best decentralised and the best centralised scripted point, paired bootstrap
   intervals), ``episodes.csv`` (the references' return per episode);
2. measures the trade-off of the search on one task (``--tradeoff-task``): the causal
   reference's return and cost against the lookahead ``h`` and the number of futures
   ``F``, the clairvoyant one's against ``h``, each on the first ``--tradeoff-episodes``
   seeds, continuing with the policies the frontier chose for that task:
   ``tradeoff.csv``, ``tradeoff.png``, ``tradeoff.md``.

Writes into ``experiments/results/rl/comm_bounds/``. Run (measured on one core: the
references cost about 60 s per reference episode summed over the nine tasks, the causal
one 85 % of it, so about 20 minutes for 20 episodes; the frontier about 15 minutes more,
the trade-off 5; ``--workers 2`` runs the tasks in two processes; ``--smoke`` for a
seconds-long check)::

    NUMBA_NUM_THREADS=1 python experiments/rl/comm_bounds.py --workers 2

Parts of a run can come from elsewhere: ``--frontier-rows`` takes the frontier rows that
``experiments/rl/comm_tasks.py --save-rows`` pickled (the same protocol run),
``--keep-references DIR ...`` the reference rows, episodes and trade-off of earlier runs
(relabelled; each row's continuation is in its ``knob`` column), and references are run
for the tasks no such folder holds. The committed results: the frontier of all nine
tasks; the references of the three tasks whose best decentralised rule became a
``settled`` rule (hence a new continuation) run again; those of the other six (whose
continuation did not change) and the trade-off (``comm_process_noise-v0``) kept; then
the upper bounds' policy table and the suite's references again::

    NUMBA_NUM_THREADS=1 python experiments/rl/comm_tasks.py --workers 2 --save-rows rows.pkl
    NUMBA_NUM_THREADS=1 python experiments/rl/comm_bounds.py --frontier-rows rows.pkl \\
        --tasks message_cost-v0 message_cost-v1 comm_schedule-v1 \\
        --tradeoff-task "" --workers 2 --out new
    NUMBA_NUM_THREADS=1 python experiments/rl/comm_bounds.py --frontier-rows rows.pkl \\
        --keep-references experiments/results/rl/comm_bounds new
    NUMBA_NUM_THREADS=1 python experiments/rl/upper_bounds.py --workers 2
    python experiments/rl/suite_references.py
"""

# %%
from __future__ import annotations

import argparse
import csv
import pickle
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense.benchmark import protocol as pr
from netsense.benchmark.headroom import headroom, markdown_headroom
from netsense.benchmark.kinds import reference_label
from netsense.benchmark.lookahead import LookaheadConfig

RESULTS = Path(__file__).resolve().parents[1] / "results" / "rl" / "comm_bounds"
TASKS = ("comm_process_noise-v0", "comm_substates-v0", "comm_channel_k2-v0",
         "message_cost-v0", "message_cost-v1", "comm_announced-v0", "comm_fading-v0",
         "comm_schedule-v0", "comm_schedule-v1")
_D = LookaheadConfig()
#: (kind, h, F, z, rounds) points of the trade-off study around the defaults (the
#: clairvoyant reference has one future, so F and z do not apply to it)
TRADEOFF = tuple(dict.fromkeys(
    [("causal", h, _D.futures, _D.confidence, _D.rounds) for h in (2, 4, 8, 16)]
    + [("causal", _D.horizon, f, _D.confidence, _D.rounds) for f in (1, 2, 4, 8, 16)]
    + [("causal", _D.horizon, _D.futures, 0.0, _D.rounds),
       ("causal", _D.horizon, _D.futures, _D.confidence, 1)]
    + [("clairvoyant", h, 1, 0.0, _D.rounds) for h in (2, 4, 8, 16)]
    + [("clairvoyant", _D.horizon, 1, 0.0, 1)]))
TRADEOFF_COLUMNS = ("task", "reference", "horizon", "futures", "confidence", "rounds",
                    "continuation", "episodes", "reward_mean", "reward_ci_low",
                    "reward_ci_high", "gain_vs_default", "gain_ci_low", "gain_ci_high",
                    "seconds_per_episode", "lane_steps_per_decision")


# %% The frontier with the references
def run_frontiers(tasks: Sequence[str], out: Path, episodes: int, reference_episodes: int,
                  overrides: dict | None = None, workers: int = 1) -> list[dict]:
    """:func:`netsense.benchmark.protocol.run_frontier` of ``tasks`` with both
    references."""
    return pr.run_frontier(tasks, out, episodes=episodes, overrides=overrides,
                           references=("causal", "clairvoyant"),
                           reference_episodes=reference_episodes,
                           reference_config=LookaheadConfig(), workers=workers)


def _references(tasks: Sequence[str], rows: Sequence[dict], episodes: int,
                overrides: dict | None, workers: int) -> dict[str, list[dict]]:
    """Both references of each of ``tasks`` continuing from its ``rows``
    (:func:`netsense.benchmark.protocol.reference_rows`), ``workers`` tasks at once."""
    jobs = [(t, [r for r in rows if r["scenario"] == t]) for t in tasks]
    if workers > 1 and len(jobs) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(min(workers, len(jobs)), mp_context=ctx) as pool:
            out = list(pool.map(_task_references, jobs, [episodes] * len(jobs),
                                [overrides] * len(jobs)))
    else:
        out = [_task_references(j, episodes, overrides) for j in jobs]
    return dict(zip(tasks, out, strict=True))


def _task_references(job, episodes, overrides) -> list[dict]:
    task, rows = job
    return pr.reference_rows(task, rows, reference_episodes=episodes,
                             reference_config=LookaheadConfig(), overrides=overrides)


def kept_references(folder: Path, tasks: Sequence[str]) -> list[dict]:
    """The reference rows of an earlier run written into ``folder`` (its ``frontier.csv``
    rows of kind ``reference``, or ``bound`` as they were once called, relabelled
    ``reference:KIND``; per-episode returns from its ``episodes.csv``; lane-steps per
    decision from its ``headroom.csv``), for ``--keep-references``: what they were computed
    with is in their ``knob`` (the continuation) and ``episodes``."""
    def rel(policy: str) -> str:
        return "reference:" + policy.partition(":")[2]

    with (folder / "frontier.csv").open() as fh:
        old = [r for r in csv.DictReader(fh) if r["scenario"] in tasks
               and r["kind"] in ("reference", "bound")]
    returns: dict[tuple[str, str], list[float]] = {}
    with (folder / "episodes.csv").open() as fh:
        for r in csv.DictReader(fh):
            returns.setdefault((r["scenario"], rel(r["policy"])), []).append(float(r["reward"]))
    lanes = {}
    with (folder / "headroom.csv").open() as fh:
        for r in csv.DictReader(fh):
            key = (r["scenario"], rel(r.get("reference", "") if "bound" not in r
                                      else r["bound"]))
            lanes[key] = float(r["lane_steps_per_decision"])
    rows = []
    for r in old:
        policy = rel(r["policy"])
        row = {c: r[c] for c in pr.CSV_COLUMNS}
        for c in pr.CSV_COLUMNS:
            if c.endswith(("_mean", "_ci_low", "_ci_high")) or c == "seconds":
                row[c] = float(r[c])
        row.update(kind="reference", family="reference", policy=policy, pareto="",
                   episodes=int(r["episodes"]), seed_first=int(r["seed_first"]),
                   seed_last=int(r["seed_last"]),
                   values={"reward": np.asarray(returns[r["scenario"], policy])},
                   cost={"lane_steps_per_decision": lanes.get((r["scenario"], policy),
                                                              float("nan"))})
        if len(row["values"]["reward"]) != row["episodes"]:
            raise ValueError(f"{folder}: episodes.csv holds {len(row['values']['reward'])} "
                             f"returns of {policy} on {r['scenario']}, frontier.csv "
                             f"{row['episodes']}")
        rows.append(row)
    return rows


def kept_tradeoff(folder: Path) -> list[dict]:
    """The trade-off rows of an earlier run (``tradeoff.csv``, the column ``bound`` as it
    was once called read as ``reference``), for ``--keep-references``."""
    with (folder / "tradeoff.csv").open() as fh:
        old = list(csv.DictReader(fh))
    ints = ("horizon", "futures", "rounds", "episodes")
    rows = []
    for r in old:
        ref = r.get("reference") or r["bound"]
        row = {c: (int(r[c]) if c in ints else r[c]) for c in TRADEOFF_COLUMNS
               if c != "reference"}
        for c in TRADEOFF_COLUMNS:
            if c not in ints + ("task", "reference", "continuation"):
                row[c] = float(r[c])
        row["reference"] = "reference:" + ref.partition(":")[2]
        rows.append(row)
    return rows


def write_reference_episodes(rows: Sequence[dict], path: Path) -> None:
    """``episodes.csv``: the references' return on each of their episodes (the first
    ``--reference-episodes`` evaluation seeds), for paired comparisons elsewhere (the
    learners' normalised scores in ``experiments/rl/learners.py``); ``policy`` is
    ``reference:causal`` or ``reference:clairvoyant``."""
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(("scenario", "policy", "episode", "seed", "reward"))
        for r in rows:
            if r["kind"] != "reference":
                continue
            for e, v in enumerate(r["values"]["reward"]):
                w.writerow((r["scenario"], r["policy"], e, int(r["seed_first"]) + e,
                            float(v)))


# %% The trade-off of the search
def tradeoff(task: str, continuation: tuple[str, ...], episodes: int,
             points: Sequence[tuple[str, int, int, float, int]] = TRADEOFF,
             overrides: dict | None = None) -> list[dict]:
    """Return and cost of the references at each ``(kind, h, F, z, rounds)`` of ``points`` on
    the first
    ``episodes`` evaluation seeds; the gain is paired against the default settings of the
    same kind (which ``points`` must hold)."""
    from tqdm.auto import tqdm

    seeds = pr.eval_seeds(episodes)
    over = pr.frontier_overrides(task, overrides)
    default = {"causal": ("causal", _D.horizon, _D.futures, _D.confidence, _D.rounds),
               "clairvoyant": ("clairvoyant", _D.horizon, 1, 0.0, _D.rounds)}
    runs = {}
    for kind, h, f, z, n in tqdm(points, desc=f"trade-off {task}"):
        cfg = LookaheadConfig(kind=kind, horizon=h, futures=f, confidence=z, rounds=n,
                          continuation=continuation)
        runs[kind, h, f, z, n] = pr._evaluate(task, f"reference:{kind}", seeds, over, cfg)
    rows = []
    for (kind, h, f, z, n), (vals, cost) in runs.items():
        ref = runs[default[kind]][0]
        mean, lo, hi = pr.bootstrap_ci(vals["reward"])
        g, glo, ghi = pr.bootstrap_ci(vals["reward"] - ref["reward"])
        rows.append({"task": task, "reference": f"reference:{kind}", "horizon": h, "futures": f,
                     "confidence": z, "rounds": n, "continuation": " + ".join(continuation),
                     "episodes": episodes, "reward_mean": mean, "reward_ci_low": lo,
                     "reward_ci_high": hi, "gain_vs_default": g, "gain_ci_low": glo,
                     "gain_ci_high": ghi, "seconds_per_episode": cost["seconds"] / episodes,
                     "lane_steps_per_decision": cost["lane_steps_per_decision"]})
    return rows


def write_tradeoff(rows: Sequence[dict], out: Path) -> None:
    """``tradeoff.csv``, ``tradeoff.md`` and ``tradeoff.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with (out / "tradeoff.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(TRADEOFF_COLUMNS)
        for r in rows:
            w.writerow([f"{r[c]:.6g}" if isinstance(r[c], float) else r[c]
                        for c in TRADEOFF_COLUMNS])
    lines = ["| reference | h | F | z | rounds | return | vs the defaults (paired) | "
             "s / episode | lane-steps / decision |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {reference_label(r['reference'])} | {r['horizon']} | {r['futures']} | "
                     f"{r['confidence']:g} | {r['rounds']} | "
                     f"{r['reward_mean']:.2f} [{r['reward_ci_low']:.2f}, "
                     f"{r['reward_ci_high']:.2f}] | {r['gain_vs_default']:+.2f} "
                     f"[{r['gain_ci_low']:+.2f}, {r['gain_ci_high']:+.2f}] | "
                     f"{r['seconds_per_episode']:.2f} | {r['lane_steps_per_decision']:.0f} |")
    (out / "tradeoff.md").write_text(
        f"{rows[0]['task']}, {rows[0]['episodes']} episodes, continuation "
        f"{rows[0]['continuation']}\n\n" + "\n".join(lines) + "\n")
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for kind, colour in (("reference:causal", "#b2182b"), ("reference:clairvoyant", "#762a83")):
        rs = [r for r in rows if r["reference"] == kind and r["rounds"] == _D.rounds and (
            kind == "reference:clairvoyant" or (r["futures"] == _D.futures
                                            and r["confidence"] == _D.confidence))]
        rs.sort(key=lambda r: r["horizon"])
        _errorbar(axes[0], [r["horizon"] for r in rs], rs, colour,
                  reference_label(kind) if kind == "reference:clairvoyant"
                  else f"{reference_label(kind)}, F = {_D.futures}")
    rs = sorted((r for r in rows if r["reference"] == "reference:causal"
                 and r["rounds"] == _D.rounds and r["horizon"] == _D.horizon
                 and r["confidence"] == _D.confidence),
                key=lambda r: r["futures"])
    _errorbar(axes[1], [r["futures"] for r in rs], rs, "#b2182b",
              f"{reference_label('reference:causal')}, h = {_D.horizon}")
    axes[0].set_xlabel("lookahead h (steps)")
    axes[1].set_xlabel("resampled futures F")
    for ax in axes:
        ax.set_xscale("log", base=2)
        ax.set_ylabel("episode return (mean over agents)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"{rows[0]['task']}: full-information references vs their search settings, "
                 f"{rows[0]['episodes']} episodes, 95 % bootstrap CI", fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "tradeoff.png", dpi=110)
    plt.close(fig)


def _errorbar(ax, x, rs, colour, label) -> None:
    y = np.array([r["reward_mean"] for r in rs])
    err = np.abs(np.array([[r["reward_ci_low"], r["reward_ci_high"]] for r in rs]).T - y)
    ax.errorbar(x, y, yerr=err, color=colour, marker="D", capsize=2, label=label)


# %% Main
def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", nargs="+", default=list(TASKS))
    p.add_argument("--episodes", type=int, default=pr.DEFAULT_EPISODES)
    p.add_argument("--reference-episodes", type=int, default=pr.DEFAULT_REFERENCE_EPISODES)
    p.add_argument("--tradeoff-task", default="comm_process_noise-v0")
    p.add_argument("--tradeoff-episodes", type=int, default=10)
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument("--smoke", action="store_true",
                   help="horizon 12, 3 episodes, 2 for the references and the trade-off")
    p.add_argument("--workers", type=int, default=1,
                   help="run the tasks' frontiers in this many processes")
    p.add_argument("--keep-references", type=Path, nargs="+", default=None, metavar="DIR",
                   help="take the reference rows and their episodes of the tasks an earlier "
                        "run in DIR holds (a later DIR first; relabelled), and the "
                        "trade-off of the first DIR that has one, instead of running them")
    p.add_argument("--frontier-rows", type=Path, default=None, metavar="FILE",
                   help="the frontier rows pickled by experiments/rl/comm_tasks.py "
                        "--save-rows (the same protocol run) instead of running the "
                        "frontier again")
    args = p.parse_args(argv)
    over = None
    if args.smoke:
        over = {"horizon": 12}
        args.episodes, args.reference_episodes, args.tradeoff_episodes = 3, 2, 2
    args.out.mkdir(parents=True, exist_ok=True)
    if args.frontier_rows is not None or args.keep_references:
        if args.frontier_rows is not None:
            with args.frontier_rows.open("rb") as fh:  # (a file this experiment wrote)
                rows = [r for r in pickle.load(fh) if r["scenario"] in args.tasks]
            if {r["scenario"] for r in rows} != set(args.tasks):
                raise ValueError(f"{args.frontier_rows} lacks some of {args.tasks}")
            if any(r["episodes"] != args.episodes for r in rows):
                raise ValueError(f"{args.frontier_rows}: not runs of {args.episodes} episodes")
        else:
            rows = pr.run_frontier(args.tasks, args.out, episodes=args.episodes,
                                   overrides=over, workers=args.workers)
        kept: dict[str, list[dict]] = {}
        for folder in args.keep_references or ():  # a later folder replaces a task's rows
            by_task: dict[str, list[dict]] = {}
            for r in kept_references(folder, args.tasks):
                by_task.setdefault(r["scenario"], []).append(r)
            kept.update(by_task)
        todo = [t for t in dict.fromkeys(args.tasks) if t not in kept]
        fresh = _references(todo, rows, args.reference_episodes, over, args.workers)
        rows = [r for t in dict.fromkeys(args.tasks) for r in
                [x for x in rows if x["scenario"] == t] + kept.get(t, fresh.get(t, []))]
        pr.write_frontiers(rows, args.out)
        trade = None
        if args.keep_references and args.tradeoff_task:
            trade = next((kept_tradeoff(f) for f in args.keep_references
                          if (f / "tradeoff.csv").is_file()), None)
    else:
        rows = run_frontiers(args.tasks, args.out, args.episodes, args.reference_episodes,
                             over, args.workers)
    write_reference_episodes(rows, args.out / "episodes.csv")
    print(markdown_headroom(headroom(rows)))
    if args.keep_references and trade:
        write_tradeoff(trade, args.out)
    elif args.tradeoff_task:
        cont = next(r["knob"] for r in rows if r["scenario"] == args.tradeoff_task
                    and r["policy"] == "reference:causal")
        trade = tradeoff(args.tradeoff_task, tuple(cont.split(" + ")),
                         args.tradeoff_episodes, overrides=over)
        write_tradeoff(trade, args.out)
        print((args.out / "tradeoff.md").read_text())
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
