"""Policies that transfer across N: the set-network learner trained from scratch on the
K-of-N collision channel at N = 50, scored there and zero-shot at N = 10, 200 and 1,000.

``python experiments/rl/transfer_scale.py --workers 2`` (about 30 minutes of training and
15 of evaluation on the 2-core machine; ``--seeds``, ``--steps``, ``--episodes-scale``
shrink it, ``--retrain`` trains again where a run's ``policy.pt`` exists, by default an
existing run is evaluated as it is; ``--workers`` trains that many seeds at once) writes
into ``experiments/results/rl/transfer_scale/``:

1. **Runs** ``runs/seed_<s>/``: MAPPO with the set actor
   (:class:`netsense.rl.set_network.SetPolicyNet`, ``--network set``: its parameters do
   not depend on ``N``, ``D``, ``M``; it reads neither the agent one-hot of the MLP actor
   nor any ``N``-sized field of the observation) trained on ``comm_channel_kofn_n50-v0``
   for :data:`STEPS` agent-steps per seed (:data:`FIELDS`: a budget, not a verdict), one
   torch thread per run; ``policy.pt`` is the final actor (critic stripped),
   with ``log.csv``, ``config.json``, ``summary.json``.
2. **Episodes** ``episodes.csv``: every final policy, greedy and sampled, on the
   protocol's held-out seeds (:func:`netsense.benchmark.protocol.eval_seeds`) of each target of
   :data:`TARGETS` (N = 50 itself; zero-shot at N = 10 on ``comm_channel_k2-v0``, the
   K = N / 5 channel at N = 10, whose graph is a random jointly connected one, not the
   circulant with Markov link failures; N = 200 and N = 1,000 on the K-of-N tasks), beside
   the task's best decentralised rule (re-evaluated here on the same episodes; the rule
   of ``experiments/results/rl/scale_tasks/summary.csv`` at scale, the suite's reference
   at N = 10) and ``never``.
3. **Transfer table** ``transfer.csv`` / ``transfer.md``: per N, the learned policies' IQM
   return over seeds x episodes with its 95 % stratified-bootstrap interval
   (:func:`netsense.benchmark.scores.iqm_interval`), the rule's and ``never``'s IQM, and
   the probability of improvement P(learned > rule) (rliable's, over all pairs of
   episodes, :func:`netsense.benchmark.scores.probability_of_improvement`), and the same
   for the policies sampled instead of greedy (``learned_sampled:``); the per-seed IQMs
   and message rates, greedy and sampled, in ``per_seed.csv``.
4. **Plot** ``transfer.png``: return per agent-step against N (log axis), learned greedy
   (IQM and interval) and sampled (IQM), every seed thin, the rule and ``never``.
5. **Suite** ``suite/`` (``table.csv``, ``table.md``, ``episodes.csv``, ``figure.png``):
   the benchmark suite's score of the five policies on the training task
   (:func:`netsense.benchmark.suite.score` with ``tasks=[TRAIN_TASK]``: IQM, the best
   decentralised rule and the best centralised scheduler of the suite's references, the
   probability of improvement; no bound at this size, so no normalised score).

Every file is written atomically (:mod:`netsense.rl.atomic`).
"""

# %%
from __future__ import annotations

import argparse
import csv
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments" / "results" / "rl" / "transfer_scale"
FRONTIER = ROOT / "experiments" / "results" / "rl" / "scale_tasks" / "summary.csv"
TRAIN_TASK = "comm_channel_kofn_n50-v0"
SEEDS = (0, 1, 2, 3, 4)
#: Agent-steps per seed: 80 iterations of 32 environments x 32 steps x 50 agents (the team
#: critic's state holds the graph on the circulant's N D base links only:
#: :func:`netsense.rl.envs.global_state`). A budget, not a verdict.
STEPS = 4_096_000
#: The run's :class:`netsense.rl.config.PPOConfig` fields beyond the scenario, seed and
#: steps (the recipe's defaults otherwise: team critic, team reward, entropy decayed to 0).
FIELDS = {"network": "set", "num_envs": 32, "rollout": 32, "minibatch": 512,
          "eval_interval": 5, "eval_envs": 16, "torch_threads": 1}


@dataclass(frozen=True)
class Target:
    """One evaluation target: ``N``, its task and the protocol's episodes there."""

    N: int
    task: str
    episodes: int
    note: str


TARGETS = (
    Target(10, "comm_channel_k2-v0", 100, "zero-shot; K = 2 = N / 5, random jointly "
           "connected graph (not circulant + Markov failures)"),
    Target(50, TRAIN_TASK, 100, "trained here"),
    Target(200, "comm_channel_kofn_n200-v0", 50, "zero-shot"),
    Target(1000, "comm_channel_kofn_n1000-v0", 20, "zero-shot"),
)


# %% training
def ppo_config(seed: int, steps: int):
    """The run's :class:`netsense.rl.config.PPOConfig`."""
    from netsense.rl.config import PPOConfig

    return PPOConfig(scenario=TRAIN_TASK, seed=int(seed), steps=int(steps), **FIELDS)


def _finish(folder: Path) -> None:
    """Keep the committed files only: checkpoints and TensorBoard events removed, the
    critic stripped from ``policy.pt``."""
    from netsense.rl.checkpoint import strip_critic

    for ck in folder.glob("checkpoint_*.pt"):
        ck.unlink()
    shutil.rmtree(folder / "tb", ignore_errors=True)
    strip_critic(folder / "policy.pt")


def train(out: Path, seeds: list[int], steps: int, retrain: bool,
          progress: bool = True, workers: int = 1) -> dict[int, Path]:
    """Train every seed without a ``policy.pt`` under ``out/runs`` (all with
    ``retrain``), ``workers`` at a time (:func:`netsense.rl.launch.launch`); returns
    ``{seed: policy file}``."""
    from netsense.rl.launch import Run, launch

    runs = out / "runs"
    todo = []
    for s in seeds:
        folder = runs / f"seed_{s}"
        if retrain or not (folder / "policy.pt").exists():
            shutil.rmtree(folder, ignore_errors=True)
            todo.append(Run(ppo_config(s, steps)))
    if todo:
        entries = launch(todo, runs, workers=workers, progress=progress)
        failed = [f"{e['folder']}: {e['error']}" for e in entries if e["status"] != "ok"]
        if failed:
            raise RuntimeError(f"runs failed: {'; '.join(failed)}")
        for e in entries:
            _finish(runs / e["folder"])
    return {s: runs / f"seed_{s}" / "policy.pt" for s in seeds}


# %% evaluation
def best_decentralised(task: str) -> str:
    """The best decentralised rule of ``task``: the scale tasks' frontier summary
    (``experiments/rl/scale_tasks.py``) where it has the task, else the benchmark suite's
    reference (:mod:`netsense.benchmark.references`)."""
    if FRONTIER.exists():
        with FRONTIER.open() as fh:
            for r in csv.DictReader(fh):
                if r["scenario"] == task and r["what"] == "best decentralised":
                    return r["policy"]
    from netsense.benchmark.references import load_references

    return load_references()[task].best_decentralised


def evaluate_all(policies: dict[int, Path], targets: list[Target], scale: float = 1.0,
                 progress: bool = True) -> list[dict]:
    """Per-episode rows of every policy (greedy, kind ``learned``, and sampled, kind
    ``sampled``), the target's best decentralised rule and ``never`` on each target's
    evaluation seeds (``scale`` x its episodes, at least 2)."""
    from tqdm.auto import tqdm

    from netsense.benchmark.protocol import eval_seeds, evaluate

    jobs = [(t, kind, s) for t in targets
            for kind, s in [("rule", None), ("never", None)]
            + [(k, s) for s in policies for k in ("learned", "sampled")]]
    rows = []
    for t, kind, s in tqdm(jobs, desc="transfer evaluation", unit="run", disable=not progress):
        seeds = eval_seeds(max(2, round(t.episodes * scale)))
        spec = {"rule": best_decentralised(t.task), "never": "never"}.get(kind)
        if kind in ("learned", "sampled"):
            spec = f"{'learned' if kind == 'learned' else 'learned_sampled'}:{policies[s]}"
        m = evaluate(t.task, spec, seeds)
        label = kind if kind in ("learned", "sampled") else spec
        rows += [{"N": t.N, "task": t.task, "kind": kind, "policy": label,
                  "seed": "" if s is None else s, "episode_seed": sd,
                  "reward": float(m["reward"][e]),
                  "msgs_per_agent_step": float(m["msgs_per_agent_step"][e]),
                  "mean_rel_error": float(m["mean_rel_error"][e])}
                 for e, sd in enumerate(seeds)]
    return rows


def transfer_table(rows: list[dict], reps: int | None = None) -> tuple[list[dict], list[dict]]:
    """``(table, per_seed)``: per N the learned IQM [95 % CI] over seeds x episodes (greedy
    and sampled), the rule's and ``never``'s IQM [CI], P(learned > rule); per N and seed
    the learned IQM and message rate (greedy and sampled).
    ``reps``: bootstrap resamples (default :data:`netsense.benchmark.scores.REPS`)."""
    from netsense.benchmark.scores import REPS, iqm, probability_of_improvement
    from netsense.benchmark.scores import iqm_interval as _interval

    def iqm_interval(v: np.ndarray) -> tuple[float, float, float]:
        return _interval(v, reps=REPS if reps is None else int(reps))

    table, per_seed = [], []
    for N in sorted({int(r["N"]) for r in rows}):
        at = [r for r in rows if int(r["N"]) == N]
        pick = {k: np.array([r["reward"] for r in at if r["kind"] == k])
                for k in ("learned", "sampled", "rule", "never")}
        msgs = {k: float(np.mean([r["msgs_per_agent_step"] for r in at if r["kind"] == k]))
                if len(pick[k]) else float("nan") for k in ("learned", "sampled", "rule")}
        li, ll, lh = iqm_interval(pick["learned"])
        si, sl, sh = iqm_interval(pick["sampled"]) if len(pick["sampled"]) else (
            (float("nan"),) * 3)
        ri, rl, rh = iqm_interval(pick["rule"])
        ni = iqm(pick["never"])
        seeds = sorted({int(r["seed"]) for r in at if r["kind"] == "learned"})
        table.append({
            "N": N, "task": at[0]["task"],
            "episodes": len({r["episode_seed"] for r in at}), "seeds": len(seeds),
            "learned_iqm": li, "learned_ci_low": ll, "learned_ci_high": lh,
            "learned_msgs": msgs["learned"],
            "rule": next(r["policy"] for r in at if r["kind"] == "rule"),
            "rule_iqm": ri, "rule_ci_low": rl, "rule_ci_high": rh, "rule_msgs": msgs["rule"],
            "never_iqm": ni,
            "sampled_iqm": si, "sampled_ci_low": sl, "sampled_ci_high": sh,
            "sampled_msgs": msgs["sampled"],
            "p_learned_beats_rule": probability_of_improvement(pick["learned"], pick["rule"]),
            "p_sampled_beats_rule": probability_of_improvement(pick["sampled"], pick["rule"])
            if len(pick["sampled"]) else float("nan"),
            "p_learned_beats_never": probability_of_improvement(pick["learned"],
                                                                pick["never"])})
        for s in seeds:
            v = np.array([r["reward"] for r in at if r["kind"] == "learned"
                          and int(r["seed"]) == s])
            m = float(np.mean([r["msgs_per_agent_step"] for r in at
                               if r["kind"] == "learned" and int(r["seed"]) == s]))
            row = {"N": N, "seed": s, "learned_iqm": iqm(v), "learned_msgs": m}
            sv = [r for r in at if r["kind"] == "sampled" and int(r["seed"]) == s]
            if sv:
                row["sampled_iqm"] = iqm([r["reward"] for r in sv])
                row["sampled_msgs"] = float(np.mean([r["msgs_per_agent_step"] for r in sv]))
            per_seed.append(row)
    return table, per_seed


# %% outputs
def write_csv(path: Path, rows: list[dict]) -> None:
    """``rows`` as CSV at ``path`` (atomically; floats to six significant digits)."""
    from netsense.rl.atomic import atomic_path

    cols = list(dict.fromkeys(k for r in rows for k in r))
    with atomic_path(path) as tmp, tmp.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        for r in rows:
            w.writerow({k: f"{v:.6g}" if isinstance(v, float) else v for k, v in r.items()})


def markdown(table: list[dict], steps: int) -> str:
    """The transfer table in Markdown."""
    lines = [f"Set-network MAPPO trained on `{TRAIN_TASK}` ({steps:,} agent-steps per seed: "
             "a budget, not a verdict), greedy (and sampled), evaluated on the protocol's "
             "held-out seeds; "
             "IQM return over seeds x episodes [95 % stratified-bootstrap CI].", "",
             "| N | task | seeds x episodes | learned IQM [95 % CI] | learned msgs/agent-step "
             "| best decentralised rule | rule IQM [95 % CI] | never IQM "
             "| P(learned > rule) | sampled IQM [95 % CI] | sampled msgs/agent-step |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in table:
        lines.append(
            f"| {r['N']} | `{r['task']}` | {r['seeds']} x {r['episodes']} | "
            f"{r['learned_iqm']:.1f} [{r['learned_ci_low']:.1f}, {r['learned_ci_high']:.1f}]"
            f" | {r['learned_msgs']:.3f} | `{r['rule']}` | {r['rule_iqm']:.1f} "
            f"[{r['rule_ci_low']:.1f}, {r['rule_ci_high']:.1f}] | {r['never_iqm']:.1f} | "
            f"{r['p_learned_beats_rule']:.2f} | {r['sampled_iqm']:.1f} "
            f"[{r['sampled_ci_low']:.1f}, {r['sampled_ci_high']:.1f}] | "
            f"{r['sampled_msgs']:.3f} |")
    return "\n".join(lines) + "\n"


def plot(table: list[dict], per_seed: list[dict], path: Path) -> None:
    """Return per agent-step against N: learned greedy (IQM, interval, seeds) and sampled,
    the rule, ``never``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from netsense.rl.atomic import save_figure

    H = 200.0  # every target's horizon: per agent-step = return / H
    Ns = np.array([r["N"] for r in table])
    fig, ax = plt.subplots(figsize=(6.4, 5.0))
    for s in sorted({r["seed"] for r in per_seed}):
        p = [r for r in per_seed if r["seed"] == s]
        ax.plot([r["N"] for r in p], [r["learned_iqm"] / H for r in p], color="C0",
                alpha=0.25, lw=0.8)
        if all("sampled_iqm" in r for r in p):
            ax.plot([r["N"] for r in p], [r["sampled_iqm"] / H for r in p], color="C2",
                    alpha=0.5, lw=0.8, ls=":")
    li = np.array([r["learned_iqm"] for r in table]) / H
    err = np.array([[r["learned_iqm"] - r["learned_ci_low"] for r in table],
                    [r["learned_ci_high"] - r["learned_iqm"] for r in table]]) / H
    ax.errorbar(Ns, li, yerr=err, color="C0", marker="o", capsize=3,
                label="set network, trained at N = 50 (IQM, 95 % CI; seeds thin)")
    ax.plot(Ns, [r["sampled_iqm"] / H for r in table], color="C2", ls=":", marker=".",
            label="the same, sampled (IQM; seeds thin)")
    ax.plot(Ns, [r["rule_iqm"] / H for r in table], color="C1", marker="s",
            label="best decentralised rule of each task")
    for r in table:
        ax.annotate(r["rule"], (r["N"], r["rule_iqm"] / H), textcoords="offset points",
                    xytext=(4, 4), fontsize=7, color="C1")
    ax.plot(Ns, [r["never_iqm"] / H for r in table], color="0.4", ls="--", marker="x",
            label="never")
    ax.axvline(50, color="0.8", lw=0.8, zorder=0)
    ax.set_xscale("log")
    ax.set_xlabel("N (agents); N = 10 is comm_channel_k2-v0")
    ax.set_ylabel("return per agent-step")
    ax.set_title("Transfer across N: K-of-N channel, K = N / 5")
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    fig.tight_layout()
    save_figure(fig, path, dpi=120)
    plt.close(fig)


def read_rows(path: Path) -> list[dict]:
    """``episodes.csv`` back as rows with numeric rewards."""
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        for k in ("reward", "msgs_per_agent_step", "mean_rel_error"):
            r[k] = float(r[k])
    return rows


def write_outputs(out: Path, rows: list[dict], steps: int) -> list[dict]:
    """``transfer.{csv,md,png}`` and ``per_seed.csv`` from the episode rows."""
    from netsense.rl.atomic import write_atomic

    table, per_seed = transfer_table(rows)
    write_csv(out / "transfer.csv", table)
    write_csv(out / "per_seed.csv", per_seed)
    write_atomic(out / "transfer.md", markdown(table, steps))
    plot(table, per_seed, out / "transfer.png")
    return table


def write_suite(out: Path, policies: dict[int, Path], episodes: int = 100,
                progress: bool = True):
    """The suite's score of the policies on :data:`TRAIN_TASK`, written to ``out/suite``."""
    from netsense.benchmark.suite import score

    res = score({"set network, N = 50": [str(policies[s]) for s in sorted(policies)]},
                [TRAIN_TASK], episodes, progress=progress)
    res.write(out / "suite")
    return res


def main(argv: list[str] | None = None) -> int:
    """Command line: train (where needed), evaluate, write the table and the plot."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("stage", nargs="?", default="all", choices=("all", "train", "summary"),
                    help="all: train where needed, evaluate, write; train: train only; "
                         "summary: the table and plot again from episodes.csv")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS))
    ap.add_argument("--steps", type=int, default=STEPS, help="agent-steps per seed")
    ap.add_argument("--episodes-scale", type=float, default=1.0,
                    help="fraction of each target's episodes (at least 2)")
    ap.add_argument("--retrain", action="store_true")
    ap.add_argument("--workers", type=int, default=1,
                    help="training processes at once (one core each; default 1)")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    if args.stage == "summary":
        table = write_outputs(out, read_rows(out / "episodes.csv"), args.steps)
    else:
        policies = train(out, args.seeds, args.steps, args.retrain, not args.no_progress,
                         args.workers)
        if args.stage == "train":
            return 0
        rows = evaluate_all(policies, list(TARGETS), args.episodes_scale,
                            not args.no_progress)
        write_csv(out / "episodes.csv", rows)
        table = write_outputs(out, rows, args.steps)
        n50 = next(t for t in TARGETS if t.task == TRAIN_TASK)
        print(write_suite(out, policies, max(2, round(n50.episodes * args.episodes_scale)),
                          not args.no_progress).markdown())
    print(markdown(table, args.steps))
    return 0


if __name__ == "__main__":
    sys.exit(main())
