"""``netsense grid``: the IEEE 37-node feeder's OpenDSS script and linear-model check."""

from __future__ import annotations

import argparse

from netsense.commands._args import nonnegative_float

NAME = "grid"
HELP = ("IEEE 37-node feeder: write the OpenDSS script generated from netsense's own data, "
        "or compare the linear power-flow model (eq. (39)) with an OpenDSS solve.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=("script", "validate"),
                        help="script: print the OpenDSS script; validate: linear model vs "
                             "OpenDSS (needs the grid extra)")
    parser.add_argument("--load-scale", type=nonnegative_float, default=1.0,
                        help="multiple of the nominal spot loads (default: 1.0)")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from netsense.grid import linearize, load_ieee37
    from netsense.grid.opendss import opendss_script, solve_opendss

    feeder = load_ieee37()
    x = args.load_scale * feeder.nominal_injections()
    if args.action == "script":
        print(opendss_script(feeder, x))
        return 0
    lp = linearize(feeder)
    v = solve_opendss(feeder, x)
    err = np.abs(lp.voltages(x) - v)
    print(f"IEEE 37 at {args.load_scale:g} x nominal load: min |v| = {np.abs(v).min():.4f} pu; "
          f"linear model error max {err.max():.2e} pu, mean {err.mean():.2e} pu")
    return 0
