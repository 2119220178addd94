"""The ``netsense`` console command.

Sub-commands live one per module in :mod:`netsense.commands`; each module defines
``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``. Discovery is by
module listing, so adding a command never edits this file.

Errors: a bad argument or input (an unknown scenario, a malformed file, a value out of
range) ends the command with exit code 2 and one line on stderr, ``netsense CMD: error:
MESSAGE``, never a traceback: argparse's own errors (printed without the usage block), and
the ``ValueError``, ``OSError``, :class:`netsense.NumericalError`, ``ImportError`` (a
missing extra) and ``MemoryError`` a command raises. Anything else is a bug and keeps its
traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
from collections.abc import Sequence

import netsense.commands as _commands

#: What a command may raise for bad input (reported in one line, exit code 2).
USER_ERRORS = (ValueError, OSError, ArithmeticError, ImportError, MemoryError)


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line on stderr (exit code 2)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


#: the extra that installs a missing top-level module (what a user should install)
EXTRA_OF = {"torch": "torchrl", "torchrl": "torchrl", "tensordict": "torchrl",
            "stable_baselines3": "rl", "sb3_contrib": "rl", "supersuit": "rl",
            "ray": "rllib", "rliable": "analysis", "opendssdirect": "grid"}


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    name = (getattr(exc, "name", None) or "").split(".")[0]
    if isinstance(exc, ModuleNotFoundError) and name in EXTRA_OF:
        extra = EXTRA_OF[name]
        torch = "pip install torch==2.13.0 && " if extra in ("torchrl", "rl", "rllib") else ""
        return (f"this needs {name!r}, which is not installed: {torch}pip install -e "
                f"\".[{extra}]\"")
    return text if isinstance(exc, ValueError) else f"{type(exc).__name__}: {text}"


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser with every discovered sub-command attached."""
    parser = _Parser(
        prog="netsense",
        description="Networked state estimation: distributed observers, environments, benchmarks.",
    )
    parser.add_argument("--debug", action="store_true",
                        help="on an error, show the full traceback instead of one line")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(_commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"netsense.commands.{info.name}")
        cmd = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(cmd)
        cmd.set_defaults(_run=module.run)
    return parser


def _unknown_options(parser: argparse.ArgumentParser, args: argparse.Namespace,
                     extra: list[str]) -> None:
    """Report arguments no parser took under the sub-command they were given to (``netsense
    train: error: unrecognized arguments: --stpes 5 (did you mean --steps?)``)."""
    import difflib

    target = parser
    for action in parser._actions:  # the sub-command's own parser, when there is one
        if isinstance(action, argparse._SubParsersAction) and args.command:
            target = action.choices[args.command]
    known = [o for a in target._actions for o in a.option_strings if o.startswith("--")]
    hints = []
    for arg in extra:
        if arg.startswith("-"):
            close = difflib.get_close_matches(arg.split("=", 1)[0], known, n=1, cutoff=0.6)
            if close:
                hints.append(f"{arg.split('=', 1)[0]} -> {close[0]}?")
    hint = f" (did you mean: {', '.join(hints)})" if hints else ""
    target.error(f"unrecognized arguments: {' '.join(extra)}{hint}")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``netsense`` command; returns the process exit code."""
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:
        _unknown_options(parser, args, extra)
    if getattr(args, "_run", None) is None:
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except BrokenPipeError:  # `netsense list | head`: the reader left; say nothing more
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except USER_ERRORS as exc:
        if args.debug:
            raise
        print(f"netsense {args.command}: error: {_one_line(exc)} (--debug for the traceback)",
              file=sys.stderr)
        return 2
    except SystemExit as exc:  # a command's own "raise SystemExit('message')"
        if isinstance(exc.code, str):
            print(f"netsense {args.command}: error: {exc.code}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
