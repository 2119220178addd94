"""Communication baselines: scripted transmit rules, each with a knob that trades messages
for accuracy (the scripted frontier of the communication-only control modes).

They act in the communication-only modes of :mod:`netsense.engine.control`, where the
scenario's fusion rule (freshness by default) adopts and an action is ``W`` bits per agent
(``W = 1``: transmit; ``W = M``: one bit per substate). A bit set at step ``k`` sends at
``k + 1``; every rule below decides ``t_i[k + 1]`` (and, per substate, ``s_i^{(j)}[k+1]``)
from the observation at ``k``, in one numpy pass over ``(B, N, ...)``. In ``"substates"``
mode a transmitting agent sends every substate it has an estimate of, except where the
rule says which (event-triggered, schedulers). Rules and knobs:

=================  ======  ===================================================================
spec               knob    rule (``k`` the step whose action is taken, ``H`` the horizon)
=================  ======  ===================================================================
``always``         --      ``t_i = 1`` (with freshness fusion: the freshness observer)
``never``          --      ``t_i = 0``
``periodic:P``     P >= 1  ``t_i[k+1] = 1`` iff ``(k + 1 + i) mod P = 0``: every ``P`` steps,
                           agents staggered by id (round robin; ``N/P`` senders per step)
``bernoulli:p``    p       ``t_i[k+1] ~ Bernoulli(p)``, independent over agents and steps
``sources:P``      P >= 0  agents with a non-empty block of Lemma 1 always; the others as
                           ``periodic:P`` (``P = 0``: never, "sources only")
``event:d``        d >= 1  send substate ``j`` iff ``news_i^{(j)} H >= d``: the information
                           the next message would carry was generated at least ``d`` steps
                           after what ``i`` last sent of ``j`` (never sent: always news)
``until:T[,d]``    T, d    ``always`` (``event:d`` if ``d >= 1``) at the steps ``< T``, then
                           never: talk while the estimates converge, then stop
``settle:e[,W]``   e, W    talk until the own estimate's relative correction stayed below
                           ``e`` for ``W`` steps (default 5), then stop (send-on-delta)
``aloha:g,q``      g, q    threshold ALOHA on the age gain (Chen et al., IEEE TIT 2022):
                           active iff gain ``>= g N / K``, then transmit w.p. ``q K / N``;
                           ``aloha:2.2,4.69`` is the proven ``K = 1`` optimum
``tdma:F``         F >= 1  the sources take turns, ``K`` per slot, one slot every ``F``
                           steps (time division from time and rank only)
``oldest:m``       m >= 1  centralised: the ``m`` agents with the largest total age
                           reduction ``I_l = sum_{i != l, j} h_{lij}`` send
``whittle:m``      m >= 1  centralised: the same with the Whittle index ``h (h + 1) / 2``
=================  ======  ===================================================================

Rules that wrap a decentralised base rule (``rule(BASE)`` or ``rule:knob(BASE)``, e.g.
``gated(sources:0)``, ``acked:6(event:2)``; the base is a spec of the table above other
than the schedulers, and no wrapped spec):

=========================  =======  ==============================================================
spec                       knob     rule
=========================  =======  ==============================================================
``gated(BASE)``            --       informed: the base's bits where the announced next graph
                                    gives the agent an out-neighbour (field ``next_out``)
``acked[:T](BASE)``        T >= 1   informed: silent while the last transmission that had
                                    out-links was lost, probing after ``T`` steps (``acks``)
``settled[:e](BASE)``      e > 0    decentralised: the base's bits once the agent's own-block
                                    estimate has settled (relative correction below ``e``;
                                    :class:`~netsense.env.comm_decentralised.Settled`)
``phased[:P](BASE)``       P >= 1   informed: the base's bits where the last transmission at
                                    the phase ``(k + 1) mod P`` had out-links (``acks``; ``P``
                                    defaults to the period of a periodic link schedule)
``oracle(BASE)``           --       privileged: where the next message reaches someone
``oracle_channel(BASE)``   --       privileged: where the sender's links deliver next step
=========================  =======  ==============================================================

The informed rules (:mod:`netsense.env.comm_informed`) are decentralised policies that
read fields only some tasks have; the privileged rules (:mod:`netsense.env.comm_privileged`)
read the simulation core (the next graph and arrivals), which no agent observes.

The rules from ``until`` to ``tdma`` (memory, randomness, clock; their sources and exact
rules) are in :mod:`netsense.env.comm_decentralised`; ``K`` is the channel capacity
(``N`` without a channel). Every rule but the schedulers and the privileged rules reads
only agent ``i``'s own observation (and memory): they are decentralised policies.

Age reduction ``h_{lij} = [tau_i^{(j)} - tau_l^{(j)}]_+`` of receiver ``i``'s age of
substate ``j`` were it to adopt sender ``l``'s (``tau_i^{(j)} = omega`` counts as ``H``,
``tau_l^{(j)} = omega`` gives 0), from every agent's indices in the observations. The
schedulers read all ``N`` observations of a member, so they are a centralised reference
(a scheduler that knows every age), not a decentralised policy; the next graph is
unknown to them, so every other agent counts as a receiver. ``whittle`` is the Whittle
index of Kadota et al. (IEEE/ACM ToN 2018) for reliable links, ``W(h) = w p h (h + 2/p -
1) / 2`` with ``w = p = 1``; ``oldest`` is max-age-first with the linear age ``h``. In
``"substates"`` mode a scheduled agent sends the substates ``j`` with ``sum_i h_{lij} >
0``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netsense.env.comm_decentralised import (
    MemberUniforms,
    Settle,
    Settled,
    Tdma,
    ThresholdAloha,
    Until,
    int_knob,
)
from netsense.env.comm_informed import (
    FIELDS,
    INFORMED,
    OPTIONS,
    Acked,
    Gated,
    Phased,
    schedule_period,
)
from netsense.env.comm_privileged import PRIVILEGED, Oracle
from netsense.env.policies import CommPolicy, TransmitAll, TransmitNone

__all__ = ["CENTRALISED", "COMM_POLICIES", "INFORMED", "PRIVILEGED", "WRAPPERS",
           "AgeScheduler", "Bernoulli", "EventTriggered", "Periodic", "Settle",
           "SourcesFirst", "Tdma", "ThresholdAloha", "Until", "make_comm_policy",
           "parse_spec", "spec_family"]


class Periodic(CommPolicy):
    """Every ``period`` steps, staggered by agent id (``stagger=False``: all at once)."""

    name = "periodic"

    def __init__(self, layout, width, horizon, period: int = 2, stagger: bool = True) -> None:
        super().__init__(layout, width, horizon)
        self.period = int_knob("periodic", period, 1)
        self.phase = np.arange(self.N) if stagger else np.zeros(self.N, dtype=np.int64)

    def act(self, obs, mask):
        k = self.steps(obs)
        send = (k[:, None] + 1 + self.phase[None]) % self.period == 0
        return self._send(mask, send)


class Bernoulli(CommPolicy):
    """Transmit with probability ``p``, independently per agent and step.

    ``seed``: an int (or None) seeds one generator for the batch; a sequence of ``B``
    seeds gives member ``b`` its own generator, as :class:`netsense.env.policies.
    RandomPolicy` does (so a batch of seeds equals the single episodes).
    """

    name = "bernoulli"

    def __init__(self, layout, width, horizon, p: float = 0.5,
                 seed: int | Sequence[int] | None = None) -> None:
        super().__init__(layout, width, horizon)
        p = float(p)
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"bernoulli: p must be a probability in [0, 1], got {p!r}")
        self.p = p
        self.uniforms = MemberUniforms(seed)

    def act(self, obs, mask):
        return self._send(mask, self.uniforms(obs.shape[0], (self.N,)) < self.p)


class SourcesFirst(CommPolicy):
    """Sources (non-empty blocks) every step; relays every ``relay_period`` steps (0: never)."""

    name = "sources"

    def __init__(self, layout, width, horizon, is_source: np.ndarray,
                 relay_period: int = 0) -> None:
        super().__init__(layout, width, horizon)
        self.relay_period = int_knob("sources", relay_period, 0)
        self.is_source = np.asarray(is_source, dtype=bool)
        if self.is_source.shape != (self.N,):
            raise ValueError(f"is_source must have shape ({self.N},)")

    def act(self, obs, mask):
        k = self.steps(obs)
        send = np.broadcast_to(self.is_source, (obs.shape[0], self.N)).copy()
        if self.relay_period:
            send |= (k[:, None] + 1 + np.arange(self.N)) % self.relay_period == 0
        return self._send(mask, send)


class EventTriggered(CommPolicy):
    """Send (substate ``j``) when the next message's information is ``threshold`` steps
    newer than what was last sent (the observation's ``news``)."""

    name = "event"

    def __init__(self, layout, width, horizon, threshold: int = 2) -> None:
        super().__init__(layout, width, horizon)
        self.threshold = int_knob("event", threshold, 1)

    def act(self, obs, mask):
        news = np.rint(obs[..., self.layout.news] * self.horizon) >= self.threshold
        return self._send(mask, news if self.width > 1 else news.any(-1))


class AgeScheduler(CommPolicy):
    """Centralised: the ``slots`` agents with the largest age-reduction index send.

    ``index = "oldest"``: ``W(h) = h``; ``"whittle"``: ``W(h) = h (h + 1) / 2``.
    """

    name = "scheduler"

    def __init__(self, layout, width, horizon, slots: int = 1, index: str = "whittle",
                 columns: np.ndarray | None = None) -> None:
        super().__init__(layout, width, horizon)
        #: (M,) bool: substates that count (non-empty blocks; default all)
        self.columns = (np.ones(self.M, bool) if columns is None
                        else np.asarray(columns, dtype=bool))
        self.slots = int_knob(index, slots, 1)
        if index not in ("oldest", "whittle"):
            raise ValueError(f"index must be 'oldest' or 'whittle', got {index!r}")
        self.index = index

    def gains(self, obs: np.ndarray) -> np.ndarray:
        """``(B, N, M)``: ``sum_{i != l} W(h_{lij})`` for every sender ``l`` and substate."""
        L, H = self.layout, self.horizon
        omega = obs[..., L.own_omega] > 0.5  # (B, N, M)
        age = np.where(omega, float(H), np.rint(obs[..., L.own_age] * H))
        h = age[:, None, :, :] - age[:, :, None, :]  # [b, l, i, j] = tau_i - tau_l
        h = np.where(omega[:, :, None, :] | ~self.columns, 0.0, np.maximum(h, 0.0))
        w = h if self.index == "oldest" else h * (h + 1.0) / 2.0
        return w.sum(2)  # (the i = l term is 0)

    def act(self, obs, mask):
        g = self.gains(np.asarray(obs))
        total = g.sum(-1)  # (B, N)
        order = np.argsort(-total, axis=1, kind="stable")  # ties: smallest id first
        rank = np.empty_like(order)
        np.put_along_axis(rank, order, np.arange(self.N)[None], axis=1)
        send = (rank < self.slots) & (total > 0)
        return self._send(mask, send[..., None] & (g > 0) if self.width > 1 else send)


#: spec name -> (knob type, default knob); ``always`` and ``never`` take none; families
#: with two knobs (``name:knob1,knob2``) give a tuple of types and of defaults (a
#: default ``None`` makes the knob required). The rules that wrap a base rule
#: (:data:`WRAPPERS`) follow.
COMM_POLICIES = {"always": (None, None), "never": (None, None), "periodic": (int, 2),
                 "bernoulli": (float, 0.5), "sources": (int, 0), "event": (int, 2),
                 "until": ((int, int), (None, 0)), "settle": ((float, int), (None, 5)),
                 "aloha": ((float, float), (2.2, 4.69)), "tdma": (int, 1),
                 "oldest": (int, 1), "whittle": (int, 1)}
#: Families that read every agent's observation (a coordinator's reference, not a
#: decentralised policy).
CENTRALISED = ("oldest", "whittle")
#: Rules that wrap a decentralised base rule, ``name[:knob](BASE)``: the informed ones
#: (decentralised, reading optional observation fields), ``settled`` (decentralised,
#: reading the agent's own estimate) and the privileged ones (read the core). A knob
#: default ``None`` of ``phased`` means the scenario's schedule period.
WRAPPERS = {**INFORMED, "settled": (float, 0.1), **PRIVILEGED}
COMM_POLICIES.update(WRAPPERS)


def spec_family(spec: str) -> str:
    """The family of a policy spec: ``"periodic:4"`` -> ``"periodic"``,
    ``"acked:6(event:2)"`` -> ``"acked"``, ``"gated(sources:0)"`` -> ``"gated"``."""
    return str(spec).split("(", 1)[0].partition(":")[0]


def parse_spec(spec: str) -> tuple[str, float | int | tuple | None]:
    """``"periodic:4"`` -> ``("periodic", 4)``, ``"aloha:2.2,4.69"`` -> ``("aloha", (2.2,
    4.69))``; the default knob(s) when none is given. A wrapping rule gives ``(knob,
    base)``: ``"acked(sources:0)"`` -> ``("acked", (6, "sources:0"))``,
    ``"gated(event:2)"`` -> ``("gated", (None, "event:2"))``."""
    spec = str(spec)
    head, paren, rest = spec.partition("(")
    name = head.partition(":")[0]
    if name in WRAPPERS or paren:
        return _parse_wrapped(spec, head, paren, rest)
    return _parse_plain(spec)


def _parse_wrapped(spec: str, head: str, paren: str, rest: str) -> tuple[str, tuple]:
    name, _, arg = head.partition(":")
    if name not in WRAPPERS:
        raise ValueError(f"{spec!r}: only {', '.join(WRAPPERS)} wrap a base rule "
                         "(rule(BASE))")
    if not paren or not rest.endswith(")"):
        raise ValueError(f"{spec!r}: {name} wraps a decentralised base rule: "
                         f"{name}(BASE), e.g. {name}(sources:0)")
    base = rest[:-1]
    if not base:
        raise ValueError(f"{spec!r}: {name}(BASE) needs a base rule, e.g. {name}(sources:0)")
    bname = spec_family(base)
    if "(" in base or bname in WRAPPERS:
        raise ValueError(f"{spec!r}: the base of {name} must be a plain rule, not a wrapped "
                         f"one ({base!r})")
    if bname in CENTRALISED:
        raise ValueError(f"{spec!r}: the base of {name} must be decentralised; {bname} is a "
                         "centralised scheduler")
    _parse_plain(base)  # unknown names and bad knobs of the base raise here
    kind, default = WRAPPERS[name]
    if kind is None:
        if arg:
            raise ValueError(f"{spec!r}: {name} takes no knob")
        return name, (None, base)
    if not arg.strip():
        return name, (default, base)
    try:
        knob = kind(arg)
    except ValueError as exc:
        raise ValueError(f"{spec!r}: the knob of {name} must be an {kind.__name__}") from exc
    return name, (knob, base)


def _parse_plain(spec: str) -> tuple[str, float | int | tuple | None]:
    name, _, arg = spec.partition(":")
    if name not in COMM_POLICIES:
        raise ValueError(f"unknown communication policy {name!r}; choose from "
                         f"{', '.join(COMM_POLICIES)}")
    kind, default = COMM_POLICIES[name]
    if kind is None:
        if arg:
            raise ValueError(f"{name} takes no knob, got {spec!r}")
        return name, None
    kinds = kind if isinstance(kind, tuple) else (kind,)
    defaults = default if isinstance(kind, tuple) else (default,)
    parts = arg.split(",") if arg else []
    if len(parts) > len(kinds):
        raise ValueError(f"{spec!r}: {name} takes at most {len(kinds)} knob(s)")
    values = []
    for t, d, part in zip(kinds, defaults, parts + [""] * (len(kinds) - len(parts)),
                          strict=True):
        if not part.strip():
            if d is None:
                raise ValueError(f"{spec!r}: {name} needs its knob(s): {name}:"
                                 + ",".join(x.__name__ for x in kinds))
            values.append(d)
            continue
        try:
            values.append(t(part))
        except ValueError as exc:
            raise ValueError(f"{spec!r}: the knobs of {name} must be "
                             f"{', '.join(x.__name__ for x in kinds)}") from exc
    return name, tuple(values) if isinstance(kind, tuple) else values[0]


def make_comm_policy(spec: str, env, seed: int | Sequence[int] | None = None) -> CommPolicy:
    """The communication baseline ``spec`` (``name[:knob]``, see the module docstring) for
    ``env`` (a :class:`netsense.env.pettingzoo_env.NetSenseEnv` or a
    :class:`netsense.engine.core.BatchedCore` in a communication-only mode).

    ``seed`` seeds ``bernoulli`` and ``aloha`` (a sequence: one generator per batch
    member), also as the base of a wrapping rule. A wrapping rule whose field the
    scenario's observation lacks, or ``phased`` without a period on a scenario whose link
    schedule is not periodic, raises a ``ValueError`` naming what is missing.
    """
    core = getattr(env, "core", env)
    comm = getattr(core, "comm", None)
    if comm is None:
        raise ValueError(f"{spec!r} is a communication baseline: it needs a communication-only "
                         "control mode (scenario [control] mode = 'transmit' or 'substates'; "
                         "override with control={'mode': 'transmit'})")
    name, knob = parse_spec(spec)
    if name in WRAPPERS:
        return _wrapped(name, knob, core, seed)
    args = (core.layout, comm.width, core.horizon)
    is_source = core.is_source
    if name == "always":
        return TransmitAll(*args)
    if name == "never":
        return TransmitNone(*args)
    if name == "periodic":
        return Periodic(*args, period=knob)
    if name == "bernoulli":
        return Bernoulli(*args, p=knob, seed=seed)
    if name == "sources":
        return SourcesFirst(*args, is_source=is_source, relay_period=knob)
    if name == "event":
        return EventTriggered(*args, threshold=knob)
    if name == "until":
        return Until(*args, stop=knob[0], threshold=knob[1])
    if name == "settle":
        return Settle(*args, A_bar=core.model.design.decomposition.A_bar, eps=knob[0],
                      window=knob[1])
    if name == "aloha":
        return ThresholdAloha(*args, g=knob[0], q=knob[1], capacity=core.capacity, seed=seed)
    if name == "tdma":
        return Tdma(*args, is_source=is_source, capacity=core.capacity, stretch=knob)
    return AgeScheduler(*args, slots=knob, index=name, columns=~core.comm.empty)


def _wrapped(name: str, knob: tuple, core, seed) -> CommPolicy:
    """The wrapping rule ``name`` with ``knob = (rule knob, base spec)``."""
    value, base_spec = knob
    args = (core.layout, core.comm.width, core.horizon)
    for f in FIELDS.get(name, ()):  # checked before the base is built
        if getattr(core.layout, f) is None:
            raise ValueError(
                f"{name}({base_spec}) reads the observation field {f!r}, which this "
                f"scenario's observation lacks: set [control] {OPTIONS[f]} = true "
                f"(override control={{'{OPTIONS[f]}': True}})")
    if name == "phased" and value is None:
        value = schedule_period(core.model)
        if value is None:
            raise ValueError(f"phased({base_spec}) needs the period P of the link schedule: "
                             f"this scenario's graph process ({type(core.model.graphs).__name__}"
                             ") is not periodic ([graph] kind = 'periodic'); give it as "
                             f"phased:P({base_spec})")
    base = make_comm_policy(base_spec, core, seed=seed)
    if name == "gated":
        return Gated(*args, base=base)
    if name == "acked":
        return Acked(*args, base=base, probe=value)
    if name == "phased":
        return Phased(*args, base=base, period=value)
    if name == "settled":
        return Settled(*args, base=base, A_bar=core.model.design.decomposition.A_bar,
                       block_of=core.block_of, eps=value)
    return Oracle(core, base, channel=name == "oracle_channel")
