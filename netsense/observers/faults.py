"""Fault models for distributed estimation over switching graphs.

Every fault is a frozen, picklable description. Except for the liar, a fault only rewrites
what the observer is given at each step -- the graph, who transmits, the measurements --
through a *step hook* (``hook(k, x, y, adjacency, transmit, arrived) -> (y, adjacency,
transmit, arrived)``, see :func:`netsense.observers.run.run_observer`), so the observers run
their unmodified update rules:

:class:`LinkDrops`
    Each directed link ``l -> i`` of ``G[k]`` loses its message independently of the
    others, following an arrival model of :mod:`netsense.sensing.drops`
    (:class:`~netsense.sensing.drops.BernoulliArrivals` or the bursty
    :class:`~netsense.sensing.drops.GilbertElliottArrivals`, one channel per link). A
    dropped message is a missing edge; when drops break joint strong connectivity the
    indices grow (Lemmas 3 and 5 no longer apply).
:class:`CrashedAgents`
    From step ``at`` the agents never transmit. A crashed *source* ``j`` leaves substate
    ``j`` open loop at every other agent: their indices ``tau_i^{(j)}`` grow by one per
    step (eq. (14)) and their error on substate ``j`` evolves as ``A_jj^k`` (eq. (12)).
    Crashed agents are excluded from the reported errors.
:class:`StuckSensor`
    From step ``at`` the agents' sensors report a frozen value (``mode="stuck"``) or
    ``delay``-step-old values (``mode="stale"``) as if current. The source still claims
    ``tau_j^{(j)} = 0``, so the wrong substate-``j`` estimate spreads with fresh indices;
    substates ``q < j`` are unaffected (they do not depend on ``y_j``, Lemma 1).
:class:`LyingAgent`
    A misbehaving agent that never refreshes its estimates (it runs open loop, eq. (12))
    and reports the freshness index ``claim`` for every substate it does not own. The
    freshness observer then uses the *reported* indices
    (:class:`LyingFreshnessObserver` overrides ``_select`` and calls the same kernels on a
    manipulated copy of ``tau``): with ``claim = 0`` the liar ties with every source and
    *captures* each neighbour that prefers it -- under the kernel's tie-break (smallest
    node index) a liar with a smaller index than the source wins the tie. In the
    consensus baseline (:class:`LyingConsensusObserver`) the same agent just keeps its
    open-loop estimate and keeps sending it.

The batched environment core (:class:`netsense.engine.core.BatchedCore`, scenario section
``[[faults]]``) applies crashes, stuck sensors and liars through the same per-member
methods the hooks use (:meth:`CrashedAgents.silenced`, :meth:`StuckSensor.apply`,
:meth:`LyingAgent.reported`), so each fault's semantics live here only.

:func:`run_with_faults` builds the observer (freshness or consensus, lying variant when a
:class:`LyingAgent` is present), composes the hooks and returns a
:class:`~netsense.observers.run.Trajectory`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from netsense.kernels.checks import MAX_STEPS
from netsense.observers.consensus import ConsensusObserver
from netsense.observers.freshness import FreshnessObserver
from netsense.observers.run import StepHook, Trajectory, run_observer
from netsense.sensing.arrivals import ArrivalModel
from netsense.sensing.drops import arrival_from_dict

if TYPE_CHECKING:  # pragma: no cover
    from netsense.systems.design import ObserverDesign
    from netsense.systems.plants import Plant

__all__ = [
    "CrashedAgents", "Fault", "LinkDrops", "LyingAgent", "LyingConsensusObserver",
    "LyingFreshnessObserver", "StuckSensor", "captured_fraction", "compose_hooks",
    "fault_from_dict", "run_with_faults",
]


def _agents(owner: str, agents: Any) -> tuple[int, ...]:
    if isinstance(agents, (int, np.integer)):
        agents = (int(agents),)
    try:
        items = tuple(agents)
    except TypeError as exc:
        raise ValueError(f"{owner}.agents must be an int or a sequence of ints, "
                         f"got {agents!r}") from exc
    if any(isinstance(a, (bool, np.bool_)) or not isinstance(a, (int, np.integer))
           for a in items):
        raise ValueError(f"{owner}.agents must be an int or a sequence of ints, got {agents!r}")
    out = tuple(int(a) for a in items)
    if not out or any(a < 0 for a in out) or len(set(out)) != len(out):
        raise ValueError(f"{owner}.agents must be distinct non-negative agent ids, got {out}")
    return out


def _check_start(owner: str, name: str, value: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"{owner}.{name} must be an int >= 0, got {value!r}")
    if value > MAX_STEPS:  # steps and indices stay exact and int64 (k + claim)
        raise ValueError(f"{owner}.{name} must be <= 2^53, got {value!r}")


def _identity(k, x, y, adj, tx, arr):
    return y, adj, tx, arr


class Fault:
    """Base class: a frozen description that yields a step hook for a batched run."""

    def check(self, num_agents: int) -> None:
        """Raise ValueError if the fault names agents outside ``0..N-1``."""
        for a in getattr(self, "agents", ()):
            if a >= num_agents:
                raise ValueError(f"{type(self).__name__}.agents names agent {a}, but there "
                                 f"are only {num_agents} agents")

    def hook(self, rng: np.random.Generator, batch_size: int, num_agents: int) -> StepHook:
        """A fresh stateful step hook for ``batch_size`` runs of ``num_agents`` agents."""
        return _identity

    def alive(self, num_agents: int) -> np.ndarray:
        """``(N,)`` mask of the agents whose errors are reported (default all)."""
        return np.ones(num_agents, dtype=bool)

    def to_dict(self) -> dict:
        raise NotImplementedError  # pragma: no cover


@dataclass(frozen=True)
class LinkDrops(Fault):
    """Independent message loss on every directed link (one arrival channel per link).

    Parameters
    ----------
    model : ArrivalModel
        ``True`` = delivered; e.g. ``BernoulliArrivals(0.7)`` (30 % i.i.d. loss) or
        ``GilbertElliottArrivals(p_good_to_bad, p_bad_to_good)`` (bursty loss).
    at : int
        First step at which messages can be lost.
    """

    model: ArrivalModel
    at: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.model, ArrivalModel):
            raise ValueError(f"LinkDrops.model must be an ArrivalModel, "
                             f"got {type(self.model).__name__}")
        _check_start("LinkDrops", "at", self.at)

    def hook(self, rng, batch_size, num_agents):
        sampler = self.model.sampler(rng, (batch_size, num_agents, num_agents))
        at = self.at

        def h(k, x, y, adj, tx, arr):
            ok = sampler.next()  # drawn every step: the stream does not depend on `at`
            return y, (adj & ok) if k >= at else adj, tx, arr
        return h

    def to_dict(self) -> dict:
        return {"kind": "link_drops", "arrivals": self.model.to_dict(), "at": self.at}


@dataclass(frozen=True)
class CrashedAgents(Fault):
    """Agents that stop sending from step ``at`` on (fail-silent crash).

    Parameters
    ----------
    agents : int or tuple of int
        Crashed agents.
    at : int
        Crash step.
    """

    agents: tuple[int, ...]
    at: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "agents", _agents("CrashedAgents", self.agents))
        _check_start("CrashedAgents", "at", self.at)

    def silenced(self, k: int | np.ndarray, num_agents: int) -> np.ndarray:
        """``(B, N)`` mask of the agents that cannot transmit at per-member times ``k``
        (``(B,)``; an int gives ``(1, N)``)."""
        dead = np.zeros(num_agents, dtype=bool)
        dead[list(self.agents)] = True
        k = np.atleast_1d(np.asarray(k))
        return dead[None, :] & (k[:, None] >= self.at)

    def hook(self, rng, batch_size, num_agents):
        self.check(num_agents)

        def h(k, x, y, adj, tx, arr):
            return y, adj, tx & ~self.silenced(k, num_agents), arr
        return h

    def alive(self, num_agents):
        out = np.ones(num_agents, dtype=bool)
        out[list(self.agents)] = False
        return out

    def to_dict(self) -> dict:
        return {"kind": "crash", "agents": list(self.agents), "at": self.at}


@dataclass(frozen=True)
class StuckSensor(Fault):
    """Sensors that report a frozen or an old value as if it were current.

    Parameters
    ----------
    agents : int or tuple of int
        Faulty sensors.
    at : int
        Step at which the fault starts.
    mode : {"stuck", "stale"}
        ``"stuck"``: ``y_i[k] = y_i[at]`` for ``k >= at``; ``"stale"``:
        ``y_i[k] = y_i[max(k - delay, 0)]`` for ``k >= at``.
    delay : int
        Age of the reported value in ``"stale"`` mode (``>= 1``).
    """

    agents: tuple[int, ...]
    at: int = 0
    mode: str = "stuck"
    delay: int = 5

    def __post_init__(self) -> None:
        object.__setattr__(self, "agents", _agents("StuckSensor", self.agents))
        _check_start("StuckSensor", "at", self.at)
        if self.mode not in ("stuck", "stale"):
            raise ValueError(f"StuckSensor.mode must be 'stuck' or 'stale', got {self.mode!r}")
        if isinstance(self.delay, bool) or not isinstance(self.delay, (int, np.integer)) \
                or self.delay < 1:
            raise ValueError(f"StuckSensor.delay must be an int >= 1, got {self.delay!r}")

    def new_state(self, batch_size: int, num_outputs: int) -> np.ndarray:
        """Per-member memory of :meth:`apply`: the frozen value (``"stuck"``) or the last
        ``delay + 1`` true readings (``"stale"``), ``(B, H, len(agents), r)``."""
        H = 1 if self.mode == "stuck" else self.delay + 1
        return np.zeros((batch_size, H, len(self.agents), num_outputs))

    def apply(self, k: int | np.ndarray, y: np.ndarray, state: np.ndarray) -> np.ndarray:
        """The readings the faulty sensors report at per-member times ``k``.

        Parameters
        ----------
        k : int or (B,) int array
            Time index of every member (consecutive calls must follow ``k = 0, 1, ...``
            per member; a member restarting at ``k = 0`` restarts its memory).
        y : (B, N, r) array
            True readings ``y_i[k]``.
        state : array from :meth:`new_state`
            Updated in place.

        Returns
        -------
        (B, N, r) array
            ``y`` with the faulty rows replaced from step ``at`` on (a copy if changed).
        """
        B = y.shape[0]
        k = np.broadcast_to(np.asarray(k, dtype=np.int64), (B,))
        idx, b = list(self.agents), np.arange(B)
        true = y[:, idx]
        if self.mode == "stuck":
            now = k == self.at
            state[now, 0] = true[now]
            held = state[:, 0]
        else:
            H = state.shape[1]
            state[b, k % H] = true
            held = state[b, np.maximum(k - self.delay, 0) % H]
        on = k >= self.at
        if not on.any():
            return y
        y = np.array(y)
        y[:, idx] = np.where(on[:, None, None], held, true)
        return y

    def hook(self, rng, batch_size, num_agents):
        self.check(num_agents)
        memory: list[np.ndarray] = []

        def h(k, x, y, adj, tx, arr):
            if not memory:
                memory.append(self.new_state(y.shape[0], y.shape[-1]))
            return self.apply(k, y, memory[0]), adj, tx, arr
        return h

    def to_dict(self) -> dict:
        return {"kind": "stuck_sensor", "agents": list(self.agents), "at": self.at,
                "mode": self.mode, "delay": self.delay}


@dataclass(frozen=True)
class LyingAgent(Fault):
    """A misbehaving agent that claims fresh information it does not have.

    Parameters
    ----------
    agents : int or tuple of int
        The liars.
    claim : int
        Freshness index reported for every substate a liar does not own (``0`` = "I am
        as fresh as the source").
    at : int
        Step from which they lie (before, they follow the protocol).
    """

    agents: tuple[int, ...]
    claim: int = 0
    at: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "agents", _agents("LyingAgent", self.agents))
        _check_start("LyingAgent", "at", self.at)
        _check_start("LyingAgent", "claim", self.claim)

    def reported(self, tau: np.ndarray, k: int | np.ndarray) -> np.ndarray:
        """The indices ``(B, N, N)`` as the network sees them at per-member times ``k``:
        from step ``at`` on the liars' rows read ``claim`` (their own substate keeps 0)."""
        k = np.broadcast_to(np.asarray(k, dtype=np.int64), tau.shape[:1])
        on = k >= self.at
        if not on.any():
            return tau
        liars = np.array(self.agents)
        rep = tau.copy()
        rep[:, liars, :] = self.claim
        rep[:, liars, liars] = 0
        return np.where(on[:, None, None], rep, tau)

    def alive(self, num_agents):
        """Only honest agents' errors are reported."""
        out = np.ones(num_agents, dtype=bool)
        out[list(self.agents)] = False
        return out

    def to_dict(self) -> dict:
        return {"kind": "liar", "agents": list(self.agents), "claim": self.claim,
                "at": self.at}


# ----------------------------------------------------------------------------- liars
class LyingFreshnessObserver(FreshnessObserver):
    """Freshness observer in which the agents of ``liar`` report false indices.

    From step ``liar.at`` on, a copy of ``tau`` with the liars' rows set to ``liar.claim``
    (their own substate keeps its true 0) is what every agent -- the liars included --
    uses in the freshness rule and in the index update (:func:`netsense.kernels.update.
    freshness_choice`, :func:`~netsense.kernels.update.advance_indices`); nothing else differs.
    A liar with ``claim = 0`` therefore never adopts anything and runs open loop.

    ``origin[b, i, j]`` records where agent ``i``'s current information about substate
    ``j`` comes from: the source ``j``, a liar (everything a lying agent sends counts as
    originating at the liar), or ``-1`` (its own initial guess).
    """

    def __init__(self, design: ObserverDesign, *, liar: LyingAgent, **kwargs) -> None:
        if not isinstance(liar, LyingAgent):
            raise ValueError(f"liar must be a LyingAgent, got {type(liar).__name__}")
        liar.check(design.num_agents)
        self.liar = liar
        self._liars = np.array(liar.agents)
        super().__init__(design, **kwargs)

    def reset(self, x0_hat=None, *, rng=None) -> None:
        super().reset(x0_hat, rng=rng)
        N = self.N
        self.origin = np.full((self.B, N, N), -1, dtype=np.int64)
        self.origin[:, np.arange(N), np.arange(N)] = np.arange(N)

    def reported(self, tau: np.ndarray) -> np.ndarray:
        """The indices as the network sees them at the current step
        (:meth:`LyingAgent.reported`)."""
        return self.liar.reported(tau, self.k)

    def _select(self, Z, tau, nbr, valid, tx):
        lying = self.k >= self.liar.at
        out = super()._select(Z, self.reported(tau), nbr, valid, tx)
        src = self.last_source
        B, N = src.shape[:2]
        origin = self.origin[np.arange(B)[:, None, None], src, np.arange(N)[None, None, :]]
        origin[:, np.arange(N), np.arange(N)] = np.arange(N)
        if lying:
            origin[:, self._liars, :] = self._liars[:, None]
            origin[:, self._liars, self._liars] = self._liars
        self.origin = origin
        return out


class LyingConsensusObserver(ConsensusObserver):
    """Consensus baseline with the same misbehaving agents: from ``liar.at`` on they do not
    mix in their neighbours' estimates (open loop, eq. (12)) but keep sending theirs."""

    def __init__(self, design: ObserverDesign, *, liar: LyingAgent, **kwargs) -> None:
        if not isinstance(liar, LyingAgent):
            raise ValueError(f"liar must be a LyingAgent, got {type(liar).__name__}")
        liar.check(design.num_agents)
        self.liar = liar
        self._liars = np.array(liar.agents)
        super().__init__(design, **kwargs)

    def _select(self, Z, tau, nbr, valid, tx):
        Z_sel, tau_next = super()._select(Z, tau, nbr, valid, tx)
        if self.k >= self.liar.at:
            Z_sel = Z_sel.copy()
            Z_sel[:, self._liars] = Z[:, self._liars]
        return Z_sel, tau_next


def captured_fraction(observer: LyingFreshnessObserver) -> np.ndarray:
    """``(B,)`` fraction of (honest agent, substate owned by an honest source) pairs whose
    current information originates at a liar."""
    liars = observer._liars
    N = observer.N
    honest = np.ones(N, dtype=bool)
    honest[liars] = False
    pair = honest[:, None] & honest[None, :] & ~np.eye(N, dtype=bool)
    cap = np.isin(observer.origin, liars) & pair
    return cap.sum((-1, -2)) / max(int(pair.sum()), 1)


# ----------------------------------------------------------------------------- running
def compose_hooks(hooks: Sequence[StepHook]) -> StepHook:
    """Apply ``hooks`` in order at every step."""
    hooks = tuple(hooks)

    def h(k, x, y, adj, tx, arr):
        for f in hooks:
            y, adj, tx, arr = f(k, x, y, adj, tx, arr)
        return y, adj, tx, arr
    return h


def run_with_faults(plant: Plant, design: ObserverDesign, graphs: np.ndarray,
                    x0: np.ndarray, faults: Sequence[Fault] = (), *,
                    observer: str = "freshness", rng: np.random.Generator | int | None = 0,
                    x0_hat: np.ndarray | None = None
                    ) -> tuple[Trajectory, FreshnessObserver | ConsensusObserver]:
    """Run a batched observer under ``faults``; returns the trajectory and the observer.

    Parameters
    ----------
    plant : Plant
    design : ObserverDesign
    graphs : (B, K, N, N) bool
    x0 : (B, n)
    faults : sequence of Fault
        At most one :class:`LyingAgent`.
    observer : {"freshness", "consensus"}
        Consensus uses uniform weights (eq. (6)).
    rng : Generator or int
        Randomness of the faults (link drops) and of the plant's noise, if any.
    """
    if observer not in ("freshness", "consensus"):
        raise ValueError(f"observer must be 'freshness' or 'consensus', got {observer!r}")
    faults = tuple(faults)
    for f in faults:
        if not isinstance(f, Fault):
            raise ValueError(f"faults must hold Fault instances, got {type(f).__name__}")
        f.check(design.num_agents)
    liars = [f for f in faults if isinstance(f, LyingAgent)]
    if len(liars) > 1:
        raise ValueError("faults may hold at most one LyingAgent (list all liars in it)")
    graphs = np.asarray(graphs, dtype=bool)
    B, N = graphs.shape[0], design.num_agents
    rng = np.random.default_rng(rng)
    if observer == "freshness":
        obs = (LyingFreshnessObserver(design, liar=liars[0], batch_size=B) if liars
               else FreshnessObserver(design, batch_size=B))
    else:
        obs = (LyingConsensusObserver(design, liar=liars[0], batch_size=B) if liars
               else ConsensusObserver(design, batch_size=B))
    fault_rng, noise_rng = rng.spawn(2)
    hook = compose_hooks([f.hook(fault_rng, B, N) for f in faults])
    alive = np.ones(N, dtype=bool)
    for f in faults:
        alive &= f.alive(N)
    return run_observer(obs, plant, graphs, x0, x0_hat=x0_hat, hook=hook, alive=alive,
                        noise_rng=noise_rng), obs


def fault_from_dict(spec: dict) -> Fault:
    """Build a fault from its ``to_dict`` form (scenario files).

    Raises
    ------
    ValueError
        On an unknown ``kind`` or field, or a bad value (named in the message).
    """
    if not isinstance(spec, dict):
        raise ValueError(f"fault spec must be a dict, got {type(spec).__name__}")
    spec = dict(spec)
    kind = spec.pop("kind", None)
    allowed = {"link_drops": {"arrivals", "at"}, "crash": {"agents", "at"},
               "stuck_sensor": {"agents", "at", "mode", "delay"},
               "liar": {"agents", "claim", "at"}}
    required = {"link_drops": {"arrivals"}, "crash": {"agents"}, "stuck_sensor": {"agents"},
                "liar": {"agents"}}
    if kind not in allowed:
        raise ValueError(f"fault spec field 'kind' must be one of {sorted(allowed)}, "
                         f"got {kind!r}")
    missing, extra = required[kind] - set(spec), set(spec) - allowed[kind]
    if missing or extra:
        raise ValueError(f"fault kind {kind!r}: missing fields {sorted(missing)}, "
                         f"unknown fields {sorted(extra)}")
    if kind == "link_drops":
        return LinkDrops(arrival_from_dict(spec.pop("arrivals")), **spec)
    cls = {"crash": CrashedAgents, "stuck_sensor": StuckSensor, "liar": LyingAgent}[kind]
    return cls(**spec)
