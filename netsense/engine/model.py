"""What a scenario compiles to: the model of the batched core and its observation layout.

:func:`netsense.env.registry.build_model` turns a scenario (a TOML file in
``netsense/env/scenarios/``)
into a :class:`CoreModel`: plant, observer design, graph process, arrival models, reward
weights (:class:`RewardConfig`), faults and the substates the indices, actions and
observations cover. :class:`netsense.engine.core.BatchedCore` simulates it, and
:class:`ObsLayout` is the layout of the flat per-agent observation vector the core writes
(:mod:`netsense.engine.observation`), fixed by the model's sizes and sources. These classes hold
and check data; none of them runs a step. :mod:`netsense.engine.core` re-exports every name
defined here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from netsense.engine.control import COMM_OBS_FIELDS, COMM_OPTION_FIELDS, Channel, Control
from netsense.graphs.processes import GraphProcess
from netsense.kernels.checks import MAX_STEPS
from netsense.observers.source import SourceEstimator
from netsense.sensing.arrivals import AlwaysArrive, ArrivalModel
from netsense.systems.design import ObserverDesign
from netsense.systems.plants import Plant

__all__ = ["SUBSTATES", "CoreModel", "ObsLayout", "RewardConfig", "symlog"]

SUBSTATES = ("all", "sources")


@dataclass(frozen=True)
class RewardConfig:
    """Reward weights (scenario section ``[reward]``).

    Agent ``i``'s reward after step ``k -> k + 1`` is

    .. math:: r_i = -w_e \\big((1 - w_t) e_i + w_t \\bar e\\big) - c\\, t_i - c_s\\, s_i,
              \\qquad e_i = \\min\\Big(\\frac{\\|\\hat x_i[k+1] - x[k+1]\\|}
              {\\max(\\|x[k+1]\\|, f)}, e_{\\max}\\Big),

    with ``\\bar e`` the mean of ``e_i`` over the agents whose errors count (crashed
    agents and liars excluded; those get only ``-c t_i``) and ``t_i`` the transmit bit
    chosen at this step, ``s_i`` the number of substates with an estimate in its message
    (communication-only control modes only; see :mod:`netsense.engine.control`). A
    non-finite error is clipped to ``e_max`` (:mod:`netsense.engine.rewards`).

    Attributes
    ----------
    error_weight : float
        ``w_e``, weight of the normalised estimation error.
    team_weight : float
        ``w_t`` in ``[0, 1]``: 0 = individual errors, 1 = fully shared team error.
    message_cost : float
        ``c``, cost of one transmission.
    error_floor : float
        ``f > 0``, the smallest ``||x||`` used for normalising (keeps ``e`` finite at 0).
    error_clip : float
        ``e_max``, the normalised error is clipped there (bounded rewards).
    substate_cost : float
        ``c_s >= 0``, cost of each substate with an estimate (index not omega, block not
        empty) in a message, communication-only modes (default 0).
    """

    error_weight: float = 1.0
    team_weight: float = 0.0
    message_cost: float = 0.0
    error_floor: float = 1e-3
    error_clip: float = 10.0
    substate_cost: float = 0.0

    def __post_init__(self) -> None:
        for name in ("error_weight", "team_weight", "message_cost", "error_floor",
                     "error_clip"):
            v = getattr(self, name)
            if (isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer,
                                                                      np.floating))
                    or not np.isfinite(v)):
                raise ValueError(f"reward.{name} must be a finite number, got {v!r}")
        if not 0.0 <= self.team_weight <= 1.0:
            raise ValueError(f"reward.team_weight must be in [0, 1], got {self.team_weight}")
        if self.error_floor <= 0:
            raise ValueError(f"reward.error_floor must be > 0, got {self.error_floor}")
        if self.error_clip <= 0:
            raise ValueError(f"reward.error_clip must be > 0, got {self.error_clip}")
        if self.message_cost < 0 or self.error_weight < 0:
            raise ValueError("reward.message_cost and reward.error_weight must be >= 0")
        c_s = self.substate_cost
        if not isinstance(c_s, (int, float, np.integer, np.floating)) or not c_s >= 0 \
                or not np.isfinite(c_s):
            raise ValueError(f"reward.substate_cost must be a finite number >= 0, got {c_s!r}")
        if not np.isfinite(float(self.error_weight) * float(self.error_clip)
                           + float(self.message_cost)
                           + float(self.substate_cost)):
            raise ValueError("reward.error_weight * reward.error_clip + reward.message_cost + "
                             "reward.substate_cost "
                             "must be finite (it bounds |reward|)")


@dataclass(frozen=True, eq=False)
class CoreModel:
    """Everything that defines one scenario's dynamics (built by :mod:`netsense.env.registry`).

    Attributes
    ----------
    plant : Plant
        eqs. (1)-(2), with its noise models.
    design : ObserverDesign
        Lemma 1 decomposition and source gains.
    graphs : GraphProcess
        Switching communication graph ``G[k]``.
    horizon : int
        Episode length (truncation).
    measurement_arrivals, message_arrivals : ArrivalModel
        Whether ``y_i[k]`` arrives (shape ``(N,)`` per step) and whether the message on
        link ``l -> i`` arrives (shape ``(N, N)`` per step, entry ``[i, l]``).
    reward : RewardConfig
    x0_std : float
        ``x[0] ~ N(0, x0_std^2 I)``; every estimate starts at 0.
    initial_transmit : bool
        Transmit flags of step 0.
    divergence_limit : float or None
        Terminate a member when some agent's normalised error (before clipping) exceeds it.
    source_estimator : callable returning a SourceEstimator, optional
        Default :class:`~netsense.observers.source.LuenbergerSource` (eq. (7)). Called
        once per core; the object keeps per-member state (see
        :mod:`netsense.observers.source`).
    faults : tuple of netsense.observers.faults.Fault
        Crashed agents, stuck/stale sensors and at most one :class:`~netsense.observers.faults.
        LyingAgent` (message loss is ``message_arrivals``); see
        :class:`~netsense.engine.core.BatchedCore`.
    substates : {"all", "sources"}
        Which substates the freshness indices, actions and observations cover: ``"all"``
        (one per agent, as in the paper: ``tau`` is ``N x N``) or ``"sources"`` (only the
        agents whose block of Lemma 1 is non-empty; ``tau`` is ``N x M``). The indices of
        an empty substate carry nothing to estimate, so the estimates, errors and rewards
        are the same in both (tested); with ``N`` agents and ``n < N`` states at most
        ``n`` agents are sources, and the O(N^2) per-member bookkeeping becomes O(N M).
    control : Control
        What the actions decide: full control (default) or communication only, with the
        fusion rule that adopts (:mod:`netsense.engine.control`).
    channel : Channel or None
        A shared channel of capacity ``K`` with collisions (default none).
    """

    plant: Plant
    design: ObserverDesign
    graphs: GraphProcess
    horizon: int
    measurement_arrivals: ArrivalModel = field(default_factory=AlwaysArrive)
    message_arrivals: ArrivalModel = field(default_factory=AlwaysArrive)
    reward: RewardConfig = field(default_factory=RewardConfig)
    x0_std: float = 1.0
    initial_transmit: bool = True
    divergence_limit: float | None = None
    source_estimator: Callable[[], SourceEstimator] | None = None
    faults: tuple = ()
    substates: str = "all"
    control: Control = field(default_factory=Control)
    channel: Channel | None = None

    def __post_init__(self) -> None:
        from netsense.observers.faults import CrashedAgents, LyingAgent, StuckSensor

        self._check_types()
        object.__setattr__(self, "faults", tuple(self.faults))
        for f in self.faults:
            if not isinstance(f, (CrashedAgents, StuckSensor, LyingAgent)):
                raise ValueError(f"faults must be CrashedAgents, StuckSensor or LyingAgent "
                                 f"(message loss is message_arrivals), got "
                                 f"{type(f).__name__}")
            f.check(self.plant.num_agents)
        if self.substates not in SUBSTATES:
            raise ValueError(f"substates must be one of {SUBSTATES}, got {self.substates!r}")
        if self.substates == "sources" and any(isinstance(f, LyingAgent)
                                                for f in self.faults):
            raise ValueError("a LyingAgent fault needs substates = 'all' (its claims are "
                             "per agent and substate)")
        if sum(isinstance(f, LyingAgent) for f in self.faults) > 1:
            raise ValueError("faults may hold at most one LyingAgent (list all liars in it)")
        if (not isinstance(self.horizon, (int, np.integer)) or isinstance(self.horizon, bool)
                or not 1 <= self.horizon <= MAX_STEPS):
            raise ValueError(f"horizon must be an integer in [1, 2^53], got {self.horizon!r}")
        for f in self.faults:
            if isinstance(f, StuckSensor) and f.mode == "stale" and f.delay > self.horizon:
                raise ValueError(f"faults: StuckSensor.delay = {f.delay} exceeds the horizon "
                                 f"{self.horizon} (the sensor would report y[0] all episode; "
                                 "use mode = 'stuck', at = 0 for that)")
        if self.graphs.num_nodes != self.plant.num_agents:
            raise ValueError(f"graph process has {self.graphs.num_nodes} nodes but the plant "
                             f"has {self.plant.num_agents} agents")
        if self.design.num_agents != self.plant.num_agents:
            raise ValueError("design and plant disagree on the number of agents")
        if (isinstance(self.x0_std, (bool, np.bool_))
                or not isinstance(self.x0_std, (int, float, np.integer, np.floating))
                or not np.isfinite(self.x0_std) or self.x0_std < 0):
            raise ValueError(f"x0_std must be a finite number >= 0, got {self.x0_std!r}")
        if not isinstance(self.initial_transmit, (bool, np.bool_)):
            raise ValueError(f"initial_transmit must be True or False, got "
                             f"{self.initial_transmit!r}")
        lim = self.divergence_limit
        if lim is not None and (isinstance(lim, (bool, np.bool_))
                                or not isinstance(lim, (int, float, np.integer, np.floating))
                                or np.isnan(lim) or lim <= 0):
            raise ValueError(f"divergence_limit must be None or a number > 0, got {lim!r}")

        self._check_control()

    @property
    def known_ahead(self) -> int:
        """How many graphs beyond ``G[k]`` the observation at ``k`` reveals: 1 with
        ``control.announce`` (``G[k+1]``, field ``next_out``), else 0.

        A lookahead that resamples the unobserved future from step ``k`` (a causal bound)
        must keep these ``known_ahead`` graphs as they are (``BatchedCore.nbr_next`` and
        the graph-process state after it, :meth:`netsense.engine.core.BatchedCore.
        peek_next_graphs`) and redraw only ``G[k + 1 + known_ahead]`` onwards: an agent
        acting on ``next_out`` knows ``G[k+1]``, so a bound that redraws it would score
        futures the agent knows to be impossible. Noise and arrivals are never announced.
        """
        return int(bool(self.control.announce))

    def _check_control(self) -> None:
        from netsense.graphs.processes import PeriodicGraphs

        if not isinstance(self.control, Control):
            raise ValueError(f"control must be a Control, got {type(self.control).__name__}")
        if self.channel is not None and not isinstance(self.channel, Channel):
            raise ValueError(f"channel must be None or a Channel, got "
                             f"{type(self.channel).__name__}")
        if self.reward.substate_cost and not self.control.comm_only:
            raise ValueError("reward.substate_cost needs a communication-only control mode "
                             "(control.mode = 'transmit' or 'substates')")
        bound = self.reward_bound
        if not np.isfinite(bound):
            rw = self.reward
            raise ValueError(f"reward: |r_i| <= error_weight * error_clip + message_cost + "
                             f"substate_cost * M must be finite, got {rw.error_weight:g} * "
                             f"{rw.error_clip:g} + {rw.message_cost:g} + "
                             f"{rw.substate_cost:g} * {self.num_substates} (the payload "
                             "cost is paid per substate)")
        if (self.control.comm_only and self.control.fusion == "tree"
                and not isinstance(self.graphs, PeriodicGraphs)):
            raise ValueError("control.fusion = 'tree' needs a periodic graph schedule, got "
                             f"{type(self.graphs).__name__}")

    @property
    def num_substates(self) -> int:
        """``M``: substates the indices and actions cover (every agent's with ``substates =
        "all"``, those of agents with a non-empty block of Lemma 1 with ``"sources"``)."""
        N = self.plant.num_agents
        if self.substates == "all":
            return N
        sizes = np.bincount(self.design.decomposition.block_of, minlength=N)
        return int(np.count_nonzero(sizes))

    @property
    def reward_bound(self) -> float:
        """Largest ``|r_i|`` of a step: ``w_e e_max + c + c_s M`` (:class:`RewardConfig`;
        the payload cost ``c_s`` is paid for each of up to ``M`` substates in a message,
        communication-only modes)."""
        rw = self.reward
        cs = float(rw.substate_cost) * self.num_substates if self.control.comm_only else 0.0
        with np.errstate(over="ignore"):
            return float(np.float64(rw.error_weight) * rw.error_clip + rw.message_cost + cs)

    def _check_types(self) -> None:
        """Every field of the right type, and the design made for this plant."""
        for name, cls in (("plant", Plant), ("design", ObserverDesign),
                          ("graphs", GraphProcess), ("measurement_arrivals", ArrivalModel),
                          ("message_arrivals", ArrivalModel), ("reward", RewardConfig)):
            v = getattr(self, name)
            if not isinstance(v, cls):
                raise ValueError(f"{name} must be a {cls.__name__}, got {type(v).__name__}")
        if self.source_estimator is not None and not callable(self.source_estimator):
            raise ValueError("source_estimator must be None or a callable returning a "
                             "SourceEstimator")
        if not isinstance(self.faults, (tuple, list)):
            raise ValueError(f"faults must be a tuple of faults, got {type(self.faults).__name__}")
        p, dec = self.plant, self.design.decomposition
        if dec.n != p.n or dec.num_agents != p.num_agents or any(
                Cb.shape != Ci.shape for Cb, Ci in zip(dec.C_bar, p.C, strict=True)):
            raise ValueError(f"design was made for another plant: its decomposition has n = "
                             f"{dec.n}, N = {dec.num_agents} and outputs "
                             f"{[c.shape[0] for c in dec.C_bar]}; the plant has n = {p.n}, "
                             f"N = {p.num_agents} and outputs {list(p.output_sizes)}")
        T = dec.T  # x = T z: the design's model of the plant is T A_bar T^T, C_bar_i T^T
        scale = max(1.0, float(np.abs(p.A).max()), max(float(np.abs(c).max(initial=0.0))
                                                       for c in p.C))
        if not (np.allclose(T @ dec.A_bar @ T.T, p.A, rtol=0, atol=1e-6 * scale)
                and all(np.allclose(Cb @ T.T, Ci, rtol=0, atol=1e-6 * scale)
                        for Cb, Ci in zip(dec.C_bar, p.C, strict=True))):
            raise ValueError("design was made for another plant: T A_bar T^T or C_bar_i T^T "
                             "differ from the plant's A or C_i (design the observer for "
                             "this plant: netsense.design_observer(plant))")


#: Fields of the per-agent observation, in their order in the flat vector.
OBS_FIELDS = ("time", "y", "y_arrived", "own_omega", "own_age", "z_dir", "z_lognorm",
              "slot_arrived", "slot_id", "slot_omega", "slot_age")


@dataclass(frozen=True)
class ObsLayout:
    """Offsets of the flat per-agent observation vector (see :mod:`netsense.env.pettingzoo_env`).

    Every field is a ``slice`` into the last axis of ``obs``; block fields with two
    dimensions are stored row-major (``slot_omega``: ``D x M``, slot first). ``M`` is the
    number of substates the indices and actions cover: ``N`` (one per agent, default) or
    the number of sources (agents with a non-empty block, scenario key
    ``substates = "sources"``); ``sources[m]`` is the agent that owns substate ``m``.
    """

    N: int
    n: int
    r: int
    D: int
    M: int
    sources: tuple[int, ...]
    time: slice
    y: slice
    y_arrived: slice
    own_omega: slice
    own_age: slice
    z_dir: slice
    z_lognorm: slice
    slot_arrived: slice
    slot_id: slice
    slot_omega: slice
    slot_age: slice
    size: int
    news: slice | None = None
    silence: slice | None = None
    channel_load: slice | None = None
    collided: slice | None = None
    agent_id: slice | None = None
    next_out: slice | None = None
    acks: slice | None = None

    @classmethod
    def build(cls, N: int, n: int, r: int, D: int,
              sources: Sequence[int] | None = None, comm: bool = False,
              announce: bool = False, feedback: bool = False) -> ObsLayout:
        """The layout; ``comm=True`` appends the communication-only modes' fields
        (:data:`netsense.engine.control.COMM_OBS_FIELDS`: ``news`` (M), ``silence``,
        ``channel_load``, ``collided``, ``agent_id``), then ``next_out`` (N) with
        ``announce`` and ``acks`` (N) with ``feedback``
        (:data:`netsense.engine.control.COMM_OPTION_FIELDS`)."""
        if (announce or feedback) and not comm:
            raise ValueError("announce and feedback are fields of the communication-only "
                             "observation (comm=True)")
        src = tuple(range(N)) if sources is None else tuple(int(v) for v in sources)
        M = len(src)
        sizes = (1, r, 1, M, M, n, 1, D, D, D * M, D * M)
        out, o = {}, 0
        for name, s in zip(OBS_FIELDS, sizes, strict=True):
            out[name] = slice(o, o + s)
            o += s
        if comm:
            for name, s in zip(COMM_OBS_FIELDS, (M, 1, 1, 1, 1), strict=True):
                out[name] = slice(o, o + s)
                o += s
            for name, on in zip(COMM_OPTION_FIELDS, (announce, feedback), strict=True):
                if on:
                    out[name] = slice(o, o + N)
                    o += N
        return cls(N=N, n=n, r=r, D=D, M=M, sources=src, size=o, **out)

    @property
    def own(self) -> np.ndarray:
        """``(N,)``: the substate (column) agent ``i`` owns, ``-1`` if none."""
        out = np.full(self.N, -1, dtype=np.int64)
        out[list(self.sources)] = np.arange(self.M)
        return out

    def table(self) -> list[tuple[str, int, int]]:
        """``(field, start, stop)`` rows in :data:`OBS_FIELDS` order (the documentation
        table, and the offsets the compiled observation pass writes at)."""
        return [(nm, getattr(self, nm).start, getattr(self, nm).stop) for nm in OBS_FIELDS]

    def comm_table(self) -> list[tuple[str, int, int]]:
        """``(field, start, stop)`` of the communication-only fields (empty in full mode)."""
        return [(nm, getattr(self, nm).start, getattr(self, nm).stop)
                for nm in COMM_OBS_FIELDS + COMM_OPTION_FIELDS if getattr(self, nm) is not None]


def symlog(v: np.ndarray) -> np.ndarray:
    """``sign(v) log(1 + |v|)``: a monotone, scale-compressing encoding of raw values."""
    return np.sign(v) * np.log1p(np.abs(v))
