"""The kinds of thing that act in a communication task: the rungs of the score ladder.

From what an agent could run to what nothing can beat (each kind has its own column
value, marker and legend group in every table and plot):

=================  ===========================================================================
kind               what
=================  ===========================================================================
``decentralised``  reads only the agent's own observation history: the scripted rules of
                   :mod:`netsense.env.comm_policies` (the informed rules of
                   :mod:`netsense.env.comm_informed` included) and the endpoints; "best
                   decentralised" is the best of all of them on the same episodes
``privileged``     decentralised in form, but reads what no agent observes (the next graph,
                   the next arrivals: :mod:`netsense.env.comm_privileged`); evidence of what
                   information is worth, never a baseline
``centralised``    schedulers that read every agent's state (``oldest``, ``whittle``)
``reference``      full-information reference schedulers (causal / clairvoyant): the
                   lookahead searches of :mod:`netsense.benchmark.lookahead`, achieved
                   returns that say what is reachable, not what is possible
``upper_bound``    certified upper bounds of a relaxation (no policy may exceed them)
``learned``        trained policies (decentralised networks)
=================  ===========================================================================
"""

from __future__ import annotations

from netsense.env.comm_policies import CENTRALISED, INFORMED, PRIVILEGED, spec_family

__all__ = ["CENTRALISED_FAMILIES", "INFORMED_FAMILIES", "KINDS", "PRIVILEGED_FAMILIES",
           "RANDOM_FAMILIES", "REFERENCE_LABELS", "SCRIPTED_KINDS", "family_kind",
           "reference_label", "spec_family"]

KINDS = ("decentralised", "privileged", "centralised", "reference", "upper_bound",
         "learned")
#: Kinds of the scripted rows (a family of :mod:`netsense.env.comm_policies`).
SCRIPTED_KINDS = ("decentralised", "privileged", "centralised")
#: Scripted families that read every agent's state (a family not listed is decentralised).
CENTRALISED_FAMILIES = frozenset(CENTRALISED)
#: Scripted families that read the simulation core (the next graph, the next arrivals).
PRIVILEGED_FAMILIES = frozenset(PRIVILEGED)
#: Decentralised families that read a task's optional observation fields.
INFORMED_FAMILIES = frozenset(INFORMED)
#: Scripted families that draw random bits (not a continuation for the references' forks).
RANDOM_FAMILIES = frozenset({"bernoulli", "aloha"})


def family_kind(family: str) -> str:
    """The kind (:data:`KINDS`) of a frontier family (or of a policy spec's family)."""
    if family in ("learned", "reference", "upper_bound"):
        return family
    family = spec_family(family)
    if family in CENTRALISED_FAMILIES:
        return "centralised"
    return "privileged" if family in PRIVILEGED_FAMILIES else "decentralised"


#: Labels of the full-information reference schedulers in tables and legends.
REFERENCE_LABELS = {"reference:causal": "full-information reference (causal)",
                    "reference:clairvoyant": "full-information reference (clairvoyant)"}


def reference_label(policy: str) -> str:
    """The label of a reference row's policy (``reference:causal`` -> "full-information
    reference (causal)"; a continuation named in the spec is kept)."""
    name, _, rest = str(policy).partition(":")
    kind, _, cont = rest.partition(":")
    label = REFERENCE_LABELS.get(f"{name}:{kind}", str(policy))
    return f"{label}, continuing {cont}" if cont and label != policy else label
