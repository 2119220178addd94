"""Two training runs at once on two cores: how much each slows the other, with and without
the launcher's thread settings.

Every condition trains through :func:`netsense.rl.launch.launch` in spawned worker
processes (one per run), the runs of a condition started together; a run is MAPPO on
``--scenario`` (default ``comm_process_noise-v0``, N = 10) in the communication-only
``transmit`` mode, ``--iters`` iterations of 64 environments x 32 steps, evaluated only at
the end. Conditions:

=================  ==========================================================================
condition          what
=================  ==========================================================================
``alone``          one run; its process starts with one thread per pool (the launcher's
                   default, :data:`netsense.rl.launch.THREAD_VARS` = 1), one torch and one
                   numba thread (``PPOConfig`` defaults)
``pair``           two runs at once, as ``alone``: what ``netsense train --seeds 0 1
                   --workers 2`` does
``pair-env``       two runs at once, one torch and one numba thread (``PPOConfig``), but the
                   processes start with the caller's environment (``threads=None``): BLAS
                   and OpenMP pools one thread per core, as two ``netsense train`` commands
                   started side by side
``alone-unset``    one run, nothing set: torch's and numba's defaults (one thread per core)
``pair-unset``     two runs at once, nothing set
``alone-serial``   ``alone`` with collection and learning one after the other
                   (``PPOConfig.overlap = False``): every other condition overlaps them, a
                   second thread per run
``pair-serial``    two runs at once, as ``alone-serial``
=================  ==========================================================================

The thread variables of the caller are removed first, so each condition sets only its own.
Conditions run in turn within each of ``--rounds`` rounds (drifts of a shared machine hit
all alike). The figure per run is its agent-steps per second of training wall time
(collection, updates and the final evaluation; the process start and the environment's
construction are outside it). The slowdown of a pair is ``alone``'s throughput (same
round) over each of its runs', so 1.0 means two runs cost nothing to each other; on two
cores that is the aim.

Writes ``bench_parallel_runs.csv`` (one row per run), ``.txt`` (per condition: median,
min and max throughput and slowdown) and ``.png`` into ``--out``::

    python experiments/bench/parallel_runs.py             # about 3 minutes on 2 cores
    python experiments/bench/parallel_runs.py --smoke --out /tmp/x   # plumbing, no timing
"""

# %%
from __future__ import annotations

import argparse
import csv
import os
import statistics
import tempfile
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1] / "results" / "bench" / "parallel_runs"
#: condition -> (runs at once, launcher threads, PPOConfig torch / numba threads,
#: PPOConfig.overlap)
CONDITIONS = {
    "alone": (1, 1, 1, True),
    "pair": (2, 1, 1, True),
    "pair-env": (2, None, 1, True),
    "alone-unset": (1, None, None, True),
    "pair-unset": (2, None, None, True),
    "alone-serial": (1, 1, 1, False),
    "pair-serial": (2, 1, 1, False),
}
#: The reference of each condition's slowdown.
REFERENCE = {"alone": "alone", "pair": "alone", "pair-env": "alone",
             "alone-unset": "alone-unset", "pair-unset": "alone-unset",
             "alone-serial": "alone-serial", "pair-serial": "alone-serial"}
COLUMNS = ("round", "condition", "run", "runs_at_once", "launcher_threads", "torch_threads",
           "numba_threads", "overlap", "agent_steps", "wall_s", "agent_steps_per_s", "collect_s",
           "learn_s", "loadavg")


# %% One condition
def measure(condition: str, scenario: str, iters: int, num_envs: int, rollout: int,
            rnd: int) -> list[dict]:
    """Train the condition's runs at once; one row per run."""
    from netsense.rl.config import PPOConfig
    from netsense.rl.launch import launch, make_runs

    at_once, threads, lib_threads, overlap = CONDITIONS[condition]
    cfg = PPOConfig(scenario, control="transmit", num_envs=num_envs, rollout=rollout,
                    steps=iters * num_envs * rollout * 10, eval_interval=0, eval_envs=8,
                    torch_threads=lib_threads, numba_threads=lib_threads, overlap=overlap)
    with tempfile.TemporaryDirectory() as tmp:
        summary = launch(make_runs(cfg, range(at_once)), tmp, workers=2, threads=threads,
                         progress=False)
        rows = []
        for e in summary:
            if e["status"] != "ok":
                raise RuntimeError(f"{condition}: run {e['folder']} failed: {e['error']}")
            with open(Path(tmp) / e["folder"] / "log.csv") as fh:
                last = list(csv.DictReader(fh))[-1]
            rows.append({"round": rnd, "condition": condition, "run": e["seed"],
                         "runs_at_once": at_once, "launcher_threads": threads or "",
                         "torch_threads": lib_threads or "", "numba_threads": lib_threads or "",
                         "overlap": overlap, "agent_steps": e["agent_steps"], "wall_s": e["wall_s"],
                         "agent_steps_per_s": e["agent_steps_per_s"],
                         "collect_s": last["collect_s"], "learn_s": last["learn_s"],
                         "loadavg": round(os.getloadavg()[0], 2)})
    return rows


# %% Summary
def report(rows: list[dict]) -> list[str]:
    """Per condition: median (min - max) throughput and slowdown against its reference
    measured in the same round."""
    ref = {(r["round"], r["condition"]): float(r["agent_steps_per_s"]) for r in rows
           if r["runs_at_once"] == 1}
    lines = ["condition     runs  agent-steps/s per run: median (min - max)   slowdown "
             "vs reference: median (min - max)"]
    for cond in CONDITIONS:
        mine = [r for r in rows if r["condition"] == cond]
        if not mine:
            continue
        sps = [float(r["agent_steps_per_s"]) for r in mine]
        slow = [ref[(r["round"], REFERENCE[cond])] / float(r["agent_steps_per_s"])
                for r in mine if (r["round"], REFERENCE[cond]) in ref]
        text = (f"{statistics.median(slow):.2f} ({min(slow):.2f} - {max(slow):.2f}) vs "
                f"{REFERENCE[cond]}" if slow else "-")
        lines.append(f"{cond:<13} {len(mine):>4}  {statistics.median(sps):>9.0f} "
                     f"({min(sps):.0f} - {max(sps):.0f}){'':>14}{text}")
    return lines


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    conds = [c for c in CONDITIONS if any(r["condition"] == c for r in rows)]
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for i, c in enumerate(conds):
        ys = [float(r["agent_steps_per_s"]) / 1e3 for r in rows if r["condition"] == c]
        ax.bar(i, statistics.median(ys), color="tab:blue" if "pair" in c else "tab:gray")
        ax.plot([i] * len(ys), ys, "k.", ms=4)
    ax.set_xticks(range(len(conds)), conds)
    ax.set_ylabel("agent-steps/s per run (thousands)")
    ax.set_title("Training runs at once on 2 cores (bars: median; dots: runs)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# %% Main
def main(argv: list[str] | None = None) -> Path:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="comm_process_noise-v0")
    p.add_argument("--iters", type=int, default=20, help="PPO iterations per run")
    p.add_argument("--num-envs", type=int, default=64)
    p.add_argument("--rollout", type=int, default=32)
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--conditions", nargs="+", choices=tuple(CONDITIONS),
                   default=list(CONDITIONS))
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument("--smoke", action="store_true",
                   help="one round of alone at a tiny size (plumbing, no timing)")
    args = p.parse_args(argv)
    if args.smoke:
        args.iters, args.num_envs, args.rollout, args.rounds = 1, 4, 8, 1
        args.conditions = ["alone"]
    from tqdm.auto import tqdm

    from netsense.rl.launch import THREAD_VARS

    saved = {k: os.environ.pop(k) for k in THREAD_VARS if k in os.environ}
    rows: list[dict] = []
    todo = [(r, c) for r in range(args.rounds) for c in args.conditions]
    try:  # each condition sets only its own thread variables
        for rnd, cond in tqdm(todo, desc="conditions", unit="condition"):
            rows += measure(cond, args.scenario, args.iters, args.num_envs, args.rollout, rnd)
    finally:
        os.environ.update(saved)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "bench_parallel_runs.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    lines = report(rows)
    head = (f"{args.scenario}, transmit mode, {args.iters} iterations of {args.num_envs} x "
            f"{args.rollout} env-steps per run, {args.rounds} round(s), "
            f"{os.cpu_count()} CPUs")
    (args.out / "bench_parallel_runs.txt").write_text("\n".join([head, *lines]) + "\n")
    plot(rows, args.out / "bench_parallel_runs.png")
    print(head, *lines, sep="\n")
    return path


if __name__ == "__main__":
    main()
