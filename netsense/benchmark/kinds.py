"""The kinds of thing that act in a communication task (``docs/communication.md``, section 8).

``decentralised`` policies read only their own observation (scripted rules, learned
networks); ``centralised`` references read every agent's state (the age-based
schedulers); ``bound`` rows are the lookahead references of
:mod:`netsense.benchmark.bounds` (not deployable); ``learned`` rows are trained policies.
Each kind has its own column value, marker and legend group in every table and plot.
"""

from __future__ import annotations

__all__ = ["CENTRALISED_FAMILIES", "KINDS", "RANDOM_FAMILIES", "family_kind"]

KINDS = ("decentralised", "centralised", "bound", "learned")
#: Scripted families that read every agent's state (a family not listed is decentralised).
CENTRALISED_FAMILIES = frozenset({"oldest", "whittle"})
#: Scripted families that draw random bits (not a continuation for the bounds' forks).
RANDOM_FAMILIES = frozenset({"bernoulli", "aloha"})


def family_kind(family: str) -> str:
    """The kind (:data:`KINDS`) of a frontier family."""
    if family in ("learned", "bound"):
        return family
    return "centralised" if family in CENTRALISED_FAMILIES else "decentralised"
