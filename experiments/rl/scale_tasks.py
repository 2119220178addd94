"""The communication tasks at scale: the scripted frontier of the K-of-N channel and the
spatial tasks at N = 50, 200 and 1000 agents.

``python experiments/rl/scale_tasks.py --workers 2`` (a few minutes on 2 cores;
``--scenarios`` / ``--episodes`` / ``--horizon`` shrink it) writes into
``experiments/results/rl/scale_tasks/``:

1. **Frontier** of each task (:func:`netsense.benchmark.protocol.frontier` on the
   protocol's evaluation seeds :func:`~netsense.benchmark.protocol.eval_seeds`, the
   episodes of :data:`EPISODES`: fewer where one run of all of them costs minutes), with
   the decentralised families of :func:`scale_families` (those of
   :data:`netsense.benchmark.protocol.FAMILIES` at knobs scaled to ``N`` and the channel's
   ``K``: ``periodic:5`` is a round robin of ``N / 5`` senders per step), ``always``,
   ``never`` and the privileged ``oracle`` over two base rules, and the centralised
   schedulers of :func:`scheduler_families` (``oldest:K``, ``whittle:K``) on the first
   :data:`SCHEDULER_EPISODES` of the same seeds (their cost grows as ``N^2``; the
   ``episodes`` column says how many); no informed rule applies (the tasks' observations
   carry neither ``next_out`` nor ``acks``), and ``settled`` is not run at scale (its
   gain is the transient of a source's own observer, measured on the tasks of
   ``experiments/rl/settled_rule.py``): ``frontier_<task>.csv/.png``,
   ``frontier.csv``, ``frontier.md``.
2. **Summary** (``summary.csv``, ``summary.md``): per task, ``always``, ``never``, the best
   decentralised rule, the best privileged rule and the best centralised scheduler, the
   last also as the task's **reference**: the certified upper bound
   (:mod:`netsense.benchmark.upper_bound`) does not scale to these tasks (one episode of
   ``comm_channel_kofn_n50-v0`` at horizon 20 takes minutes; its linear program grows as
   ``N M H W``) and the lookahead references fork the core per agent and step, so the
   centralised age-based scheduler, which reads every agent's state, is the
   full-information reference of every task here.
3. **Plot** ``scale_tasks.png``: return per agent-step of each of those rows against ``N``,
   one panel per family of tasks.

Every file is written atomically (:mod:`netsense.rl.atomic`).
"""

# %%
from __future__ import annotations

import argparse
import csv
import math
import time
from pathlib import Path

from netsense.rl.atomic import atomic_path, write_atomic

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments/results/rl/scale_tasks"
#: Tasks and the evaluation episodes of their decentralised and privileged rules (the
#: first seeds of the protocol's evaluation seeds).
EPISODES = {
    "comm_channel_kofn_n50-v0": 100,
    "comm_channel_kofn_n200-v0": 100,
    "comm_channel_kofn_n1000-v0": 20,
    "comm_spatial_n50-v0": 100,
    "comm_spatial_n200-v0": 50,
}
#: Episodes of the centralised schedulers (the first of the same seeds): a scheduler step
#: ranks every sender by its age reduction over every receiver, ``N^2 M`` per member and
#: step (about 0.3 s per member-step at ``N = 1000``, 12 ms at ``N = 200``).
SCHEDULER_EPISODES = {
    "comm_channel_kofn_n50-v0": 100,
    "comm_channel_kofn_n200-v0": 20,
    "comm_channel_kofn_n1000-v0": 3,
    "comm_spatial_n50-v0": 100,
    "comm_spatial_n200-v0": 20,
}
#: Base rules of the privileged ``oracle`` rows.
ORACLE_BASES = ("sources:0", "event:2")
#: Rows of the summary, in order (the best centralised scheduler is also the reference).
WHAT = ("always", "never", "best decentralised", "best privileged", "best centralised")


# %% the knobs at scale
def _size(scenario: str) -> tuple[int, int | None]:
    """``N`` and the channel's capacity ``K`` (None without a channel)."""
    from netsense.env.vector import load_model

    model, _ = load_model(scenario)
    return model.plant.num_agents, (model.channel.capacity if model.channel is not None
                                    else None)


def scale_families(scenario: str) -> dict[str, tuple]:
    """The decentralised families of the frontier at knobs scaled to the task's ``N``.

    ``periodic:P`` and ``sources:P`` send ``N / P`` relays per step (``periodic:5``: a round
    robin of ``N / 5`` senders, the channel tasks' ``K``); ``bernoulli:p`` spans the same
    loads; ``event:d`` does not depend on ``N``; ``tdma`` only where there is a channel.
    """
    _, K = _size(scenario)
    fams: dict[str, tuple] = {
        "periodic": (5, 10, 20),
        "bernoulli": (0.2, 0.1),
        "sources": (0, 5, 10),
        "event": (1, 2, 4, 8),
    }
    if K is not None:
        fams["tdma"] = (1, 2)
    return fams


def scheduler_families(scenario: str) -> dict[str, tuple]:
    """The centralised schedulers: ``oldest:m`` and ``whittle:m`` with ``m = K`` senders per
    step (``N / 5`` without a channel); at ``N = 1000`` only ``oldest`` (the two share
    their cost, :data:`SCHEDULER_EPISODES`)."""
    N, K = _size(scenario)
    m = K if K is not None else N // 5
    return {"oldest": (m,)} if N >= 1000 else {"oldest": (m,), "whittle": (m,)}


# %% one task
def run_task(scenario: str, episodes: int, scheduler_episodes: int,
             horizon: int | None = None, progress: bool = False
             ) -> tuple[list[dict], float]:
    """The frontier rows of one task (the schedulers on their own episodes) and the
    seconds they took."""
    from netsense.benchmark.protocol import frontier, pareto_front

    t0 = time.perf_counter()
    over = {} if horizon is None else {"horizon": horizon}
    rows = frontier(scenario, episodes=episodes, families=scale_families(scenario),
                    informed_bases=ORACLE_BASES, privileged=True, overrides=over,
                    progress=progress, settled_bases=())
    sched = frontier(scenario, episodes=min(scheduler_episodes, episodes),
                     families=scheduler_families(scenario), informed_bases=(),
                     privileged=False, overrides=over, progress=progress,
                     settled_bases=())
    rows += [r for r in sched if r["kind"] == "centralised"]
    front = [r for r in rows if r["kind"] in ("decentralised", "centralised")]
    for r, p in zip(front, pareto_front(front), strict=True):
        r["pareto"] = p
    return rows, time.perf_counter() - t0


def _task(args: tuple) -> tuple[list[dict], float]:
    return run_task(*args)


# %% summary
def summarise(scenario: str, rows: list[dict], seconds: float,
              horizon: int | None = None) -> list[dict]:
    """``always``, ``never`` and the best row of each kind (:data:`WHAT`) of one task
    (``horizon``: the one the rows ran with, if not the task's)."""
    from netsense.env.vector import load_model

    model, _ = load_model(scenario)
    N = model.plant.num_agents
    K = model.channel.capacity if model.channel is not None else ""

    def best(kind):
        rs = [r for r in rows if r["kind"] == kind]
        return max(rs, key=lambda r: r["reward_mean"]) if rs else None

    picks = {"always": next(r for r in rows if r["policy"] == "always"),
             "never": next(r for r in rows if r["policy"] == "never"),
             "best decentralised": best("decentralised"),
             "best privileged": best("privileged"),
             "best centralised": best("centralised")}
    H = horizon or model.horizon
    out = []
    for what in WHAT:
        r = picks[what]
        if r is None:
            continue
        out.append({"scenario": scenario, "N": N, "K": K, "horizon": H,
                    "episodes": r["episodes"], "what": what,
                    "reference": "yes" if what == "best centralised" else "",
                    "kind": r["kind"], "policy": r["policy"],
                    "reward_mean": r["reward_mean"], "reward_ci_low": r["reward_ci_low"],
                    "reward_ci_high": r["reward_ci_high"],
                    "per_agent_step": r["reward_mean"] / H,
                    "error": r["mean_rel_error_mean"],
                    "msgs": r["msgs_per_agent_step_mean"], "task_seconds": seconds})
    return out


def _fmt(v) -> str:
    if isinstance(v, float):
        return "nan" if not math.isfinite(v) else f"{v:.6g}"
    return str(v)


def write_summary(summary: list[dict], out: Path) -> None:
    """``summary.csv`` and ``summary.md`` (atomically)."""
    cols = list(summary[0])
    with atomic_path(out / "summary.csv") as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in summary:
            w.writerow([_fmt(r[c]) for c in cols])
    lines = ["| task | N | K | episodes | what | kind | policy | return [95 % CI] | "
             "error | msgs / agent-step |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in summary:
        what = r["what"] + (" (reference)" if r["reference"] else "")
        lines.append(f"| {r['scenario']} | {r['N']} | {r['K'] or '–'} | {r['episodes']} | "
                     f"{what} | {r['kind']} | `{r['policy']}` | {r['reward_mean']:.1f} "
                     f"[{r['reward_ci_low']:.1f}, {r['reward_ci_high']:.1f}] | "
                     f"{r['error']:.3f} | {r['msgs']:.3f} |")
    secs = {r["scenario"]: r["task_seconds"] for r in summary}
    lines += ["", "Run time per task (s): " + ", ".join(f"{s} {t:.0f}"
                                                       for s, t in secs.items())]
    write_atomic(out / "summary.md", "\n".join(lines) + "\n")


def plot(summary: list[dict], path: Path) -> None:
    """Return per agent-step of the summary's rows against ``N``, one panel per family."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fams = list(dict.fromkeys(r["scenario"].rsplit("_n", 1)[0] for r in summary))
    fig, axes = plt.subplots(1, len(fams), figsize=(5.2 * len(fams), 4), squeeze=False)
    style = {"always": ("C3", "x"), "never": ("C7", "s"), "best decentralised": ("C0", "o"),
             "best privileged": ("C1", "^"), "best centralised": ("C2", "D")}
    for ax, fam in zip(axes[0], fams, strict=True):
        mine = [r for r in summary if r["scenario"].rsplit("_n", 1)[0] == fam]
        for what, (color, marker) in style.items():
            pts = sorted((r["N"], r["per_agent_step"]) for r in mine if r["what"] == what)
            if pts:
                label = what + (" (reference)" if what == "best centralised" else "")
                ax.plot([p[0] for p in pts], [p[1] for p in pts], color=color,
                        marker=marker, label=label)
        ax.set_xscale("log")
        ax.set_xlabel("agents N")
        ax.set_ylabel("return per agent-step")
        ax.set_title(fam)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


# %%
def main(argv: list[str] | None = None) -> list[dict]:
    """Run the tasks, write the outputs, print the summary table."""
    from tqdm.auto import tqdm

    from netsense.benchmark.protocol import write_frontiers

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=list(EPISODES))
    ap.add_argument("--episodes", type=int, default=None,
                    help="episodes of every task and scheduler (default: EPISODES, "
                         "SCHEDULER_EPISODES)")
    ap.add_argument("--horizon", type=int, default=None,
                    help="override the tasks' horizon (smoke runs)")
    ap.add_argument("--workers", type=int, default=1, help="tasks run at once (processes)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    jobs = [(sc, args.episodes or EPISODES.get(sc, 100),
             args.episodes or SCHEDULER_EPISODES.get(sc, 20), args.horizon)
            for sc in dict.fromkeys(args.scenarios)]
    bar = tqdm(total=len(jobs), desc="scale tasks", unit="task", disable=args.no_progress)
    results: dict[str, tuple[list[dict], float]] = {}
    if args.workers > 1 and len(jobs) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(min(args.workers, len(jobs)), mp_context=ctx) as pool:
            big_first = sorted(jobs, key=lambda job: -_size(job[0])[0])  # the slowest first
            futs = {pool.submit(_task, job): job[0] for job in big_first}
            for fut in as_completed(futs):
                results[futs[fut]] = fut.result()
                bar.update()
    else:
        for job in jobs:
            results[job[0]] = run_task(*job, progress=not args.no_progress)
            bar.update()
    bar.close()
    rows = [r for sc, *_ in jobs for r in results[sc][0]]
    write_frontiers(rows, args.out)
    summary = [s for sc, *_ in jobs for s in summarise(sc, *results[sc], args.horizon)]
    write_summary(summary, args.out)
    plot(summary, args.out / "scale_tasks.png")
    print((args.out / "summary.md").read_text())
    return summary


if __name__ == "__main__":
    main()
