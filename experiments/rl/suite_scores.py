"""The benchmark suite's scores of the committed learners and the scripted families, and the
leaderboard page's tables.

The commands (from the repository root)::

    python experiments/rl/suite_scores.py score     # evaluate everything (a few minutes)
    python experiments/rl/suite_scores.py summary   # the tables again from episodes.csv

**score** runs :func:`netsense.benchmark.suite.score` on the protocol's 100 evaluation
episodes of every task for

* the committed learners: the MLP learner of ``experiments/rl/learners.py`` after 2M
  agent-steps (``experiments/results/rl/learners/runs``) and after 10M
  (``experiments/results/rl/learners/budget_10m/runs``), five training seeds each;
* every scripted family of the frontier (``experiments/results/rl/comm_tasks/``), at its
  best knob per task (mean return), labelled with its kind (decentralised rules,
  privileged rules and centralised schedulers are different rungs of the score ladder);

and writes ``experiments/results/rl/suite_scores/`` (``table.csv``, ``table.md``,
``episodes.csv``, ``figure.png``) and the tables of ``docs/leaderboard.md`` (between its
markers). **summary** rebuilds the same files from ``episodes.csv`` under the current
references (after ``experiments/rl/suite_references.py`` ran again: a new upper bound or
best rule changes the scores, not the policies' returns), without evaluating a policy.
"""

# %%
from __future__ import annotations

import argparse
import csv
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RL = ROOT / "experiments" / "results" / "rl"
RESULTS = ROOT / "experiments" / "results" / "rl" / "suite_scores"
FRONTIERS = RL / "comm_tasks"
PAGE = ROOT / "docs" / "leaderboard.md"
#: name -> runs folder of the committed learners
LEARNERS = {"mlp, 2M agent-steps": RL / "learners" / "runs",
            "mlp, 10M agent-steps": RL / "learners" / "budget_10m" / "runs"}
#: frontier kinds of the scripted families scored (the endpoints always/never excluded)
FAMILY_KINDS = ("decentralised", "privileged", "centralised")
START, END = "<!-- suite-table:start -->", "<!-- suite-table:end -->"


def family_rules(tasks, folder: Path = FRONTIERS) -> dict[str, dict[str, str]]:
    """``{"<family> (<kind>)": {task: "rule:<best knob>"}}`` from the frontier CSVs (the
    best knob by mean return, per task)."""
    best: dict[str, dict[str, tuple[float, str]]] = {}
    for task in tasks:
        with (folder / f"frontier_{task}.csv").open() as fh:
            for r in csv.DictReader(fh):
                if r["kind"] not in FAMILY_KINDS or r["family"] in ("always", "never"):
                    continue
                label = f"{r['family']} ({r['kind']})"
                cur = best.setdefault(label, {}).get(task)
                if cur is None or float(r["reward_mean"]) > cur[0]:
                    best[label][task] = (float(r["reward_mean"]), r["policy"])
    return {k: {t: f"rule:{spec}" for t, (_, spec) in v.items()}
            for k, v in sorted(best.items(), key=lambda kv: _rank(kv[0]))}


def _rank(label: str) -> tuple:
    """Families ordered by rung (decentralised, privileged, centralised), then by name."""
    family, _, kind = label.partition(" (")
    return (FAMILY_KINDS.index(kind.rstrip(")")) if kind.rstrip(")") in FAMILY_KINDS
            else len(FAMILY_KINDS), family)


def write_page(table: list[dict], page: Path = PAGE) -> None:
    """Replace the text between the page's markers by the leaderboard's tables."""
    from netsense.benchmark.suite_output import leaderboard_markdown

    text = page.read_text()
    if START not in text or END not in text:
        raise ValueError(f"{page}: the markers {START} and {END} are missing")
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    page.write_text(f"{head}{START}\n{leaderboard_markdown(table)}{END}{tail}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("command", choices=("score", "summary"))
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--tasks", nargs="+")
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument("--page", type=Path, default=PAGE)
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    from netsense.benchmark.references import SUITE_TASKS
    from netsense.benchmark.suite import read_episodes, rescore, score
    from netsense.benchmark.suite_output import read_table

    if args.command == "score":
        tasks = args.tasks or list(SUITE_TASKS)
        policies = {**{k: str(v) for k, v in LEARNERS.items()}, **family_rules(tasks)}
        result = score(policies, tasks, args.episodes, progress=not args.no_progress)
    else:
        path = args.out / "episodes.csv"
        names = {r["learner"] for r in read_episodes(path) if r["kind"] == "policy"}
        order = [n for n in LEARNERS if n in names] + sorted(
            (n for n in names if n not in LEARNERS), key=_rank)
        result = rescore(path, order=order)
    # the figure: the learners (the rules are there as the best decentralised marker)
    paths = result.write(args.out, [ln for ln in result.learners if ln in LEARNERS])
    write_page(read_table(paths["table.csv"]), args.page)  # the page shows what the CSV holds
    print(result.markdown())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
