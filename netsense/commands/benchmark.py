"""``netsense benchmark``: scenarios x policies x seeds -> CSV, Markdown table, PNG plots;
``--frontier``: the scripted communication frontier (informed and privileged rules
included), learned points and (``--references``) the full-information reference schedulers
per scenario under the evaluation protocol of
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
    from netsense.benchmark.lookahead import REFERENCE_KINDS, LookaheadConfig
    from netsense.benchmark.protocol import (
        DEFAULT_EPISODES,
        DEFAULT_REFERENCE_EPISODES,
        EVAL_SEED0,
        FAMILIES,
    )

    parser.add_argument("scenarios", nargs="+", help="scenario ids (see `netsense list`)")
    parser.add_argument("--policies", nargs="+", default=None,
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
    parser.add_argument("--families", nargs="+", default=None, metavar="FAMILY",
                        choices=list(FAMILIES),
                        help=f"--frontier: baseline families (default: {' '.join(FAMILIES)})")
    parser.add_argument("--learned", action="append", default=None, metavar="PATH",
                        help="--frontier: a learned policy, policy.pt of `netsense train "
                             "--backend torchrl` (run in the control mode it was trained in) "
                             "or a MaskablePPO policy.zip ({scenario} is replaced by the "
                             "scenario id); repeatable")
    parser.add_argument("--references", nargs="+", default=[], metavar="KIND",
                        choices=list(REFERENCE_KINDS),
                        help="--frontier: full-information reference schedulers to add "
                             "(causal, clairvoyant: centralised lookahead searches, not "
                             "deployable; achieved returns, not bounds)")
    parser.add_argument("--reference-episodes", type=positive_int,
                        default=DEFAULT_REFERENCE_EPISODES,
                        help="--references: run them on the first N evaluation seeds "
                             f"(default: {DEFAULT_REFERENCE_EPISODES}; they cost far more "
                             "per episode)")
    parser.add_argument("--reference-horizon", type=positive_int,
                        default=LookaheadConfig.horizon,
                        help="--references: lookahead steps h (default: "
                             f"{LookaheadConfig.horizon})")
    parser.add_argument("--reference-futures", type=positive_int,
                        default=LookaheadConfig.futures,
                        help="--references: resampled futures F of the causal reference "
                             f"(default: {LookaheadConfig.futures})")
    parser.add_argument("--reference-continuation", nargs="+", default=None,
                        metavar="POLICY",
                        help="--references: continuation policies (default: the best "
                             "scripted point of the run and the best decentralised one)")
    parser.add_argument("--reference-seed", type=nonnegative_int,
                        default=LookaheadConfig.seed,
                        help="--references: seed of the resampled futures (default: "
                             f"{LookaheadConfig.seed})")
    parser.add_argument("--eps", type=positive_float, default=None,
                        help="relative-error threshold of 'steps to eps' (default: 0.01; "
                             "not a --frontier metric)")
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


def _check_inputs(scenarios: list[str], policies: list[str], overrides: dict) -> None:
    """Unknown scenarios, policies, bad overrides and missing or unreadable policy files
    fail before anything runs."""
    from pathlib import Path

    from netsense.benchmark import POLICY_NAMES
    from netsense.env.comm_policies import COMM_POLICIES, parse_spec, spec_family
    from netsense.env.registry import list_scenarios, unknown_scenario

    known = list_scenarios()
    for sc in scenarios:
        if sc not in known:
            raise unknown_scenario(sc)
    from netsense.env.vector import load_model

    for sc in dict.fromkeys(scenarios):
        load_model(sc, **overrides)  # bad override values name their field here
    for p in policies:
        name, _, path = p.partition(":")
        name = spec_family(p) if spec_family(p) in COMM_POLICIES else name
        if name not in POLICY_NAMES:
            raise ValueError(f"--policies: unknown policy {p!r}; choose from "
                             f"{', '.join(POLICY_NAMES)}")
        if name in COMM_POLICIES:
            parse_spec(p)  # a bad knob or base fails here, by name
        learned = name in ("learned", "learned_sampled")
        if learned and not path:
            raise ValueError(f"--policies {p}: a learned policy needs its file: {name}:PATH")
        for sc in scenarios if learned else ():
            f = Path(path.replace("{scenario}", sc))
            if not f.is_file():
                raise ValueError(f"--policies {p}: no policy file {f}")
            _check_policy_file(f)


def _check_policy_file(path) -> None:
    """Read a policy file as data (checksum, weights) before any episode runs."""
    from netsense.benchmark.rollouts import is_batched_policy

    if is_batched_policy(path):
        from netsense.rl.checkpoint import read_policy

        read_policy(path)
    else:
        from netsense.rl.sb3_policy import read_sb3_policy

        read_sb3_policy(path)


#: Options of each mode and their defaults (``None`` in the parser, so that an option of
#: the other mode is refused instead of ignored).
TABLE_DEFAULTS = {"policies": None, "eps": 1e-2, "workers": None, "address": None}
FRONTIER_DEFAULTS = {"learned": [], "families": None}


def _given(args: argparse.Namespace, names) -> list[str]:
    return ["--" + n.replace("_", "-") for n in names if getattr(args, n) is not None]


def run(args: argparse.Namespace) -> int:
    from netsense.benchmark import DEFAULT_POLICIES, run_benchmark
    from netsense.commands.train import parse_overrides

    if args.seeds < 1:
        raise SystemExit("--seeds must be >= 1")
    overrides = parse_overrides(args.override)
    if args.frontier:
        wrong = _given(args, TABLE_DEFAULTS) + (
            [f"--backend {args.backend}"] if args.backend != "batched" else [])
        if wrong:
            raise ValueError(f"{', '.join(wrong)} do{'es' if len(wrong) == 1 else ''} not "
                             "apply to --frontier (learned policies go in --learned PATH; "
                             "the frontier runs batched, in this process)")
        for k, v in FRONTIER_DEFAULTS.items():
            setattr(args, k, v if getattr(args, k) is None else getattr(args, k))
        _check_inputs(args.scenarios, [f"learned:{p}" for p in args.learned], overrides)
        return _frontier(args, overrides)
    wrong = _given(args, FRONTIER_DEFAULTS)
    if wrong:
        raise ValueError(f"{', '.join(wrong)} need{'s' if len(wrong) == 1 else ''} "
                         "--frontier (without it, benchmark learned policies with "
                         "--policies learned:PATH)")
    for k, v in TABLE_DEFAULTS.items():
        setattr(args, k, v if getattr(args, k) is None else getattr(args, k))
    if args.policies is None:
        args.policies = list(DEFAULT_POLICIES)
    if args.workers is not None and (args.workers < 1 or args.backend != "process"):
        raise SystemExit(f"--workers must be >= 1 and needs --backend process "
                         f"(got --workers {args.workers} with --backend {args.backend})")
    if args.address is not None and args.backend != "ray":
        raise SystemExit(f"--address needs --backend ray (got --backend {args.backend})")
    _check_inputs(args.scenarios, args.policies, overrides)
    seeds = range(args.seed0, args.seed0 + args.seeds)
    results, rows = run_benchmark(args.scenarios, args.policies, seeds, out=args.out,
                                  overrides=overrides, eps=args.eps, backend=args.backend,
                                  workers=args.workers, ray_address=args.address,
                                  progress=not args.no_progress)
    from netsense.benchmark import markdown_table

    print(markdown_table(rows, args.eps))
    _say_skipped(args.scenarios, args.policies, seeds, overrides, results)
    print(f"wrote {args.out}/episodes.csv, summary.csv, summary.md and plots")
    return 0


def _say_skipped(scenarios, policies, seeds, overrides: dict, results) -> None:
    """Name (on stderr) each policy that did not apply to a scenario, and why."""
    import sys

    from netsense.benchmark import make_jobs
    from netsense.benchmark.rollouts import NotApplicable, scripted_policy
    from netsense.env.registry import make

    ran = {(r["job"]["scenario"], r["job"]["policy"]) for r in results}
    skipped = [(j.scenario, j.policy) for j in make_jobs(scenarios, policies, seeds[:1],
                                                          overrides=overrides)
               if (j.scenario, j.policy) not in ran]
    for sc, pol in skipped:
        try:
            scripted_policy(pol, make(sc, **overrides), 0)
            why = "not applicable"
        except NotApplicable as exc:
            why = " ".join(str(exc).split())
        except ValueError as exc:
            why = " ".join(str(exc).split())
        print(f"note: {pol} skipped on {sc}: {why}", file=sys.stderr)


def _frontier(args: argparse.Namespace, overrides: dict) -> int:
    from netsense.benchmark.headroom import headroom, markdown_headroom
    from netsense.benchmark.lookahead import LookaheadConfig
    from netsense.benchmark.protocol import FAMILIES, markdown_frontier, run_frontier

    families = FAMILIES if args.families is None else {f: FAMILIES[f] for f in args.families}
    config = LookaheadConfig(horizon=args.reference_horizon, futures=args.reference_futures,
                             seed=args.reference_seed)
    rows = run_frontier(args.scenarios, args.out, episodes=args.seeds, seed0=args.seed0,
                        families=dict(families), learned=args.learned, overrides=overrides,
                        progress=not args.no_progress, references=args.references,
                        reference_episodes=args.reference_episodes,
                        reference_config=config,
                        reference_continuation=args.reference_continuation or "best")
    print(markdown_frontier(rows))
    if args.references:
        print(markdown_headroom(headroom(rows)))
    print(f"wrote {args.out}/frontier.csv, frontier.md and frontier_<scenario>.csv/.png"
          + (", headroom.csv and headroom.md" if args.references else ""))
    return 0
