"""``netsense suite score``: score policies on the benchmark suite's communication tasks.

Each ``POLICY`` is a policy file (``.npz`` of any framework, docs/suite.md; ``.pt`` of
``netsense train``), a runs folder (``DIR/<task>/[<learner>/]seed_<s>/``) or a scripted
rule ``rule:SPEC``; ``NAME=POLICY`` names it in the tables. Files given without a name form
one policy (``--name``, one file per task and training seed). Prints the table; ``--out``
writes ``table.csv``, ``table.md``, ``episodes.csv`` and ``figure.png``
(:mod:`netsense.benchmark.suite`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from netsense.commands._args import positive_int

NAME = "suite"
HELP = ("Score policies (.npz or .pt files, runs folders of `netsense train`, rule:SPEC) on "
        "the benchmark suite's communication tasks: IQM return with 95-percent intervals, "
        "probability of improvement over the best decentralised rule, scores normalised "
        "between never (0) and the certified upper bound (1), the aggregate; writes a "
        "table, the per-episode returns and a figure.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from netsense.benchmark.references import KNOWN_TASKS, SCALE_TASKS

    parser.add_argument("action", choices=("score",), help="score: evaluate and summarise")
    parser.add_argument("policies", nargs="+", metavar="POLICY",
                        help="[NAME=]PATH of a policy file or runs folder, or [NAME=]rule:SPEC")
    parser.add_argument("--tasks", nargs="+", choices=list(KNOWN_TASKS),
                        metavar="TASK",
                        help="tasks to score (default: the nine communication tasks; the "
                             f"tasks at scale {', '.join(SCALE_TASKS)} only by name, "
                             "with no upper bound)")
    parser.add_argument("--episodes", type=positive_int, default=100,
                        help="evaluation episodes, the protocol's first seeds (default 100)")
    parser.add_argument("--name", default="policy",
                        help="name of the policy the unnamed files form (default: policy)")
    parser.add_argument("--references", type=Path, default=None,
                        help="a references file (default: the package's)")
    parser.add_argument("--out", type=Path, default=None,
                        help="folder for table.csv, table.md, episodes.csv, figure.png")
    parser.add_argument("--no-progress", action="store_true")


def _entries(items: list[str], name: str) -> dict:
    policies: dict = {}
    files: list[str] = []
    for item in items:
        label, sep, what = item.partition("=")
        if not sep:
            label, what = "", item
        if what.startswith("rule:"):
            policies[label or what] = what
        elif Path(what).is_dir():
            policies[label] = what
        elif Path(what).is_file():
            if label:
                policies.setdefault(label, []).append(what)
            else:
                files.append(what)
        else:
            raise ValueError(f"{what}: no such file or folder (a POLICY is a policy file, a "
                             "runs folder or rule:SPEC)")
    if files:
        if name in policies:
            raise ValueError(f"--name {name!r} is also given as NAME=")
        policies[name] = files
    return policies


def run(args: argparse.Namespace) -> int:
    from netsense.benchmark.suite import score

    policies = _entries(args.policies, args.name)
    result = score(policies, args.tasks, args.episodes, references=args.references,
                   progress=not args.no_progress)
    print(result.markdown())
    if args.out is not None:
        for path in result.write(args.out).values():
            print(f"wrote {path}")
    return 0
