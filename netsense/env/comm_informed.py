"""Informed decentralised communication rules: a base rule gated by what a task's extra
observation fields tell the agent (the announced next graph, delivery feedback).

Each rule wraps a decentralised base rule of :mod:`netsense.env.comm_policies` (spec
``rule(BASE)``, e.g. ``gated(sources:0)``, ``acked:6(event:2)``, ``phased(until:40)``)
and transmits the base rule's bits only where its gate is open: it can stay silent where
the base would talk, never the reverse. Like the rules of
:mod:`netsense.env.comm_decentralised`, a rule decides agent ``i``'s bits at ``k`` (sent at
``k + 1``) from agent ``i``'s own row of the observation, its own memory of earlier rows
and design-time constants (``N``, ``H``, the period ``P`` of a periodic link schedule);
memory is kept per batch member and agent and restarts where the member's observation
shows ``time = 0``, so a batch of seeds equals the single episodes.

=====================  =====================  ==============================================
spec                   reads (own row)        gate on the base bits for step ``k + 1``
=====================  =====================  ==============================================
``gated(BASE)``        ``next_out``           open iff the announced ``G[k+1]`` gives the
                                              agent an out-neighbour
                                              (``sum_l next_out_i^{(l)} > 0``)
``acked[:T](BASE)``    ``acks``, ``silence``  closed while the agent's last transmission
                                              that had out-links was lost on all of them
                                              (every non-zero ack ``-1``: its channel is
                                              bad), except once ``T`` steps (default 6)
                                              passed since that transmission: a probe
``phased[:P](BASE)``   ``acks``, ``silence``,  open iff the agent's last transmission at
                       ``time``               the phase ``(k + 1) mod P`` had out-links
                                              (some ack non-zero); open at phases it never
                                              sent at
=====================  =====================  ==============================================

The base rule reads its own fields besides (``news``, ``time``, ...; see its docstring).
``next_out`` needs ``[control] announce = true`` and ``acks`` needs ``[control] feedback
= true`` (:mod:`netsense.engine.control`); a rule built on a scenario whose observation
lacks its field raises a ``ValueError`` naming the field and the option. ``phased``
takes ``P`` from the scenario's periodic link schedule (``[graph] kind = "periodic"``:
the number of graphs it repeats, a design-time constant like ``N``) unless the spec
gives it (``phased:12(event:2)``); on a graph process that is not periodic the spec must
give it.

Measured on the protocol's 100 test episodes (``experiments/rl/comm_tasks.py``), each
beats every rule of the frontier that does not read these fields on the task it was
written for: ``gated`` on ``comm_announced-v0``, ``acked`` on ``comm_fading-v0``,
``phased`` on ``comm_schedule-v0``. On ``comm_schedule-v1`` ``phased(until:40)`` beats
the generic families but not ``settled:0.3(until:40)``
(:class:`netsense.env.comm_decentralised.Settled`).
"""

from __future__ import annotations

import numpy as np

from netsense.env.comm_decentralised import GatedRule, _MemberState, int_knob
from netsense.env.policies import CommPolicy

__all__ = ["FIELDS", "INFORMED", "OPTIONS", "Acked", "Gated", "InformedRule", "Phased",
           "applicable", "schedule_period"]

#: Observation field -> the ``[control]`` option that adds it.
OPTIONS = {"next_out": "announce", "acks": "feedback"}
#: Informed rule -> the optional observation fields it reads.
FIELDS = {"gated": ("next_out",), "acked": ("acks",), "phased": ("acks",)}
#: The informed families (spec name -> (knob type, default knob); ``None``: no knob, or
#: for ``phased`` the schedule's period).
INFORMED = {"gated": (None, None), "acked": (int, 6), "phased": (int, None)}


def schedule_period(model) -> int | None:
    """The period of the model's link schedule (the number of graphs a
    :class:`~netsense.graphs.processes.PeriodicGraphs` repeats), None if not periodic."""
    from netsense.graphs.processes import PeriodicGraphs

    graphs = getattr(model, "graphs", None)
    return len(graphs.graphs) if isinstance(graphs, PeriodicGraphs) else None


def applicable(model) -> tuple[str, ...]:
    """The informed families a scenario's observation supports (its communication-only
    mode carries their fields; ``phased`` also needs a periodic link schedule)."""
    control = model.control
    if not control.comm_only:
        return ()
    have = {"next_out": bool(control.announce), "acks": bool(control.feedback)}
    out = [name for name, fields in FIELDS.items() if all(have[f] for f in fields)]
    if "phased" in out and schedule_period(model) is None:
        out.remove("phased")
    return tuple(out)


class InformedRule(GatedRule):
    """A decentralised base rule whose bits pass only where :meth:`gate` is open, the gate
    reading the optional observation fields of :data:`FIELDS`.

    Parameters
    ----------
    layout, width, horizon
        As :class:`netsense.env.policies.CommPolicy`.
    base : CommPolicy
        The decentralised base rule (same layout, width and horizon).
    """

    name = "informed"

    def __init__(self, layout, width, horizon, base: CommPolicy) -> None:
        super().__init__(layout, width, horizon, base)
        for f in FIELDS[self.name]:
            if getattr(layout, f) is None:
                raise ValueError(
                    f"{self.name} reads the observation field {f!r}, which this "
                    f"scenario's observation lacks: set [control] {OPTIONS[f]} = true "
                    f"(override control={{'{OPTIONS[f]}': True}})")

    def own_steps(self, obs: np.ndarray) -> np.ndarray:
        """``(B, N)`` time index ``k`` read from each agent's own row."""
        return np.rint(obs[..., self.layout.time.start] * self.horizon).astype(np.int64)


class Gated(InformedRule):
    """The base rule's bits where the announced ``G[k+1]`` gives the agent an
    out-neighbour. Reads the own row's ``next_out`` (``[control] announce = true``)."""

    name = "gated"

    def gate(self, obs):
        return obs[..., self.layout.next_out].sum(-1) > 0


class Acked(InformedRule):
    """The base rule's bits unless the agent's last transmission that had out-links was
    lost on all of them; after ``probe`` steps since that transmission it may try again.

    Reads the own row's ``acks`` (``[control] feedback = true``) and ``silence`` (0: the
    agent transmitted at ``k``, so the acks are about its own message). Memory per member
    and agent: whether the channel was good at the last such transmission (initially
    yes) and the steps since.
    """

    name = "acked"

    def __init__(self, layout, width, horizon, base: CommPolicy, probe: int = 6) -> None:
        super().__init__(layout, width, horizon, base)
        self.probe = int_knob("acked", probe, 1)
        self.mem = _MemberState()

    def gate(self, obs):
        L, N = self.layout, self.N
        self.mem.restart(self.steps(obs), {"ok": ((N,), True), "since": ((N,), 0)})
        ok, since = self.mem["ok"], self.mem["since"]
        acks = obs[..., L.acks]
        seen = (obs[..., L.silence.start] == 0) & (acks != 0).any(-1)
        ok[...] = np.where(seen, (acks > 0).any(-1), ok)
        since[...] = np.where(seen, 0, since + 1)
        return ok | (since >= self.probe)


class Phased(InformedRule):
    """The base rule's bits where the agent's last transmission at the phase ``(k + 1)
    mod P`` of a periodic link schedule had out-links (phases it never sent at: open).

    Reads the own row's ``acks`` (``[control] feedback = true``), ``silence`` (0: it
    transmitted at ``k``) and ``time``. ``period``: ``P``, the number of graphs the
    schedule repeats (a design-time constant). Memory per member and agent: one bit per
    phase.
    """

    name = "phased"

    def __init__(self, layout, width, horizon, base: CommPolicy, period: int) -> None:
        super().__init__(layout, width, horizon, base)
        self.period = int_knob("phased", period, 1)
        self.mem = _MemberState()

    def gate(self, obs):
        L, N, P = self.layout, self.N, self.period
        self.mem.restart(self.steps(obs), {"table": ((N, P), True)})
        table = self.mem["table"]
        k = self.own_steps(obs)  # (B, N)
        b, i = np.nonzero(obs[..., L.silence.start] == 0)
        table[b, i, k[b, i] % P] = (obs[b, i][:, L.acks] != 0).any(-1)
        nxt = (k + 1) % P
        return np.take_along_axis(table, nxt[..., None], axis=2)[..., 0]
