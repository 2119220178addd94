"""``netsense demo``: the paper's Fig. 1/Fig. 2 example in one command."""

from __future__ import annotations

import argparse

from netsense.commands._args import nonnegative_int, positive_int

NAME = "demo"
HELP = "Run the Fig. 1/2 example (consensus diverges, freshness converges) and write its figure."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--steps", type=positive_int, default=30, help="time steps to simulate")
    parser.add_argument("--seed", type=nonnegative_int, default=0,
                        help="seed of the initial estimates")
    parser.add_argument("--out", default="netsense_demo", help="output directory")


def run(args: argparse.Namespace) -> int:
    from netsense.studies.examples import run_fig2, save_fig2, summarize_fig2

    result = run_fig2(steps=args.steps, seed=args.seed)
    csv, png = save_fig2(result, args.out, stem="fig2")
    print("Scalar plant x[k+1] = 2 x[k]; node 1 measures x; the graph alternates "
          "between the two graphs of Fig. 1.")
    print(summarize_fig2(result))
    print(f"wrote {png} and {csv}")
    return 0
