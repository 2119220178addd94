"""``netsense benchmark``: scenarios x policies x seeds -> CSV, Markdown table, PNG plots;
``--frontier``: the scripted communication frontier, learned points and (``--bounds``) the
lookahead bounds per scenario under the evaluation protocol of
:mod:`netsense.benchmark.protocol` (Pareto PNG + CSV, headroom table)."""

from __future__ import annotations

import argparse

from netsense.commands._args import nonnegative_int, positive_float, positive_int

NAME = "benchmark"
HELP = ("Benchmark learned and scripted policies and a centralized KF oracle on scenarios "
        "(seeds as one batched run, or in processes or on Ray); writes CSV, a Markdown table "
        "and plots. --frontier: the scripted communication frontier with learned points, "
        "95-percent bootstrap intervals, Pareto plots.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from netsense.benchmark import BACKENDS, DEFAULT_POLICIES, POLICY_NAMES
    from netsense.benchmark.bounds import BOUND_KINDS, BoundConfig
    from netsense.benchmark.protocol import (
        DEFAULT_BOUND_EPISODES,
        DEFAULT_EPISODES,
        EVAL_SEED0,
        FAMILIES,
    )

    parser.add_argument("scenarios", nargs="+", help="scenario ids (see `netsense list`)")
    parser.add_argument("--policies", nargs="+", default=list(DEFAULT_POLICIES),
                        metavar="POLICY",
                        help=f"policies among {', '.join(POLICY_NAMES)}; a learned policy is "
                             "learned:PATH where {scenario} in PATH is replaced by the "
                             f"scenario id (default: {' '.join(DEFAULT_POLICIES)})")
    parser.add_argument("--seeds", type=positive_int, default=DEFAULT_EPISODES,
                        help=f"number of evaluation seeds (default: {DEFAULT_EPISODES})")
    parser.add_argument("--seed0", type=nonnegative_int, default=EVAL_SEED0,
                        help=f"first seed; seeds are seed0..seed0+seeds-1 (default: "
                             f"{EVAL_SEED0}: training uses seeds below it)")
    parser.add_argument("--frontier", action="store_true",
                        help="run the scripted communication frontier (every baseline at "
                             "each knob, in the scenario's communication-only mode, "
                             "'transmit' for full-control scenarios) and the --learned "
                             "policies (greedy and sampled); writes frontier_<scenario>.csv/"
                             ".png, frontier.csv and frontier.md")
    parser.add_argument("--families", nargs="+", default=list(FAMILIES), metavar="FAMILY",
                        choices=list(FAMILIES),
                        help=f"--frontier: baseline families (default: {' '.join(FAMILIES)})")
    parser.add_argument("--learned", action="append", default=[], metavar="PATH",
                        help="--frontier: a learned policy, policy.pt of `netsense train "
                             "--backend torchrl` (run in the control mode it was trained in) "
                             "or a MaskablePPO policy.zip ({scenario} is replaced by the "
                             "scenario id); repeatable")
    parser.add_argument("--bounds", nargs="+", default=[], metavar="KIND",
                        choices=list(BOUND_KINDS),
                        help="--frontier: lookahead bounds to add (causal, clairvoyant; "
                             "centralised full-information references, not deployable)")
    parser.add_argument("--bound-episodes", type=positive_int, default=DEFAULT_BOUND_EPISODES,
                        help="--bounds: run them on the first N evaluation seeds (default: "
                             f"{DEFAULT_BOUND_EPISODES}; they cost far more per episode)")
    parser.add_argument("--bound-horizon", type=positive_int, default=BoundConfig.horizon,
                        help=f"--bounds: lookahead steps h (default: {BoundConfig.horizon})")
    parser.add_argument("--bound-futures", type=positive_int, default=BoundConfig.futures,
                        help="--bounds: resampled futures F of the causal bound (default: "
                             f"{BoundConfig.futures})")
    parser.add_argument("--bound-continuation", nargs="+", default=None, metavar="POLICY",
                        help="--bounds: continuation policies (default: the best scripted "
                             "point of the run and the best decentralised one)")
    parser.add_argument("--bound-seed", type=nonnegative_int, default=BoundConfig.seed,
                        help=f"--bounds: seed of the resampled futures (default: "
                             f"{BoundConfig.seed})")
    parser.add_argument("--eps", type=positive_float, default=1e-2,
                        help="relative-error threshold of 'steps to eps' (default: 0.01)")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--backend", choices=BACKENDS, default="batched",
                        help="batched: the seeds of each scenario and policy as one batched "
                             "run in this process (learned policies episode by episode); "
                             "process / serial / ray: one episode per job in worker "
                             "processes / this process / Ray tasks (default: batched)")
    parser.add_argument("--workers", type=positive_int, default=None,
                        help="worker processes of --backend process (default: number of "
                             "cores)")
    parser.add_argument("--address", default=None,
                        help="Ray cluster address for --backend ray (e.g. auto, "
                             "ray://head:10001); default a local Ray instance")
    parser.add_argument("--override", action="append", default=[], metavar="KEY=JSON",
                        help="scenario override for every scenario (repeatable)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def _check_inputs(scenarios: list[str], policies: list[str]) -> None:
    """Unknown scenarios, policies and missing policy files fail before anything runs."""
    from pathlib import Path

    from netsense.benchmark import POLICY_NAMES
    from netsense.env.registry import list_scenarios

    known = list_scenarios()
    for sc in scenarios:
        if sc not in known:
            raise ValueError(f"unknown scenario {sc!r} (see `netsense list`)")
    for p in policies:
        name, _, path = p.partition(":")
        if name not in POLICY_NAMES:
            raise ValueError(f"--policies: unknown policy {p!r}; choose from "
                             f"{', '.join(POLICY_NAMES)}")
        for sc in scenarios if name == "learned" and path else ():
            f = Path(path.replace("{scenario}", sc))
            if not f.is_file():
                raise ValueError(f"--policies {p}: no policy file {f}")


def run(args: argparse.Namespace) -> int:
    from netsense.benchmark import run_benchmark
    from netsense.commands.train import parse_overrides

    if args.seeds < 1:
        raise SystemExit("--seeds must be >= 1")
    if args.workers is not None and (args.workers < 1 or args.backend != "process"):
        raise SystemExit(f"--workers must be >= 1 and needs --backend process "
                         f"(got --workers {args.workers} with --backend {args.backend})")
    if args.frontier:
        _check_inputs(args.scenarios, [])
        return _frontier(args, parse_overrides(args.override))
    _check_inputs(args.scenarios, args.policies)
    seeds = range(args.seed0, args.seed0 + args.seeds)
    _, rows = run_benchmark(args.scenarios, args.policies, seeds, out=args.out,
                            overrides=parse_overrides(args.override), eps=args.eps,
                            backend=args.backend, workers=args.workers,
                            ray_address=args.address, progress=not args.no_progress)
    from netsense.benchmark import markdown_table

    print(markdown_table(rows, args.eps))
    print(f"wrote {args.out}/episodes.csv, summary.csv, summary.md and plots")
    return 0


def _frontier(args: argparse.Namespace, overrides: dict) -> int:
    from netsense.benchmark.bounds import BoundConfig
    from netsense.benchmark.headroom import headroom, markdown_headroom
    from netsense.benchmark.protocol import FAMILIES, markdown_frontier, run_frontier

    config = BoundConfig(horizon=args.bound_horizon, futures=args.bound_futures,
                         seed=args.bound_seed)
    rows = run_frontier(args.scenarios, args.out, episodes=args.seeds, seed0=args.seed0,
                        families={f: FAMILIES[f] for f in args.families},
                        learned=args.learned, overrides=overrides,
                        progress=not args.no_progress, bounds=args.bounds,
                        bound_episodes=args.bound_episodes, bound_config=config,
                        bound_continuation=args.bound_continuation or "best")
    print(markdown_frontier(rows))
    if args.bounds:
        print(markdown_headroom(headroom(rows)))
    print(f"wrote {args.out}/frontier.csv, frontier.md and frontier_<scenario>.csv/.png"
          + (", headroom.csv and headroom.md" if args.bounds else ""))
    return 0
