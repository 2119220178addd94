"""``netsense list``: the registered scenarios (one per file in ``netsense/env/scenarios/``)."""

from __future__ import annotations

import argparse

NAME = "list"
HELP = "List the registered environment scenarios (ids for netsense.env.registry.make)."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--details", action="store_true",
                        help="also print N, n, max in-degree D and the horizon")


def run(args: argparse.Namespace) -> int:
    from netsense.env.registry import list_scenarios, load

    for sid in list_scenarios():
        sc = load(sid)
        line = f"{sid:<32} {sc.description}"
        if args.details:
            from netsense.env.registry import _cached_model

            m = _cached_model(sid)
            line = (f"{sid:<32} N={m.plant.num_agents:<4} n={m.plant.n:<3} "
                    f"D={m.graphs.max_in_degree:<3} horizon={m.horizon:<5} {sc.description}")
        print(line)
    return 0
