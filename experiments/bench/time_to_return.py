"""Return against wall-clock time at the training benchmark's grid points: which
``num_envs:minibatch`` trains the best policy in a given time, and where the command line's
defaults stand.

The throughput benchmark (``train_throughput.py``) ranks its grid points by agent-steps per
second. A larger minibatch takes fewer gradient steps per agent-step, so the fastest point
also learns the least per sample. This script ranks the same points by what a user trains
for, the return reached in a given time, from two committed measurements, without training
anything:

* **the learning**: the from-scratch runs of ``experiments/rl/learners.py`` in ``--runs``
  (default ``experiments/results/rl/learners/batch_10m``: the recipe ``mlp`` at the command
  line's 256 environments and minibatches of 2048 env-steps; ``mlp_512``, ``mlp_1024``,
  ``mlp_1024_lr`` (the same with twice the learning rate) and ``mlp_fast`` at the grid's
  larger points; five seeds of 10M agent-steps each on ``comm_process_noise-v0`` and on
  ``message_cost-v0`` with the transmit bit). Per run, the greedy return of its periodic
  evaluation during training (``log.csv``'s ``eval_return``: 32 validation episodes seeded
  from 10^9, apart from the training seeds and from the protocol's test seeds; every 6
  iterations, so every 0.49M agent-steps at 256 environments and every 1.97M at 1024);
* **the speed**: per task, a throughput benchmark CSV (``--throughput TASK=CSV``): the median
  agent-steps/s of its tuned path at the run's ``num_envs:minibatch`` (read from the run's
  ``config.json``), every grid point measured in one run, in interleaved rounds, with the
  command line's thread settings (the ``mlp`` runs trained on one torch thread; the thread
  count changes a run's speed, not what it learns per agent-step).

An evaluation at ``x`` agent-steps happened after ``x / rate`` seconds of training at the
benchmark's rate for the run's grid point (the runs' own wall times were measured under
varying load, and are not used). Per task, the budget ``W`` is the shortest time a learner
takes for its whole run, so that every learner's runs cover it. At ``W / 4``, ``W / 2`` and
``W``, each run's latest evaluation within the budget (the policy a user would hold by
then): the interquartile mean (IQM) over the seeds with a 95 % stratified-bootstrap interval
and the probability that the defaults' learner returns more than the other (rliable). The
best settings at a budget are the learner with the highest IQM there.

Writes ``time_to_return.csv`` (one row per task, learner and budget),
``time_to_return.txt`` and ``time_to_return.png`` (the runs folder's learning curves,
``curves.csv``: IQM against agent-steps with its band, which ``learners.py`` computes, here
against seconds; with the best decentralised scripted policy on the same validation episodes
and the causal bound on the test episodes, from its ``curve_refs.csv``) into ``--out``::

    python experiments/bench/time_to_return.py          # about 10 seconds

The default throughput CSVs are the throughput benchmark's committed run
(``python experiments/bench/train_throughput.py``) and its grid on ``message_cost-v0`` in the
learners' control mode (``python experiments/bench/train_throughput.py --comm-scenario
message_cost-v0 --comm-control transmit --paths torchrl-defaults-tx torchrl-tuned-tx --tag
message_cost-v0``).
"""

# %%
from __future__ import annotations

import argparse
import csv
import json
import statistics
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments" / "results" / "bench" / "time_to_return"
THROUGHPUT = ROOT / "experiments" / "results" / "bench" / "train_throughput"
RUNS = ROOT / "experiments" / "results" / "rl" / "learners" / "batch_10m"
#: the budgets, as fractions of W
FRACTIONS = (0.25, 0.5, 1.0)


def _task_csv(text: str) -> tuple[str, Path]:
    task, sep, path = text.partition("=")
    if not sep or not task or not path:
        raise argparse.ArgumentTypeError(f"--throughput: TASK=CSV, got {text!r}")
    return task, Path(path)


def main(argv: list[str] | None = None) -> Path:
    """Read, combine, write; returns the CSV path."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=Path, default=RUNS,
                   help="a results folder of experiments/rl/learners.py (runs/<task>/"
                        "<learner>/seed_<s>/)")
    p.add_argument("--throughput", type=_task_csv, nargs="+", metavar="TASK=CSV",
                   default=[("comm_process_noise-v0",
                             THROUGHPUT / "bench_train_throughput.csv"),
                            ("message_cost-v0", THROUGHPUT / "message_cost-v0.csv")],
                   help="per task, the throughput benchmark's CSV whose tuned path measured "
                        "that task's grid points")
    p.add_argument("--defaults", default="mlp",
                   help="the learner trained at the command line's defaults")
    p.add_argument("--path", default="torchrl-tuned-tx",
                   help="the throughput CSV's path that holds the grid points")
    p.add_argument("--out", type=Path, default=RESULTS)
    args = p.parse_args(argv)
    rates = {}
    for task, path in args.throughput:
        if not path.is_file():
            p.error(f"--throughput {task}: no file {path}")
        rates[task] = grid_rates(path, args.path)
        if not rates[task]:
            p.error(f"--throughput {task}: {path} has no rows of path {args.path!r}")
    runs = read_runs(args.runs, list(rates))
    if not (args.runs / "curves.csv").is_file():
        p.error(f"--runs: no curves.csv in {args.runs} (python experiments/rl/learners.py "
                f"summary --out {args.runs} writes it)")
    for task in rates:
        if args.defaults not in runs.get(task, {}):
            p.error(f"--runs: no runs of learner {args.defaults!r} on {task} in {args.runs}")
        missing = sorted({lr["point"] for lr in runs[task].values()} - set(rates[task]))
        if missing:
            p.error(f"--throughput {task}: no rate for num_envs:minibatch "
                    f"{', '.join(f'{b}:{m}' for b, m in missing)}")
    rows = budgets(runs, rates, args.defaults)
    args.out.mkdir(parents=True, exist_ok=True)
    csv_path = args.out / "time_to_return.csv"
    with csv_path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    text = report(rows, args)
    (args.out / "time_to_return.txt").write_text(text)
    print(text, end="")
    plot(runs, rates, rows, _curves(args.runs), _refs(args.runs),
         args.out / "time_to_return.png")
    return csv_path


# %% reading
def grid_rates(path: Path, which: str) -> dict[tuple[int, int], float]:
    """``(num_envs, minibatch) -> median agent-steps/s`` of the CSV's rows of path ``which``."""
    got: dict[tuple[int, int], list[float]] = {}
    with path.open() as fh:
        for r in csv.DictReader(fh):
            if r["path"] == which:
                got.setdefault((int(r["num_envs"]), int(r["minibatch"])), []).append(
                    float(r["agent_steps_per_s"]))
    return {k: statistics.median(v) for k, v in got.items()}


def read_runs(folder: Path, tasks: list[str]) -> dict:
    """``{task: {learner: {"point": (num_envs, minibatch), "lr": float, "evals": [(agent
    steps, greedy validation return), ...] per seed}}}`` of ``folder/runs``' finished runs."""
    out: dict = {}
    for task in tasks:
        for ld in sorted((folder / "runs" / task).glob("*/")):
            # finished runs only (a run writes its summary.json last)
            seeds = sorted(s.parent / "log.csv" for s in ld.glob("seed_*/summary.json"))
            if not seeds:
                continue
            cfgs = [json.loads((s.parent / "config.json").read_text()) for s in seeds]
            points = {(int(c["num_envs"]), int(c["minibatch"])) for c in cfgs}
            if len(points) != 1:
                raise ValueError(f"{ld}: the seeds' runs differ in num_envs:minibatch "
                                 f"({sorted(points)})")
            evals = []
            for s in seeds:
                with s.open() as fh:
                    evals.append([(int(r["agent_steps"]), float(r["eval_return"]))
                                  for r in csv.DictReader(fh) if r.get("eval_return")])
                if not evals[-1]:
                    raise ValueError(f"{s}: no evaluation during training (eval_interval 0)")
            out.setdefault(task, {})[ld.name] = {"point": points.pop(),
                                                 "lr": float(cfgs[0]["lr"]), "evals": evals}
        if task in out:  # in the grid's order: num_envs, minibatch, then learning rate
            out[task] = dict(sorted(out[task].items(),
                                    key=lambda kv: (kv[1]["point"], kv[1]["lr"], kv[0])))
    return out


def _curves(folder: Path) -> dict:
    """``{task: {learner: (agent_steps, iqm, ci_low, ci_high)}}`` (arrays) of the learning
    curves in ``curves.csv``."""
    got: dict = {}
    with (folder / "curves.csv").open() as fh:
        for r in csv.DictReader(fh):
            got.setdefault(r["task"], {}).setdefault(r["learner"], []).append(
                [float(r[k]) for k in ("agent_steps", "iqm", "ci_low", "ci_high")])
    return {t: {ln: tuple(np.array(v).T) for ln, v in d.items()} for t, d in got.items()}


def _refs(folder: Path) -> dict:
    """``{task: {policy: (spec, episodes, return)}}`` of ``curve_refs.csv`` (empty without)."""
    path = folder / "curve_refs.csv"
    out: dict = {}
    if path.is_file():
        with path.open() as fh:
            for r in csv.DictReader(fh):
                out.setdefault(r["task"], {})[(r["policy"], r["episodes"])] = (
                    r["spec"], float(r["return"]))
    return out


# %% the comparison
def _intervals(scores: dict, func, reps: int) -> tuple[dict, dict]:
    """rliable's point estimates and 95 % stratified-bootstrap intervals, the same on every
    run (NumPy's global generator seeded: ``seeded_global_rng``)."""
    from rliable import library as rly

    from netsense.benchmark.intervals import seeded_global_rng

    with seeded_global_rng(), warnings.catch_warnings():
        # arch deprecates random_state; the resamples come from the seeded global
        # generator either way
        warnings.simplefilter("ignore", FutureWarning)
        return rly.get_interval_estimates(scores, func, reps=reps,
                                          random_state=np.random.RandomState(0))


def latest_within(evals: list[tuple[int, float]], steps: float) -> tuple[int, float] | None:
    """The last evaluation at or before ``steps`` agent-steps (``None`` if there is none)."""
    before = [e for e in evals if e[0] <= steps]
    return before[-1] if before else None


def budgets(runs: dict, rates: dict, defaults: str) -> list[dict]:
    """Per task, learner and budget ``f * W``: the learner's seeds' latest evaluations within
    the budget, their IQM with a 95 % interval, and P(defaults > learner). A learner with a
    seed not yet evaluated by the budget has no return there (NaN, never the best)."""
    from rliable import metrics

    rows = []
    for task, learners in runs.items():
        rate = {ln: rates[task][lr["point"]] for ln, lr in learners.items()}
        W = min(min(e[-1][0] for e in lr["evals"]) / rate[ln] for ln, lr in learners.items())
        for f in FRACTIONS:
            at = {}
            for ln, lr in learners.items():
                got = [latest_within(e, f * W * rate[ln]) for e in lr["evals"]]
                if None not in got:
                    at[ln] = (np.array([g[1] for g in got])[:, None], [g[0] for g in got])
            best = max(at, key=lambda ln: metrics.aggregate_iqm(at[ln][0]))
            for ln, lr in learners.items():
                row = {"task": task, "learner": ln, "num_envs": lr["point"][0],
                       "minibatch": lr["point"][1], "lr": lr["lr"],
                       "agent_steps_per_s": rate[ln], "budget": f, "seconds": round(f * W, 2),
                       "agent_steps": 0, "seeds": len(lr["evals"]), "iqm": float("nan"),
                       "ci_low": float("nan"), "ci_high": float("nan"),
                       "p_defaults_better": "", "defaults": ln == defaults, "best": ln == best}
                if ln in at:
                    scores, steps = at[ln]
                    point, ci = _intervals({"x": scores},
                                           lambda s: np.array([metrics.aggregate_iqm(s)]), 2000)
                    row.update(agent_steps=int(np.mean(steps)), iqm=float(point["x"][0]),
                               ci_low=float(ci["x"][0, 0]), ci_high=float(ci["x"][1, 0]))
                    if ln != defaults and defaults in at:
                        row["p_defaults_better"] = float(
                            metrics.probability_of_improvement(at[defaults][0], scores))
                rows.append(row)
    return rows


# %% output
def _rel(path: Path) -> str:
    full = path.resolve()
    return str(full.relative_to(ROOT) if full.is_relative_to(ROOT) else path)


def _line(r: dict) -> str:
    tag = (" (defaults)" if r["defaults"] else "") + (" best" if r["best"] else "")
    p_ = "" if r["p_defaults_better"] == "" else f"{r['p_defaults_better']:.2f}"
    head = (f"    {r['learner']:<13}{r['num_envs']:>8}:{r['minibatch']:<6}"
            f"{r['agent_steps_per_s']:>15,.0f}")
    if not np.isfinite(r["iqm"]):
        return f"{head}   no evaluation of every seed within the budget{tag}"
    ci = f"[{r['ci_low']:.1f}, {r['ci_high']:.1f}]"
    return (f"{head}{r['agent_steps'] / 1e6:>12.2f}M   "
            f"{r['iqm']:>7.1f} {ci:<18}{p_:>5}{tag}")


def report(rows: list[dict], args) -> str:
    """The text summary: per task and budget, a table; and the defaults' standing at W."""
    lines = [f"# runs: {_rel(args.runs)}; throughput: the {args.path} rows of "
             + ", ".join(f"{t}={_rel(p)}" for t, p in args.throughput),
             "# greedy validation return, each seed's latest evaluation within the budget; "
             "IQM over the seeds [95 % stratified-bootstrap CI]; P = P(defaults > learner)"]
    for task in dict.fromkeys(r["task"] for r in rows):
        mine = [r for r in rows if r["task"] == task]
        lines += ["", f"{task}: W = {max(r['seconds'] for r in mine):.1f} s (the shortest "
                      f"time a learner takes for its whole run)"]
        for f in FRACTIONS:
            at = [r for r in mine if r["budget"] == f]
            lines += [f"  budget {f:g} W = {at[0]['seconds']:.1f} s",
                      f"    {'learner':<13}{'envs:minibatch':>15}{'agent-steps/s':>15}"
                      f"{'agent-steps':>13}   {'IQM [95 % CI]':<26}{'P':>5}"]
            lines += [_line(r) for r in at]
        final = [r for r in mine if r["budget"] == 1.0]
        best = next(r for r in final if r["best"])
        dflt = next(r for r in final if r["defaults"])
        fast = max(final, key=lambda r: r["agent_steps_per_s"])
        lines.append(
            f"  best settings at W: {best['learner']} ({best['num_envs']}:{best['minibatch']}, "
            f"{best['agent_steps_per_s']:,.0f} agent-steps/s); defaults / best settings, "
            f"agent-steps/s: {dflt['agent_steps_per_s'] / best['agent_steps_per_s']:.2f}x; "
            f"fastest grid point {fast['learner']} ({fast['num_envs']}:{fast['minibatch']}): "
            f"{fast['agent_steps_per_s'] / dflt['agent_steps_per_s']:.2f}x the defaults' "
            f"agent-steps/s, IQM at W {fast['iqm']:.1f} against the defaults' {dflt['iqm']:.1f}")
    return "\n".join(lines) + "\n"


def plot(runs: dict, rates: dict, rows: list[dict], curves: dict, refs: dict,
         path: Path) -> None:
    """The learning curves (IQM of the greedy validation return with its 95 %
    stratified-bootstrap band, :func:`_curves`) against seconds of training, per task; a
    learner without a curve is left out of the plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(runs)
    fig, axes = plt.subplots(1, len(tasks), figsize=(5.6 * len(tasks), 4.0), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        W = max(r["seconds"] for r in rows if r["task"] == task)
        for ln, lr in runs[task].items():
            if ln not in curves.get(task, {}):
                continue
            steps, iqm, lo, hi = curves[task][ln]
            x = steps / rates[task][lr["point"]]
            b, m = lr["point"]
            line, = ax.plot(x, iqm, "-", lw=1.4, label=f"{ln} ({b}:{m})")
            ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.15, lw=0)
        for (policy, episodes), (spec, ret) in refs.get(task, {}).items():
            if policy == "best_decentralised" and episodes == "validation":
                ax.axhline(ret, color="k", ls="--", lw=1.1,
                           label=f"best decentralised scripted ({spec})")
            elif policy == "reference:causal":
                ax.axhline(ret, color="g", ls=":", lw=1.1, label="causal bound (test episodes)")
        ax.axvline(W, color="0.5", ls=":", lw=0.9)
        ax.set_xlabel("seconds of training at the benchmark's rate")
        ax.set_ylabel("greedy validation return (IQM over seeds)")
        ax.set_title(task, fontsize=9)
        ax.legend(fontsize=6.5, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
