"""``netsense list``: the registered scenarios (one per file in ``netsense/env/scenarios/``)."""

from __future__ import annotations

import argparse
import shutil
import textwrap

NAME = "list"
HELP = "List the registered environment scenarios (ids for netsense.env.registry.make)."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--details", action="store_true",
                        help="also print N, n, max in-degree D and the horizon")


def run(args: argparse.Namespace) -> int:
    from netsense.env.registry import list_scenarios, load

    width = shutil.get_terminal_size((100, 24)).columns
    for sid in list_scenarios():
        sc = load(sid)
        head = f"{sid:<32}"
        if args.details:
            from netsense.env.registry import _cached_model

            m = _cached_model(sid)
            head = (f"{sid:<32} N={m.plant.num_agents:<4} n={m.plant.n:<3} "
                    f"D={m.graphs.max_in_degree:<3} horizon={m.horizon:<5}")
        print(wrap_row(head, " ".join(sc.description.split()), width))
    return 0


def wrap_row(head: str, text: str, width: int) -> str:
    """``head`` then ``text`` wrapped to ``width`` columns, continuation lines aligned
    under the text (or, when ``head`` leaves under 40 columns, indented below it)."""
    indent = len(head) + 1
    if width - indent < 40:
        body = textwrap.fill(text, width=max(width, 40), initial_indent="    ",
                             subsequent_indent="    ")
        return f"{head.rstrip()}\n{body}"
    return textwrap.fill(text, width=width, initial_indent=head + " ",
                         subsequent_indent=" " * indent)
