"""Settings of the full-information reference schedulers (:mod:`netsense.benchmark.lookahead`)
and their policy specs.

A reference is named ``reference:causal`` or ``reference:clairvoyant``, optionally followed by its
continuation policy (``reference:causal:sources:0``); everything else about its search is a
:class:`LookaheadConfig`, whose defaults are the settings measured in ``docs/communication.md``
(section 8): lookahead ``h = 8``, ``F = 8`` resampled futures, a one-standard-error margin
over the base action, two rounds.
"""

from __future__ import annotations

from dataclasses import dataclass

from netsense.kernels import checks

__all__ = ["CANDIDATES", "DEFAULT_CONTINUATION", "MAX_EXHAUSTIVE", "REFERENCE_KINDS",
           "LookaheadConfig", "parse_reference"]

REFERENCE_KINDS = ("causal", "clairvoyant")
CANDIDATES = ("flips", "exhaustive")
#: Continuation used when none is named (overridden per task by the frontier: the best
#: scripted point of the same run).
DEFAULT_CONTINUATION = "event:2"
#: Most patterns the exhaustive search enumerates per member and decision.
MAX_EXHAUSTIVE = 4096


@dataclass(frozen=True)
class LookaheadConfig:
    """Search settings of a full-information reference scheduler (module docstring).

    Attributes
    ----------
    kind : {"causal", "clairvoyant"}
        Resampled futures, or the realised one.
    horizon : int
        ``h``: steps scored per candidate (the decision step and ``h - 1`` steps of
        continuation).
    futures : int
        ``F``: resampled futures per candidate (``causal``; ``clairvoyant`` uses 1).
    candidates : {"flips", "exhaustive"}
        Candidate generation.
    depth : int
        ``exhaustive``: steps whose patterns are all enumerated (``2^(N W depth)``
        sequences); must be 1 with ``flips``.
    continuation : tuple of str
        Communication policy specs; the first is the base (its action, all on / all off
        and single flips are scored with it as the continuation).
    seed : int
        Seed of the resampled futures.
    known_ahead : int
        Graphs after ``G[k]`` known at ``k`` (kept by the resampled futures); a scenario
        whose model has an attribute ``known_ahead`` (a schedule announced ahead) raises
        it to that.
    terminal : int
        Terminal estimate: the last lookahead step's reward counted for this many more
        steps (at most to the end of the episode); 0: none.
    confidence : float
        ``z >= 0``: leave the base policy's action (candidate 0) only for a candidate
        whose paired gain over it, less ``z`` standard errors over the futures, is
        positive (0: the plain argmax; the clairvoyant reference has one future and ignores
        it). Guards against picking a candidate for its lucky futures.
    rounds : {1, 2}
        ``2`` (``flips``): a second fork scores the base action with every single-bit
        flip that passed the margin flipped at once against the first round's choice
        (a step of greedy coordinate improvement: several agents change at once).
    """

    kind: str = "causal"
    horizon: int = 8
    futures: int = 8
    candidates: str = "flips"
    depth: int = 1
    continuation: tuple[str, ...] = (DEFAULT_CONTINUATION,)
    seed: int = 0
    known_ahead: int = 0
    terminal: int = 0
    confidence: float = 1.0
    rounds: int = 2

    def __post_init__(self) -> None:
        checks.choice("kind", self.kind, REFERENCE_KINDS)
        checks.choice("candidates", self.candidates, CANDIDATES)
        checks.integer("horizon", self.horizon, 1)
        checks.integer("futures", self.futures, 1)
        checks.integer("depth", self.depth, 1)
        checks.integer("known_ahead", self.known_ahead, 0)
        checks.integer("terminal", self.terminal, 0)
        checks.number("confidence", self.confidence, 0)
        checks.integer("rounds", self.rounds, 1)
        if self.rounds > 2:
            raise ValueError(f"rounds must be 1 or 2, got {self.rounds}")
        checks.seed_value("seed", self.seed)
        if self.depth > self.horizon:
            raise ValueError(f"depth ({self.depth}) must be <= horizon ({self.horizon})")
        if self.depth > 1 and self.candidates != "exhaustive":
            raise ValueError("depth > 1 enumerates sequences: it needs candidates="
                             "'exhaustive'")
        cont = self.continuation
        if isinstance(cont, str) or not cont or not all(isinstance(c, str) for c in cont):
            raise ValueError(f"continuation must be a non-empty tuple of policy specs, got "
                             f"{cont!r}")
        from netsense.env.comm_policies import WRAPPERS, parse_spec

        for spec in cont:
            name, knob = parse_spec(spec)  # raises for unknown names and bad knobs
            if name in WRAPPERS:
                name, _ = parse_spec(knob[1])
            if name in ("bernoulli", "aloha"):
                raise ValueError("a continuation must be a deterministic function of the "
                                 f"observation; {spec!r} draws random bits")
        object.__setattr__(self, "continuation", tuple(cont))

    @property
    def num_futures(self) -> int:
        """Futures per candidate: ``futures`` (causal) or 1 (clairvoyant)."""
        return self.futures if self.kind == "causal" else 1


def parse_reference(spec: str, config: LookaheadConfig | None = None) -> LookaheadConfig:
    """The configuration of a policy spec ``reference:KIND`` or
    ``reference:KIND:CONTINUATION`` (e.g. ``reference:causal:sources:0``), on top of
    ``config`` (default settings otherwise). The former spelling ``bound:KIND`` raises a
    ``ValueError`` naming the new one (they are achieved references, not bounds)."""
    name, _, rest = spec.partition(":")
    kind, _, cont = rest.partition(":")
    if name == "bound":
        raise ValueError(f"{spec!r}: the lookahead schedulers are full-information "
                         f"references, not bounds; write 'reference:{rest}'")
    if name != "reference" or kind not in REFERENCE_KINDS:
        raise ValueError("a full-information reference spec is 'reference:causal' or "
                         "'reference:clairvoyant', optionally followed by ':CONTINUATION' "
                         f"(e.g. reference:causal:event:2); got {spec!r}")
    base = config or LookaheadConfig()
    kwargs = {f: getattr(base, f) for f in ("horizon", "futures", "candidates", "depth",
                                            "continuation", "seed", "known_ahead",
                                            "terminal", "confidence", "rounds")}
    kwargs["kind"] = kind
    if cont:
        kwargs["continuation"] = (cont,)
    return LookaheadConfig(**kwargs)


