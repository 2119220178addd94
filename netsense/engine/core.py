"""Batched simulation core of the netsense environment: ``B`` scenarios as one array program.

:class:`BatchedCore` advances ``B`` independent copies of one scenario (own seeds, own
graph, noise and drop realisations) with arrays shaped ``(B, N, ...)``. The PettingZoo
environment (:class:`netsense.env.pettingzoo_env.NetSenseEnv`) is the ``B = 1`` case of this
class, and
every update rule comes from the row functions of :mod:`netsense.kernels.rules` (freshness
indices, gather, uniform mix, propagation, outputs, messages; run through
:func:`netsense.kernels.update.apply_actions` and :mod:`netsense.kernels.drivers`), the rewards of
:mod:`netsense.engine.rewards` and the source estimator interface of
:mod:`netsense.observers.source` (eq. (7)): there is no second copy of any rule here.
What the core simulates is a :class:`~netsense.engine.model.CoreModel` (the scenario compiled
by :mod:`netsense.env.registry`); the model, its reward weights and the observation layout
live in :mod:`netsense.engine.model` and are re-exported here.

Array API
---------
>>> core = BatchedCore(model, batch_size=B)
>>> obs, mask = core.reset(seed)            # obs (B, N, obs_dim) float32, mask (B, N, M) int8
>>> out = core.step(actions)                # actions (B, N, M + 1) int (M = N by default)
>>> out.obs, out.action_mask, out.reward, out.terminated, out.truncated

``reset(seed)`` seeds member ``b`` with ``seed + b`` (or with ``seed[b]`` for a sequence),
so member ``b`` of a batch equals a single environment reset with that seed, step by
step. ``reset(seed, members=mask)`` re-initialises only the selected members (the hook
for auto-reset in vector environments). The core never resets itself: members that are
truncated or terminated keep stepping until the caller resets them.

Timing protocol (one step, ``k -> k + 1``)
------------------------------------------
At time ``k`` every agent observes its measurement ``y_i[k]`` (if it arrived), its own
freshness indices and estimate, and the *messages of step k*: the in-neighbours of
``G[k]`` that transmitted at ``k`` (and whose link did not drop the message), with their
indices ``tau_l[k]``. Its action then chooses, per substate, what to propagate
(keep / adopt slot ``d`` / uniform average) **and whether to transmit at step k + 1**.
So the transmit bit of the action at ``k`` is the message neighbours receive at
``k + 1``; the transmit flags of step 0 come from the scenario (``initial_transmit``).
This lets a policy act on the masks of exactly the messages it can use, and the freshness
policy with transmit always on reproduces :class:`netsense.FreshnessObserver`.

Action encoding (per agent, ``M + 1`` integers)
-----------------------------------------------
``M`` substates: ``N`` (one per agent, the paper's setting) or, with
``substates = "sources"``, the agents whose block is non-empty (``layout.sources``).
``a[j]`` for substate ``j < M``: ``0`` keep own estimate (open loop, eqs. (11)/(12),
(14)); ``1..D`` adopt from in-neighbour slot ``d = a[j] - 1`` (eqs. (9)/(10)); ``D + 1``
uniform average over self and every in-neighbour whose message arrived (eq. (6), index:
stalest contributor + 1). ``a[M]``: transmit at the next step (0/1). The source's entry
for its own substate must be 0 (update (7) is not an action).

In the communication-only control modes (``model.control``, :mod:`netsense.engine.control`)
the actions are ``(B, N, 1)`` transmit bits or ``(B, N, M)`` per-substate bits; the fusion
rule's choice (computed by :class:`~netsense.engine.control.CommControl` when a step's
messages are loaded) fills ``a[:M]`` and the step above runs unchanged.

Faults (``CoreModel.faults``, scenario ``[[faults]]``)
-----------------------------------------------------
A crashed agent's transmit bits are cleared from its crash step on; a stuck or stale
sensor's ``y_i[k]`` is replaced before the observation and the source correction (eq. (7))
use it; a liar's claimed indices replace its rows of ``tau`` in every agent's observation
and in the index update (eqs. (9), (11), (14); ``advance_row`` in the fused update).
The rules are those of :mod:`netsense.observers.faults` (``silenced``, ``apply``, ``reported``),
evaluated at each member's own time; crashed agents and liars are excluded from the team
error, from error rewards and from the divergence check (:attr:`BatchedCore.alive`).

Bad actions: entries outside ``0..D+1`` (or a transmit bit outside ``{0, 1}``) always
raise ``ValueError``; masked choices (adopting from an empty slot or from a neighbour
whose message did not arrive, or anything but 0 on the own substate) raise too when
``invalid_actions="raise"`` (default) and are replaced by 0 (keep) with
``invalid_actions="keep"``. Validation happens before any state changes.

Numerical health: a step checks that every agent's error ``||z_hat_i - z||`` is finite
(it is iff the plant state and the estimates are, up to an overflow of the distance; one
reduction over ``(B, N)``). Rewards are finite by construction (errors are clipped, NaN
included, and :class:`RewardConfig` bounds them). When an error is not finite, with
``nonfinite="terminate"`` (default) the member is
terminated at that step (``terminated[b] = True``), ``BatchedCore.nonfinite[b]``
records ``{"step", "what", "agent"}`` (``what``: ``"state"``, ``"estimate"`` or ``"error"``
(finite state and estimate whose distance overflows); ``agent`` is ``None`` for the plant
state) and a :class:`~netsense.kernels.
checks.NumericalWarning` names member, agent and step (once per member and episode); with
``nonfinite="raise"`` the step raises :class:`~netsense.kernels.checks.NumericalError`
instead, before the plant and estimates are committed (a stateful source estimator has
already taken its step: reset before stepping on).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import NamedTuple

import numpy as np

from netsense.engine import observation, rewards
from netsense.engine.control import CommControl, apply_collisions, tree_choice_table
from netsense.engine.model import SUBSTATES, CoreModel, ObsLayout, RewardConfig, symlog
from netsense.engine.observation import FillBuffers
from netsense.graphs.processes import slot_adjacency
from netsense.kernels import checks, drivers
from netsense.kernels import update as kernels
from netsense.kernels.checks import NumericalError, NumericalWarning
from netsense.observers.source import LuenbergerSource
from netsense.sensing.arrivals import AlwaysArrive
from netsense.sensing.noise import NoNoise

# the model classes live in netsense.engine.model; this module re-exports them
__all__ = ["CHUNK", "CHUNK_BUDGET", "INVALID_ACTIONS", "NONFINITE", "SUBSTATES", "BatchedCore",
           "CoreModel", "NumericalError", "ObsLayout", "RewardConfig", "StepResult", "symlog"]

#: Most steps of graphs, noise and arrivals drawn at once per member.
CHUNK = 64
#: Memory budget of those pre-drawn chunks (bytes, whole batch); large batches use shorter
#: chunks. A realisation never depends on the chunk length (every stream is drawn
#: sequentially; ``tests/test_env_core.py`` checks this on every scenario).
CHUNK_BUDGET = 48 * 2**20
_STREAMS = ("init", "graph", "process_noise", "measurement_noise", "measurement_arrivals",
            "message_arrivals", "source")
INVALID_ACTIONS = ("raise", "keep")
#: What a step does when a plant state, estimate or reward becomes non-finite.
NONFINITE = ("terminate", "raise")


@contextmanager
def _rows(buf: np.ndarray, members: np.ndarray, start: int = 0) -> Iterator[np.ndarray]:
    """The rows ``buf[members, start:]`` to write into: a view when the members are
    contiguous and ``start = 0``, else a scratch array that is copied into ``buf`` on
    exit."""
    if not start and members.size and members[-1] - members[0] + 1 == members.size:
        yield buf[members[0]:members[-1] + 1]
        return
    out = np.empty((members.size, buf.shape[1] - start, *buf.shape[2:]), buf.dtype)
    yield out
    buf[members, start:] = out


class StepResult(NamedTuple):
    """What :meth:`BatchedCore.step` returns (all arrays have a leading batch axis)."""

    obs: np.ndarray  #: (B, N, obs_dim) float32
    action_mask: np.ndarray  #: (B, N, M * (D + 2) + 2) int8
    reward: np.ndarray  #: (B, N) float64
    terminated: np.ndarray  #: (B,) bool
    truncated: np.ndarray  #: (B,) bool


class BatchedCore:
    """``B`` independent environments of one scenario advanced together.

    Parameters
    ----------
    model : CoreModel
        The scenario's dynamics.
    batch_size : int
        ``B``.
    invalid_actions : {"raise", "keep"}
        Behaviour on masked actions (see the module docstring).
    chunk : int, optional
        Steps of graphs, noise and arrivals drawn at once per member.
    nonfinite : {"terminate", "raise"}
        Behaviour when a state, estimate or reward becomes non-finite (module docstring).

    Attributes (state at the current time ``k``; read-only for callers)
    ------------------------------------------------------------------------
    x : (B, n)             true state ``x[k]``.
    Z : (B, N, n)          estimates in Lemma 1 coordinates (``x_hat = T z_hat``).
    tau : (B, N, M) int    freshness indices (``OMEGA = -1``; column m: source sources[m]).
    k : (B,) int           time index per member.
    adjacency : (B, N, N)  ``G[k]``; ``nbr``/``valid`` its slots (B, N, D).
    y : (B, N, r_max)      measurements ``y[k]``; ``y_arrived`` (B, N).
    transmit : (B, N)      who transmitted at ``k``; ``msg`` (B, N, D): message arrived.
    errors : (B, N)        normalised errors of the last step (0 after reset).
    nonfinite : list of B  ``None``, or ``{"step", "what", "agent"}`` from the step at which
                           member ``b``'s state or estimates stopped being finite.

    The state arrays are the core's working buffers, written in place by its threaded
    passes: ``x``, ``Z`` and ``tau`` alternate between two sets (the arrays of step ``k``
    are rewritten at step ``k + 2``), ``nbr``, ``y`` and ``msg`` are rewritten at every
    step, and so are ``transmit``, ``errors`` and ``raw_errors``. Copy what you keep.
    What :meth:`step`, :meth:`reset` and :meth:`observe` return (observations, masks,
    rewards, flags) is fresh at every step.

    Notes
    -----
    Randomness: member ``b`` owns independent generators (spawned from its seed) for the
    initial state, the graph process, process and measurement noise, measurement and
    message arrivals; graphs, noise and arrivals are drawn ``chunk`` steps at a time per
    member (``chunk`` defaults to :data:`CHUNK`, less when the batch would exceed
    :data:`CHUNK_BUDGET`), and a member's realisation depends only on its seed, never on
    ``B`` or ``chunk``.
    The source estimator is one object for the whole batch that keeps per-member state:
    it receives the per-member time vector ``k``, is given each member's own ``"source"``
    generator, and partial resets restart only the selected members
    (:meth:`~netsense.observers.source.SourceEstimator.reset_members`), so a member equals
    a single run with the same seed for stateful estimators (KFIO, RSEIO, equalized) too.
    """

    def __init__(self, model: CoreModel, batch_size: int = 1, *,
                 invalid_actions: str = "raise", chunk: int | None = None,
                 nonfinite: str = "terminate") -> None:
        if not isinstance(model, CoreModel):
            raise ValueError("model must be a CoreModel (see netsense.env.registry)")
        batch_size = checks.integer("batch_size", batch_size, 1)
        checks.choice("invalid_actions", invalid_actions, INVALID_ACTIONS)
        if chunk is not None:
            chunk = checks.integer("chunk", chunk, 1)
        self.nonfinite_mode = checks.choice("nonfinite", nonfinite, NONFINITE)
        self.model = model
        self.B = int(batch_size)
        self.invalid_actions = invalid_actions
        plant, design = model.plant, model.design
        dec = design.decomposition
        self.N, self.n = plant.num_agents, plant.n
        self.r = plant.max_outputs
        self.D = int(model.graphs.max_in_degree)
        self.horizon = int(model.horizon)
        self.T = dec.T
        self.block_of = dec.block_of
        self.A_diag, self.A_lower = dec.A_diag, dec.A_lower
        self._ALT = np.ascontiguousarray(self.A_lower.T)
        self._ADT = np.ascontiguousarray(self.A_diag.T)
        self._TT = np.ascontiguousarray(dec.T)
        self._A_T = np.ascontiguousarray(plant.A.T)
        self.C_padded = plant.C_padded
        self._C_flat_T = self.C_padded.reshape(-1, self.n).T.copy()  # y = C x, eq. (2)
        self.output_mask = plant.output_mask
        self._outputs_all_real = bool(np.all(self.output_mask))
        self.W = plant.W_effective
        self._W_T = np.ascontiguousarray(self.W.T)
        #: ``(N,)`` whether the agent measures a block of Lemma 1's decomposition (a source)
        self.is_source = np.bincount(self.block_of, minlength=self.N) > 0
        self.sources = (np.flatnonzero(self.is_source) if model.substates == "sources"
                        else np.arange(self.N))
        self.M = int(self.sources.size)
        self.control = model.control
        self.layout = ObsLayout.build(self.N, self.n, self.r, self.D, self.sources,
                                      comm=self.control.comm_only,
                                      announce=self.control.announce,
                                      feedback=self.control.feedback)
        #: ``(B, N, D)`` slots of ``G[k+1]`` when the scenario announces it
        #: (``model.known_ahead = 1``; None otherwise)
        self.nbr_next: np.ndarray | None = None
        #: ``(N,)`` column of each agent's own substate (``-1``: owns none)
        self.own = self.layout.own
        self.nvec = np.array([self.D + 2] * self.M + [2], dtype=np.int64)
        #: the communication-only modes' state and rules (None in full control)
        self.comm: CommControl | None = None
        if self.control.comm_only:
            table = (tree_choice_table(model.graphs, self.D, self.sources)
                     if self.control.fusion == "tree" else None)
            empty = ~self.is_source[self.sources]
            self.comm = CommControl(self.control, self.B, self.N, self.M, self.D, self.own,
                                    self.horizon, table, empty)
            self.nvec = self.comm.nvec
        self.mask_size = int(self.nvec.sum())
        #: capacity ``K`` of the shared channel (None: no ``[channel]``)
        self.capacity = None if model.channel is None else int(model.channel.capacity)
        column = np.full(self.N, -1, dtype=np.int64)
        column[self.sources] = np.arange(self.M)
        self._block_of = np.ascontiguousarray(column[self.block_of])
        self.source = (model.source_estimator or LuenbergerSource)()
        from netsense.observers.faults import CrashedAgents, LyingAgent, StuckSensor

        self._crashes = [f for f in model.faults if isinstance(f, CrashedAgents)]
        self._stuck = [f for f in model.faults if isinstance(f, StuckSensor)]
        self._liar = next((f for f in model.faults if isinstance(f, LyingAgent)), None)
        alive = np.ones(self.N, dtype=bool)
        for f in model.faults:
            alive &= f.alive(self.N)
        #: ``(N,)`` agents whose errors count (crashed agents and liars excluded)
        self.alive = alive
        self._has_pnoise = not isinstance(plant.process_noise, NoNoise)
        self._has_mnoise = not isinstance(plant.measurement_noise, NoNoise)
        self._meas_always = isinstance(model.measurement_arrivals, AlwaysArrive)
        self._msg_always = isinstance(model.message_arrivals, AlwaysArrive)
        B, N, D = self.B, self.N, self.D
        self._slot_dtype = np.int16 if N < 2**15 else np.int64
        per_step = (N * D * np.dtype(self._slot_dtype).itemsize
                    + 8 * N * self.r * self._has_mnoise + 8 * self.W.shape[1] * self._has_pnoise
                    + N * (not self._meas_always) + N * N * (not self._msg_always))
        self.chunk = int(chunk) if chunk is not None else int(
            np.clip(CHUNK_BUDGET // max(B * per_step, 1), 1, CHUNK))
        self._bidx = np.arange(B)
        self._obs_starts = np.array([start for _, start, _ in self.layout.table()],
                                    dtype=np.int64)
        self._seeded = False

    # ------------------------------------------------------------------ reset
    def reset(self, seed: int | Sequence[int] | None = None,
              members: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Start new episodes; returns ``(obs (B, N, obs_dim), action_mask (B, N, M))``.

        Parameters
        ----------
        seed : int, sequence of B ints, or None
            Member ``b`` gets ``seed + b`` (int) or ``seed[b]``; ``None`` draws fresh
            entropy. With ``members``, only the selected members are re-seeded (an int
            seed then still maps member ``b`` to ``seed + b``).
        members : (B,) bool, optional
            Reset only these members (default all). The first reset must be a full one.
        """
        B = self.B
        if members is None:
            sel = np.ones(B, bool)
        else:
            sel = np.asarray(members)
            if sel.dtype != bool or sel.shape != (B,):
                raise ValueError(f"members must be a bool mask of shape ({B},), got "
                                 f"{sel.dtype} {sel.shape} (for member indices idx pass "
                                 f"np.isin(np.arange({B}), idx))")
        if not self._seeded and not sel.all():
            raise ValueError("the first reset must reset every member")
        if seed is None:
            seeds = [int(s) for s in np.random.SeedSequence().generate_state(B, np.uint64)]
        elif isinstance(seed, (str, bytes)) or np.ndim(seed) == 0:
            seeds = [checks.seed_value("seed", seed, B) + b for b in range(B)]
        else:
            if not isinstance(seed, (Sequence, np.ndarray)) or np.ndim(seed) != 1:
                raise ValueError(f"seed must be an int, a sequence of {B} ints or None, got "
                                 f"{type(seed).__name__}")
            if len(seed) != B:
                raise ValueError(f"seed must hold {B} entries, got {len(seed)}")
            seeds = [checks.seed_value(f"seed[{b}]", s) for b, s in enumerate(seed)]
        if not self._seeded:
            self._alloc()
        idx = np.flatnonzero(sel)
        for b in idx:
            self._reset_member(b, seeds[b])
        self._refill(idx)
        source_rngs = [r.get("source") for r in self.rngs]  # each member's own stream
        if sel.all():
            self.source.reset(self.model.design, B, source_rngs)
        else:
            self.source.reset_members(sel, source_rngs)
        self._seeded = True
        if self.comm is not None:
            self.comm.reset_members(idx, self.transmit, self.tau, self.k)
        self._load_step()
        return self.observe()

    def _alloc(self) -> None:
        B, N, n, r, K = self.B, self.N, self.n, self.r, self.chunk
        self.rngs: list[dict[str, np.random.Generator]] = [{} for _ in range(B)]
        self.graph_state: list = [None] * B
        #: per member, the graph process state before the last drawn step was drawn
        #: (with ``chunk = 1``: the state ``G[k]`` came from; :mod:`netsense.engine.fork`)
        self.graph_state_prev: list = [None] * B
        # lanes of a fork share their generators, graph states and samplers until their
        # first refill (netsense.engine.fork): member -> the shared snapshot to copy then
        self._snapshots: dict[int, tuple] = {}
        self.meas_sampler: list = [None] * B
        self.msg_sampler: list = [None] * B
        self.x = np.zeros((B, n))
        self.Z = np.zeros((B, N, n))
        self.tau = np.full((B, N, self.M), kernels.OMEGA, dtype=np.int64)
        self.k = np.zeros(B, dtype=np.int64)
        self.transmit = self._tx_buf = np.ones((B, N), dtype=bool)  # rewritten in place
        self.errors = self._err_buf = np.zeros((B, N))  # at every step
        self.raw_errors = self._raw_buf = np.zeros((B, N))
        self.messages_sent = np.zeros(B, dtype=np.int64)
        self.nonfinite: list[dict | None] = [None] * B
        #: (B,) bool: the messages of the current step collided (``[channel]``)
        self.collided = np.zeros(B, dtype=bool)
        self.ptr = np.zeros(B, dtype=np.int64)
        # graphs are kept as their slot tables only (-1 = empty slot; G[k] is rebuilt
        # from them on demand), in the smallest integer type that holds a node id
        self.buf_nbr = np.zeros((B, K, N, self.D), dtype=self._slot_dtype)
        self._ones_BN = np.ones((B, N), dtype=bool)
        self.buf_w = np.zeros((B, K, self.W.shape[1])) if self._has_pnoise else None
        self.buf_v = np.zeros((B, K, N, r)) if self._has_mnoise else None
        self.buf_meas = None if self._meas_always else np.ones((B, K, N), dtype=bool)
        self.buf_msg = None if self._msg_always else np.ones((B, K, N, N), dtype=bool)
        self._stuck_memory = [f.new_state(B, r) for f in self._stuck]
        # largest index a liar injects (indices are <= k + claim: exact in float32 below)
        self._claim = 0 if self._liar is None else int(self._liar.claim)
        self._no_v = np.zeros((1, 1, 1))  # stand-ins for absent buffers (never read)
        self._no_link = np.ones((1, 1, 1, 1), dtype=bool)
        # working buffers, written in place by the threaded passes at every step (each
        # member's rows by the same thread; see kernels.StepBuffers for why): two sets of
        # step outputs, used in turn (a step reads the state the other set holds; made
        # at the first step), the observation pass's scratch rows and the current
        # step's slots, outputs and messages
        self._step_bufs: tuple[kernels.StepBuffers, ...] = ()
        self._turn = 0
        self._fill_bufs = FillBuffers(B, N, self.M, self.mask_size)
        self.nbr = np.empty((B, N, self.D), dtype=np.int64)
        self._y_load = np.empty((B, N * r))
        self.msg = np.empty((B, N, self.D), dtype=bool)
        if self.control.announce:
            self.nbr_next = np.empty((B, N, self.D), dtype=np.int64)

    def _reset_member(self, b: int, seed: int) -> None:
        m = self.model
        children = np.random.SeedSequence(seed).spawn(len(_STREAMS))
        rngs = {name: np.random.default_rng(c) for name, c in zip(_STREAMS, children,
                                                                   strict=True)}
        self.rngs[b] = rngs
        self._snapshots.pop(b, None)
        self.x[b] = m.x0_std * rngs["init"].standard_normal(self.n)
        self.Z[b] = 0.0
        self.tau[b] = kernels.OMEGA
        self.tau[b, self.sources, np.arange(self.M)] = 0
        self.k[b] = 0
        self.transmit[b] = bool(m.initial_transmit)
        self.transmit[b] &= ~self._silenced(np.zeros(1, np.int64))[0]
        self.errors[b] = 0.0
        self.raw_errors[b] = 0.0
        self.nonfinite[b] = None
        self.messages_sent[b] = 0
        self.graph_state[b] = m.graphs.initial_state(rngs["graph"])
        if not self._meas_always:
            self.meas_sampler[b] = m.measurement_arrivals.sampler(
                rngs["measurement_arrivals"], (self.N,))
        if not self._msg_always:
            self.msg_sampler[b] = m.message_arrivals.sampler(
                rngs["message_arrivals"], (self.N, self.N))

    def _refill(self, members: np.ndarray) -> None:
        """Draw the next ``chunk`` steps of graphs, noise and arrivals for ``members``."""
        members = np.asarray(members, dtype=np.int64)
        if self._snapshots:
            self._materialise(members)
        for b in members:
            self.graph_state_prev[b] = self.graph_state[b]
        self._draw(members)
        self.ptr[members] = 0

    def _draw(self, members: np.ndarray, graph: int = 0, process: int = 0,
              other: int = 0) -> None:
        """Fill the chunk positions from ``graph`` on with graphs, from ``process`` on
        with process noise and from ``other`` on with measurement noise and arrivals, for
        ``members``, each from its own generators and samplers (positions before the
        starts are left as they are; a fork fills them, :mod:`netsense.engine.fork`)."""
        m, K = self.model, self.chunk
        # graphs for groups of members at once (each from its own "graph" generator, so
        # equal to per-member sampling), in groups that keep the process's temporaries
        # near 16 MB; slot tables written straight into the chunk buffer
        group = max(1, (16 * 2**20) // max(m.graphs.slot_sample_bytes(K), 1))
        for g in range(0, len(members) if graph < K else 0, group):
            mem = members[g:g + group]
            with _rows(self.buf_nbr, mem, graph) as out:
                _, states = m.graphs.sample_slots_many(
                    [self.rngs[b]["graph"] for b in mem], K - graph,
                    [self.graph_state[b] for b in mem], self.D, out=out)
            for b, st in zip(mem, states, strict=True):
                self.graph_state[b] = st
        # noise of all members in one call per model (one compiled pass for Gaussian
        # noise), each member from its own generator: the same numbers as member by member
        if self._has_pnoise and process < K:
            with _rows(self.buf_w, members, process) as out:
                m.plant.process_noise.sample_many(
                    [self.rngs[b]["process_noise"] for b in members],
                    (K - process, self.W.shape[1]), out)
        if other >= K:
            return
        if self._has_mnoise:
            with _rows(self.buf_v, members, other) as out:
                m.plant.measurement_noise.sample_many(
                    [self.rngs[b]["measurement_noise"] for b in members],
                    (K - other, self.N, self.r), out)
                if not self._outputs_all_real:
                    out *= self.output_mask  # padded outputs carry no noise
        for b in members if not (self._meas_always and self._msg_always) else ():
            if not self._meas_always:
                s = self.meas_sampler[b]
                self.buf_meas[b, other:] = np.stack([s.next() for _ in range(K - other)])
            if not self._msg_always:
                s = self.msg_sampler[b]
                self.buf_msg[b, other:] = np.stack([s.next() for _ in range(K - other)])

    def _materialise(self, members: np.ndarray) -> None:
        """Give the members that still share a fork's snapshot their own copies of its
        generators, graph states and samplers (before anything draws from them)."""
        import copy

        for b in members:
            snap = self._snapshots.pop(int(b), None)
            if snap is not None:
                (self.rngs[b], self.graph_state[b], self.graph_state_prev[b],
                 self.meas_sampler[b], self.msg_sampler[b]) = copy.deepcopy(snap)

    def _load_step(self) -> None:
        """Expose the current step's graph, measurements and messages (from the chunk)."""
        B, N, r = self.B, self.N, self.r
        # one compiled pass per member: slots, outputs y = C x + v (eq. (2)) and the
        # message table (link l -> i is buf_msg[b, p, i, l]), into the core's buffers
        y = self._y_load
        v = self.buf_v.reshape(B, self.chunk, N * r) if self._has_mnoise else self._no_v
        link = self._no_link if self._msg_always else self.buf_msg
        drivers.load_all.at(B * N * (self.D + self.n * r), runs=B)(
            self.buf_nbr, self.ptr, self.x, self._C_flat_T, self._has_mnoise, v,
            self.transmit, not self._msg_always, link, self.nbr, y, self.msg)
        self._adjacency = None
        y = y.reshape(B, N, r)
        for f, memory in zip(self._stuck, self._stuck_memory, strict=True):
            y = f.apply(self.k, y, memory)  # stuck/stale readings replace y_i[k]
        self.y = y
        if self.capacity is not None:  # at most K senders per step, else all lost
            apply_collisions(self.transmit, self.msg, self.capacity, self.collided)
        if self.comm is not None:  # the fusion rule's choice for this step's messages
            self.comm.fuse(self.reported_indices(), self.nbr, self.msg, self.k)
        if self.nbr_next is not None:  # G[k+1], announced in the observation
            self._load_next_graph()
        if self._meas_always:
            self.y_arrived = self._ones_BN
        elif self.ptr.min() == self.ptr.max():  # all members at one chunk position:
            # C-contiguous, as the gather below gives (B * N bools), so that the compiled
            # passes that read it are compiled for one layout only (a strided view made the
            # threaded update and observation compile twice: +10 s cold)
            self.y_arrived = np.ascontiguousarray(self.buf_meas[:, int(self.ptr[0])])
        else:
            self.y_arrived = self.buf_meas[self._bidx, self.ptr]
        self._mask = None
        self._obs = None

    def _load_next_graph(self) -> None:
        """``nbr_next``: the slots of ``G[k+1]``, from the chunk where it is drawn, else a
        peek (:meth:`peek_next_graphs`)."""
        inside = self.ptr + 1 < self.chunk
        if inside.any():
            b = np.flatnonzero(inside)
            self.nbr_next[b] = self.buf_nbr[b, self.ptr[b] + 1]
        if not inside.all():
            b = np.flatnonzero(~inside)
            self.nbr_next[b] = self.peek_next_graphs(b)[0]

    def peek_next_graphs(self, members: np.ndarray) -> tuple[np.ndarray, list]:
        """The next graph the members' graph streams will draw, without drawing it.

        For members at the last step of their chunk (``ptr + 1 = chunk``) this is
        ``G[k+1]``: the graph process is sampled one step from copies of the member's
        ``"graph"`` generator and process state, which the next refill then draws again
        (a realisation does not depend on the chunk length). Returns the slot tables
        ``(len(members), N, D)`` and the graph-process states after that graph (what a
        lookahead that keeps ``G[k+1]`` and redraws the rest continues from).
        """
        import copy

        members = np.asarray(members, dtype=np.int64)
        if self._snapshots:  # lanes of a fork that still share its generators
            self._materialise(members)
        rngs = [copy.deepcopy(self.rngs[b]["graph"]) for b in members]
        states = [copy.deepcopy(self.graph_state[b]) for b in members]
        out = np.empty((members.size, 1, self.N, self.D), dtype=self._slot_dtype)
        _, after = self.model.graphs.sample_slots_many(rngs, 1, states, self.D, out=out)
        return out[:, 0].astype(np.int64), after

    # ------------------------------------------------------------------ slot views
    @property
    def valid(self) -> np.ndarray:
        """``(B, N, D)`` bool: slot ``d`` of agent ``i`` holds an in-neighbour in ``G[k]``."""
        return self.nbr >= 0

    # ------------------------------------------------------------------ masks
    def action_mask(self) -> np.ndarray:
        """``(B, N, M * (D + 2) + 2)`` int8: allowed choices per substate, then transmit.

        The block of substate ``j`` is ``[keep, slot 0 .. slot D-1, average]``; slots
        allow only a message that arrived, and an agent's own substate allows only keep.
        """
        self._require_reset("action_mask")
        if self._mask is None:
            self._mask = np.empty((self.B, self.N, self.mask_size), dtype=np.int8)
            self._fill(None, self._mask)
        return self._mask

    # ------------------------------------------------------------------ step
    def _as_actions(self, actions) -> np.ndarray:
        """``actions`` as an integer ``(B, N, len(nvec))`` array (shape and dtype checked):
        ``M + 1`` entries in full control, 1 or ``M`` bits in the communication modes."""
        B, N, A = self.B, self.N, self.nvec.size
        a = np.asarray(actions)
        if a.shape != (B, N, A):
            what = "M + 1" if self.comm is None else "len(nvec)"
            raise ValueError(f"actions must have shape (B, N, {what}) = {(B, N, A)}, "
                             f"got {a.shape}")
        if a.dtype.kind not in "iu":
            if a.dtype.kind not in "fb":
                raise ValueError(f"actions must be integers, got dtype {a.dtype}")
            if a.dtype.kind == "f":  # integral and exact in int64, else named with its value
                bad = ~(np.abs(a) < 2**62) | (a != np.round(a))
                if bad.any():
                    pos = tuple(int(v[0]) for v in np.nonzero(bad))
                    raise ValueError(f"actions must be integers; entry {list(pos)} (member, "
                                     f"agent, column) is {float(a[pos])!r}")
            a = a.astype(np.int64)
        elif a.dtype == np.uint64:  # uint64 + int64 offsets would promote to float
            if a.size and a.max() >= 2**62:
                b, i, j = (int(v) for v in np.unravel_index(int(a.argmax()), a.shape))
                if self.comm is None:
                    what = f"substate {j}" if j < self.M else "transmit"
                else:
                    what = f"substate {j}" if self.comm.per_substate else "transmit"
                raise ValueError(f"action of agent {i} (batch member {b}) for {what} is "
                                 f"{int(a[b, i, j])}, outside 0..{int(self.nvec[j]) - 1}")
            a = a.astype(np.int64)
        return a

    def _refuse(self, status: np.ndarray, a: np.ndarray) -> None:
        """Raise for an out-of-range entry, or a masked one under ``"raise"``
        (``status`` of :func:`netsense.kernels.update.check_actions`)."""
        M = self.M
        if status[0] >= 0:  # out of range (always an error)
            b, i, j = (int(v) for v in status[:3])
            what = f"substate {j}" if j < M else "transmit"
            raise ValueError(f"action of agent {i} (batch member {b}) for {what} is "
                             f"{int(a[b, i, j])}, outside 0..{int(self.nvec[j]) - 1}")
        if status[3] >= 0 and self.invalid_actions == "raise":
            b, i, j = (int(v) for v in status[3:])
            c = int(a[b, i, j])
            why = ("the own substate of a source is updated by eq. (7), only 0 is allowed"
                   if j == self.own[i] else f"slot {c - 1} holds no message at this step")
            raise ValueError(f"masked action: agent {i} (batch member {b}), substate {j}, "
                             f"choice {c}: {why}")

    def step(self, actions, *, observe: bool = True) -> StepResult:
        """Advance every member from ``k`` to ``k + 1`` under ``actions (B, N, M + 1)``.

        Estimates: eqs. (7), (9)-(12) via the kernels; indices: eqs. (9), (11), (14), and
        the stalest-contributor rule for averages. Then the plant (eq. (1)), the next
        graph, measurements (eq. (2)) and messages, rewards and observations.

        With ``observe=False`` the result's ``obs`` and ``action_mask`` are ``None`` and
        nothing of size ``obs_dim`` is built (for callers that act on the state, e.g.
        Monte Carlo runs of scripted rules); :meth:`observe` returns them for the current
        step on demand, equal to what ``observe=True`` would have returned. Validation of
        the next actions never needs them.
        """
        self._require_reset("step")
        a = self._as_actions(actions)
        bits = comm_masked = None
        if self.comm is not None:  # the fusion rule adopts, the bits say who transmits
            a, bits, comm_masked = self.comm.expand(a, self.invalid_actions)
        B = self.B
        Z, tau = self.Z, self.reported_indices()  # a liar's claims are what others adopt
        # the default fixed-gain source (eq. (7)) runs inside the fused update; any other
        # estimator (KFIO, RSEIO, equalized, ...) returns its correction here, after the
        # actions were validated (a stateful source's correction is a state change)
        if type(self.source) is LuenbergerSource:
            src_kw = {"luenberger": (self.y, self.y_arrived, self.source.C_bar_pad,
                                     self.source.L_pad, self.source.gain_rows)}
        else:
            choice = np.empty((B, self.N, self.M), dtype=np.int64)
            self._refuse(kernels._check_actions(a, self.msg, choice,
                                                np.empty(choice.shape, bool), self.own), a)
            corr = self.source.correction(self.k, Z, self.y, self.y_arrived)
            src_kw = {"corr": np.ascontiguousarray(corr, dtype=float)}
        if not self._step_bufs:
            C = src_kw["luenberger"][2] if "luenberger" in src_kw else np.zeros((1, 1, 1))
            one = kernels.StepBuffers(B, self.N, self.n, self.M, self.D, self.n, C.shape[1],
                                      tau.dtype)
            self._step_bufs = (one, kernels.StepBuffers(*one.key, share_scratch=one))
        w = None
        if self._has_pnoise:
            w = np.take_along_axis(self.buf_w, self.ptr[:, None, None], 1)[:, 0]  # (B, p)
        # --- one pass: plant (eq. (1)), validation, keep / adopt / average per agent and
        # substate, eqs. (6)-(14), source correction (eq. (7)), errors; every member is
        # computed alone, exactly as in a B = 1 run. (kernels.keep_own_blocks is not
        # needed: validation leaves every own substate at 0 = keep.)
        out = kernels._apply_actions(
            Z, tau, a, self.nbr, self.msg, self._block_of, self._ALT, self._ADT, x=self.x,
            A_T=self._A_T, T=self._TT, w=w, W_T=self._W_T, own=self.own,
            work=self._step_bufs[self._turn], **src_kw)
        self._refuse(out.status, a)  # nothing committed yet (the outputs are the set
        # numerical health: ||z_hat - z|| is finite iff the state and the estimates are (a
        # finite error is <= sqrt(DBL_MAX), so their sum is finite iff every one is)
        bad = None if math.isfinite(np.add.reduce(out.err, None)) else self._diagnose(out)
        self._turn ^= 1  # of buffers the state is not in)
        self.last_invalid = out.masked if comm_masked is None else comm_masked
        self.x, self.Z, self.tau = out.x_next, out.Z_next, out.tau_next
        self.k += 1
        # rewards, next transmit flags (crashed agents send nothing from their crash step
        # on; k already advanced), termination and truncation, in one compiled pass
        N = self.N  # (rewards and flags fresh: they are returned)
        tail = rewards.finish_step(
            out.x_next, out.err, a, self.M, self._silenced(self.k) if self._crashes else None,
            self.alive, self.model.reward, self.model.divergence_limit, self.k,
            self.horizon, self.messages_sent, rewards.StepTail(
                np.empty((B, N)), self._raw_buf, self._err_buf, self._tx_buf,
                np.empty(B, bool), np.empty(B, bool)))
        if bad:
            self._flag_nonfinite(bad, tail)
        self.transmit = tail.transmit
        self.raw_errors, self.errors = tail.raw_errors, tail.errors
        if self.comm is not None:  # per-substate payload, what each agent last sent
            self.comm.after_step(bits, self.transmit, self.tau, self.k, tail.reward,
                                 self.model.reward.substate_cost)
        self.ptr += 1
        if self.ptr.max() >= self.chunk:
            self._refill(np.flatnonzero(self.ptr >= self.chunk))
        self._load_step()
        obs, mask = self.observe() if observe else (None, None)
        return StepResult(obs, mask, tail.reward, tail.terminated, tail.truncated)

    # ------------------------------------------------------------------ health
    def _require_reset(self, what: str) -> None:
        if not self._seeded:
            raise ValueError(f"reset() must be called before {what}()")

    def _diagnose(self, out) -> dict[int, dict]:
        """The members whose state or estimates are not finite after this step: ``{b:
        {"step", "what", "agent"}}``; raises under ``nonfinite="raise"``. (Rewards need no
        check: errors are clipped, NaN included, and :class:`RewardConfig` bounds
        ``|reward| <= error_weight * error_clip + message_cost``.)"""
        found = {}
        for b in np.flatnonzero(~np.isfinite(out.err).all(1)):
            b = int(b)
            if not np.isfinite(out.x_next[b]).all():
                what, agent = "state", None
            elif not np.isfinite(out.Z_next[b]).all():
                bad_i = ~np.isfinite(out.Z_next[b]).all(1)
                what, agent = "estimate", int(np.flatnonzero(bad_i)[0])
            else:  # finite, but ||z_hat_i - z|| overflowed
                what, agent = "error", int(np.flatnonzero(~np.isfinite(out.err[b]))[0])
            found[b] = {"step": int(self.k[b]) + 1, "what": what, "agent": agent}
            if self.nonfinite_mode == "raise":
                r = found[b]
                raise NumericalError(self._nonfinite_message(b, r), member=b,
                                     agent=r["agent"], step=r["step"], what=what)
        return found

    def _nonfinite_message(self, b: int, r: dict) -> str:
        who = {"state": "the plant state x is inf or NaN",
               "estimate": f"the estimate of agent {r['agent']} is inf or NaN",
               "error": f"the estimation error of agent {r['agent']} overflowed (finite "
                        "state and estimate, |x_hat - x| > 1e154)"}[r["what"]]
        return (f"non-finite {r['what']}: {who} at step {r['step']} (batch member {b}); "
                "the member's episode is over, reset it")

    def _flag_nonfinite(self, bad: dict[int, dict], tail) -> None:
        """Terminate the members of ``bad``; record and warn once per member and episode."""
        import warnings

        for b, r in bad.items():
            tail.terminated[b], tail.truncated[b] = True, False
            if self.nonfinite[b] is None:
                self.nonfinite[b] = r
                warnings.warn(self._nonfinite_message(b, r), NumericalWarning, stacklevel=3)

    # ------------------------------------------------------------------ faults
    def _silenced(self, k: np.ndarray) -> np.ndarray:
        """``(len(k), N)``: agents crashed at times ``k`` (never transmit)."""
        out = np.zeros((len(k), self.N), dtype=bool)
        for f in self._crashes:
            out |= f.silenced(k, self.N)
        return out

    def reported_indices(self) -> np.ndarray:
        """Freshness indices as the network sees them, ``(B, N, N)``: ``tau`` with a liar's
        rows replaced by its claim from its start step (:meth:`netsense.observers.faults.LyingAgent.
        reported`); ``tau`` itself without a liar."""
        self._require_reset("reported_indices")
        if self._liar is None:
            return self.tau
        return self._liar.reported(self.tau, self.k)

    # ------------------------------------------------------------------ observations
    def observe(self) -> tuple[np.ndarray, np.ndarray]:
        """Observations ``(B, N, obs_dim)`` float32 and masks of the current step
        (:func:`netsense.engine.observation.fill`; computed once per step)."""
        self._require_reset("observe")
        if self._obs is None:
            self._obs = np.empty((self.B, self.N, self.layout.size), dtype=np.float32)
            if self._mask is None:
                self._mask = np.empty((self.B, self.N, self.mask_size), dtype=np.int8)
                self._fill(self._obs, self._mask)
            else:
                self._fill(self._obs, None)
        return self._obs, self._mask

    def _fill(self, obs: np.ndarray | None, mask: np.ndarray | None) -> None:
        H = float(self.horizon)
        exact = H < 2**24 and int(self.k.max()) + self._claim < 2**24
        dummy_o = np.empty((1, 1, 1), np.float32)
        dummy_m = np.empty((1, 1, 1), np.int8)
        full_mask = mask if self.comm is None else None
        if obs is not None or full_mask is not None:
            observation.fill(dummy_o if obs is None else obs,
                             dummy_m if full_mask is None else full_mask,
                             self._obs_starts, self.k, H, self.y, self.y_arrived,
                             self.reported_indices(), self.Z, self.nbr, self.msg, exact,
                             observations=obs is not None, masks=full_mask is not None,
                             own=self.own, work=self._fill_bufs)
        if self.comm is not None:
            self.comm.fill(obs, mask, self.layout, self.k, self.nbr, self.msg, self.transmit,
                           None if self.capacity is None else self.collided, self.nbr_next)

    # ------------------------------------------------------------------ views
    @property
    def adjacency(self) -> np.ndarray:
        """``G[k]`` as ``(B, N, N)`` bool (``[b, i, l]``: ``l -> i``), from the slots."""
        self._require_reset("adjacency")
        if self._adjacency is None:
            self._adjacency = slot_adjacency(self.nbr, self.N)
        return self._adjacency

    @property
    def estimates(self) -> np.ndarray:
        """Every agent's estimate of ``x``, ``(B, N, n)`` (``x_hat = T z_hat``)."""
        self._require_reset("estimates")
        return self.Z @ self.T.T

    def state_vector(self) -> np.ndarray:
        """Global state per member ``(B, n + N n + N N)``: ``x``, estimates, ``G[k]``."""
        self._require_reset("state_vector")
        B = self.B
        return np.concatenate([self.x, self.estimates.reshape(B, -1),
                               self.adjacency.reshape(B, -1).astype(float)], axis=1)
