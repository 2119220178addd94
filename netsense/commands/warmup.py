"""``netsense warmup``: compile every numba driver now instead of at the first step."""

from __future__ import annotations

import argparse

NAME = "warmup"
HELP = ("Compile (or load from numba's cache) every compiled pass the scenarios use, serial "
        "and threaded, with a progress bar; later first steps then start at once "
        "(about 45 s on a cold cache on a 2-core machine, seconds when warm; see "
        "docs/first-run.md).")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenarios", nargs="*",
                        help="scenario ids to run (default: every registered scenario)")
    parser.add_argument("--serial-only", action="store_true",
                        help="skip the threaded builds (used by batches, not by one env)")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress bar and no summary line")


def run(args: argparse.Namespace) -> int:
    from netsense.env.warmup import warmup

    rep = warmup(args.scenarios or None, threaded=not args.serial_only,
                 progress=not args.quiet)
    if not args.quiet:
        print(f"netsense warmup: {rep.tasks} tasks in {rep.seconds:.1f} s; compiled "
              f"{rep.compiled} functions, loaded {rep.loaded} builds from numba's cache")
    return 0
