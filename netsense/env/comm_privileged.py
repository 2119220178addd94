"""Privileged communication rules: decentralised in form, but gated on what no agent
observes (the next graph and the next step's arrivals, read from the simulation core).

They are evidence of what information is worth, never a baseline: kind ``privileged`` in
every table and plot, never the "best decentralised" point (the score ladder of the
design notes). A rule wraps a decentralised base rule of
:mod:`netsense.env.comm_policies` (spec ``rule(BASE)``) and passes the base rule's bits
where its gate is open:

==========================  ==================================================================
spec                        gate on the base bits for step ``k + 1`` (read from the core)
==========================  ==================================================================
``oracle(BASE)``            the message of step ``k + 1`` reaches someone: some out-link
                            ``i -> l`` of ``G[k+1]`` whose arrival of step ``k + 1`` is drawn
                            true (collisions on a shared channel are not foreseen)
``oracle_channel(BASE)``    the sender's links deliver at ``k + 1``: some arrival of step
                            ``k + 1`` on a link from ``i`` is drawn true, out-links or not
                            (the sender's fading state; no different from the base where
                            messages are never dropped)
==========================  ==================================================================

``G[k+1]`` and the arrivals of ``k + 1`` come from the core's drawn chunk, or, at a chunk's
last step, from a peek at copies of the member's generators (nothing is drawn, so the
realisation is the same as without the rule; no ``announce`` option is needed).
"""

from __future__ import annotations

import copy

import numpy as np

from netsense.env.policies import CommPolicy

__all__ = ["PRIVILEGED", "Oracle", "applicable"]

#: The privileged families (spec name -> (knob type, default knob)).
PRIVILEGED = {"oracle": (None, None), "oracle_channel": (None, None)}


def applicable(model) -> tuple[str, ...]:
    """The privileged families worth running on a scenario: ``oracle`` in every
    communication-only mode, ``oracle_channel`` where messages can be dropped."""
    from netsense.sensing.arrivals import AlwaysArrive

    if not model.control.comm_only:
        return ()
    drops = not isinstance(model.message_arrivals, AlwaysArrive)
    return ("oracle", "oracle_channel") if drops else ("oracle",)


class Oracle(CommPolicy):
    """Privileged: the base rule's bits where the next message reaches someone
    (``channel=False``) or the sender's links deliver at ``k + 1`` (``channel=True``).

    Parameters
    ----------
    core : BatchedCore
        The core the rule acts on (read at every call, never written).
    base : CommPolicy
        The base rule.
    channel : bool
        Gate on the arrivals alone (``oracle_channel``).
    """

    name = "oracle"

    def __init__(self, core, base: CommPolicy, channel: bool = False) -> None:
        super().__init__(core.layout, core.comm.width, core.horizon)
        if not isinstance(base, CommPolicy):
            raise ValueError(f"oracle: base must be a communication policy, got "
                             f"{type(base).__name__}")
        self.core, self.base, self.channel = core, base, bool(channel)
        if channel:
            self.name = "oracle_channel"

    def next_arrivals(self) -> np.ndarray:
        """``(B, N, N)`` arrivals of step ``k + 1`` (``[b, i, l]``: link ``l -> i``), from
        the chunk or a peek at a copy of the member's arrival sampler."""
        c = self.core
        if c.buf_msg is None:
            return np.ones((c.B, c.N, c.N), bool)
        out = np.empty((c.B, c.N, c.N), bool)
        for b in range(c.B):
            p = int(c.ptr[b]) + 1
            out[b] = (c.buf_msg[b, p] if p < c.chunk
                      else copy.deepcopy(c.msg_sampler[b]).next())
        return out

    def next_slots(self) -> np.ndarray:
        """``(B, N, D)`` slots of ``G[k+1]`` (the core's announced ones if it has them)."""
        c = self.core
        if c.nbr_next is not None:
            return c.nbr_next
        out = np.empty((c.B, c.N, c.D), dtype=np.int64)
        inside = c.ptr + 1 < c.chunk
        b = np.flatnonzero(inside)
        out[b] = c.buf_nbr[b, c.ptr[b] + 1]
        if not inside.all():
            b = np.flatnonzero(~inside)
            out[b] = c.peek_next_graphs(b)[0]
        return out

    def gate(self) -> np.ndarray:
        """``(B, N)`` bool: whether agent ``i``'s message of ``k + 1`` would get through."""
        c = self.core
        arrive = self.next_arrivals()
        if self.channel:
            return arrive.any(1)
        links = np.zeros((c.B, c.N, c.N), bool)  # [b, i, l]: l -> i in G[k+1]
        nbr = self.next_slots()
        b, i, d = np.nonzero(nbr >= 0)
        links[b, i, nbr[b, i, d]] = True
        return (links & arrive).any(1)

    def act(self, obs, mask):
        return self.base.act(obs, mask) * self.gate()[..., None]
