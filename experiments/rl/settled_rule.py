"""Why ``settled:e(BASE)`` belongs in the frontier: the sources' own observers in their
transient, and which agents the learners keep quiet.

``python experiments/rl/settled_rule.py`` (about 30 s) writes into
``experiments/results/rl/settled_rule/``:

1. ``transient.csv``/``.md``/``.png``: on each task of :data:`TASKS`, every source's
   error on its *own* block of Lemma 1, ``||P_i (z_i[k] - z[k])|| / ||z[k]||`` (median
   over the protocol's 100 evaluation episodes), at the steps :data:`STEPS`, under
   ``never`` (no messages: only the agent's own observer acts on its block; with
   freshness fusion an agent keeps its own substate, so messages never change it) and
   the step at which ``settled:0.3`` opens the agent's gate (median). A receiver adopts
   the freshest estimate of a substate, so a source that sends while this error is above
   1 hands its receivers an estimate of its block that errs by more than holding 0 for
   it would (at most the state's norm).
2. ``sends.csv``/``.md``: per agent, the share of the steps 1 to 40 at which it
   transmits, on each task of :data:`SENDS`: its best rule before and after ``settled``
   and the final greedy policies of the five seeds of a committed learner (20M
   agent-steps), with each policy's mean return.
3. ``gain.csv``/``.md``: on every communication task, the best decentralised rule of the
   frontier (``experiments/results/rl/comm_tasks/frontier_<task>.csv``) other than
   ``settled``, the best ``settled`` row, and the paired difference of their returns on
   the 100 episodes with its 95 % bootstrap interval.
"""

# %%
from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments/results/rl/settled_rule"
TASKS = ("message_cost-v0", "message_cost-v1", "comm_schedule-v1")
STEPS = (0, 2, 5, 10, 15, 20, 30, 40)
LEARNERS = ROOT / "experiments/results/rl/learners"
#: task -> (its rules, the runs folder of a learner whose five seeds are measured)
SENDS = {"comm_schedule-v1": (("phased(until:40)", "settled:0.3(until:40)"),
                              "clock_20m/runs/comm_schedule-v1/mlp_clock"),
         "message_cost-v1": (("settle:0.03", "settled:0.3(settle:0.03)"),
                             "clock_gate_20m/runs/message_cost-v1/mlp_clock_news_gate")}
FRONTIERS = ROOT / "experiments/results/rl/comm_tasks"
COMM_TASKS = ("comm_process_noise-v0", "comm_substates-v0", "comm_channel_k2-v0",
              "message_cost-v0", "message_cost-v1", "comm_announced-v0", "comm_fading-v0",
              "comm_schedule-v0", "comm_schedule-v1")
EARLY = 40


def own_block_errors(task: str, episodes: int = 100, eps: float = 0.3) -> list[dict]:
    """One row per source of ``task``: the median own-block relative error at
    :data:`STEPS` under ``never`` and the median step at which ``settled:eps`` opens."""
    import netsense.rl  # noqa: F401  (registers the learned-policy loaders)
    from netsense.benchmark.protocol import eval_seeds, evaluate, frontier_overrides
    from netsense.env.comm_policies import make_comm_policy

    seeds = eval_seeds(episodes)
    over = frontier_overrides(task)
    Z, z, opened, blocks = [], [], [], []

    def actor(core, _seeds):
        gate = make_comm_policy(f"settled:{eps}(always)", core)
        T = core.model.design.decomposition.T  # z = T^T x (Lemma 1's coordinates)
        blocks.append(np.asarray(core.block_of))

        def act(obs, mask):
            Z.append(core.Z.copy())
            z.append(core.x @ T)
            opened.append(gate.gate(np.asarray(obs)))
            return np.zeros_like(mask[..., 1::2], dtype=np.int64)

        return act

    evaluate(task, "never", seeds, over, actor=actor)
    Z, z, opened = np.stack(Z), np.stack(z), np.stack(opened)  # (K, B, N, n), (K, B, n)
    norm = np.linalg.norm(z, axis=-1)
    block_of = blocks[0]
    rows = []
    for i in np.unique(block_of):
        cols = block_of == i
        err = np.linalg.norm(Z[:, :, i][..., cols] - z[..., cols], axis=-1) / norm
        first = np.argmax(opened[:, :, i], axis=0).astype(float)
        first[~opened[:, :, i].any(0)] = np.nan
        rows.append({"task": task, "agent": int(i), "block_size": int(cols.sum()),
                     **{f"k{k}": float(np.median(err[k])) for k in STEPS},
                     "opens_at": float(np.nanmedian(first))})
    return rows


def early_sends(task: str, specs: list[tuple[str, str]], episodes: int = 100) -> list[dict]:
    """Per policy ``(label, spec)``: its mean return and each agent's share of the steps
    1 to ``EARLY`` at which it transmits."""
    import netsense.rl  # noqa: F401
    from netsense.benchmark.protocol import eval_seeds, evaluate, frontier_overrides

    seeds = eval_seeds(episodes)
    rows = []
    for label, spec in specs:
        sent = []

        def record(core, live, sent=sent):
            if int(core.k.max()) <= EARLY:
                sent.append(core.transmit[live].astype(float))

        over = None if spec.startswith("learned:") else frontier_overrides(task)
        ret = evaluate(task, spec, seeds, over, on_step=record)["reward"]
        rate = np.concatenate(sent).mean(0)
        rows.append({"task": task, "policy": label, "return": float(ret.mean()),
                     **{f"agent_{i}": float(r) for i, r in enumerate(rate)}})
    return rows


def frontier_gain(task: str, episodes: int = 100) -> dict:
    """The best ``settled`` row of the task's frontier against its best other
    decentralised row: both means, and the paired difference (settled minus other) with
    its 95 % bootstrap interval on the protocol's episodes."""
    import netsense.rl  # noqa: F401
    from netsense.benchmark.intervals import bootstrap_ci
    from netsense.benchmark.protocol import eval_seeds, evaluate, frontier_overrides

    with (FRONTIERS / f"frontier_{task}.csv").open() as fh:
        rows = [r for r in csv.DictReader(fh) if r["kind"] == "decentralised"]
    if not any(r["family"] == "settled" for r in rows):
        raise SystemExit(f"{task}: the frontier has no settled rows; run "
                         "experiments/rl/comm_tasks.py")
    best = {k: max((r for r in rows if (r["family"] == "settled") == k),
                   key=lambda r: float(r["reward_mean"])) for k in (False, True)}
    seeds = eval_seeds(episodes)
    ret = {k: evaluate(task, r["policy"], seeds, frontier_overrides(task))["reward"]
           for k, r in best.items()}
    gain, lo, hi = bootstrap_ci(ret[True] - ret[False])
    return {"task": task, "rule": best[False]["policy"], "rule_mean": float(ret[False].mean()),
            "settled": best[True]["policy"], "settled_mean": float(ret[True].mean()),
            "gain": gain, "gain_ci_low": lo, "gain_ci_high": hi}


def write_csv(path: Path, rows: list[dict]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def markdown(rows: list[dict], cols: list[str], heads: list[str], fmt: str) -> str:
    lines = ["| " + " | ".join(heads) + " |", "|---" * len(heads) + "|"]
    for r in rows:
        cells = [f"{r[c]:{fmt}}" if isinstance(r[c], float) else str(r[c]) for c in cols]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(TASKS), figsize=(4.2 * len(TASKS), 3.4), sharey=True)
    for ax, task in zip(np.atleast_1d(axes), TASKS, strict=True):
        for r in (r for r in rows if r["task"] == task):
            ax.plot(STEPS, [r[f"k{k}"] for k in STEPS], marker="o",
                    label=f"agent {r['agent']} ({r['block_size']})")
        ax.axhline(1.0, color="grey", lw=0.8, ls="--")
        ax.set_yscale("log")
        ax.set_title(task)
        ax.set_xlabel("step k")
    np.atleast_1d(axes)[0].set_ylabel("own-block error / ||z|| (median)")
    np.atleast_1d(axes)[-1].legend(title="source (block size)", fontsize=8)
    fig.suptitle("sources' own-block error with no messages (dashed: the whole state's norm)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument("--episodes", type=int, default=100)
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = [r for t in TASKS for r in own_block_errors(t, args.episodes)]
    write_csv(args.out / "transient.csv", rows)
    cols = ["task", "agent", "block_size", *(f"k{k}" for k in STEPS), "opens_at"]
    text = markdown(rows, cols, ["task", "source", "block size",
                                 *(f"k = {k}" for k in STEPS), "settled:0.3 opens at"],
                    ".2f")
    (args.out / "transient.md").write_text(text)
    print(text)
    plot(rows, args.out / "transient.png")
    sends = []
    for task, (rules, runs) in SENDS.items():
        files = [LEARNERS / runs / f"seed_{s}" / "policy.pt" for s in range(5)]
        for f in files:
            if not f.exists():
                raise SystemExit(f"no such policy file {f}")
        sends += early_sends(task, [(s, s) for s in rules] + [
            (f"{f.parent.parent.name}, {f.parent.name}", f"learned:{f}") for f in files],
            args.episodes)
    write_csv(args.out / "sends.csv", sends)
    n = len([c for c in sends[0] if c.startswith("agent_")])
    text = markdown(sends, ["task", "policy", "return", *(f"agent_{i}" for i in range(n))],
                    ["task", "policy", "return", *(f"agent {i}" for i in range(n))], ".2f")
    (args.out / "sends.md").write_text(text)
    print(text)
    gains = [frontier_gain(t, args.episodes) for t in COMM_TASKS]
    write_csv(args.out / "gain.csv", gains)
    text = markdown(gains, ["task", "rule", "rule_mean", "settled", "settled_mean", "gain",
                            "gain_ci_low", "gain_ci_high"],
                    ["task", "best other decentralised rule", "mean", "best settled",
                     "mean", "gain", "95 % CI low", "high"], ".1f")
    (args.out / "gain.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
