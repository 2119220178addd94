"""Argument types shared by the sub-commands: a bad value is an argparse error (exit code 2,
one line naming the option), never a traceback from deep inside a command.

Not a command (the leading underscore keeps :mod:`netsense.cli` from listing it).
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable
from typing import Any

__all__ = ["finite_float", "json_value", "nonnegative_float", "nonnegative_int",
           "positive_float", "positive_int"]


def _int(text: str, lo: int) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid integer: {text!r}") from None
    if v < lo:
        raise argparse.ArgumentTypeError(f"must be >= {lo}, got {v}")
    return v


def positive_int(text: str) -> int:
    """An integer >= 1."""
    return _int(text, 1)


def nonnegative_int(text: str) -> int:
    """An integer >= 0."""
    return _int(text, 0)


def _float(text: str, ok: Callable[[float], bool], what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid number: {text!r}") from None
    if not math.isfinite(v) or not ok(v):
        raise argparse.ArgumentTypeError(f"must be {what}, got {text}")
    return v


def finite_float(text: str) -> float:
    """A finite number."""
    return _float(text, lambda v: True, "a finite number")


def positive_float(text: str) -> float:
    """A finite number > 0."""
    return _float(text, lambda v: v > 0, "a finite number > 0")


def nonnegative_float(text: str) -> float:
    """A finite number >= 0."""
    return _float(text, lambda v: v >= 0, "a finite number >= 0")


def json_value(text: str) -> Any:
    """A JSON value (a matrix such as ``[[2.0]]``)."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"not valid JSON ({exc.msg}): {text!r}") from None
