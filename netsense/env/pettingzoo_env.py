"""NetSense: networked state estimation as a PettingZoo ``ParallelEnv``.

Description
-----------
``N`` sensor agents estimate the state ``x`` of a linear plant ``x[k+1] = A x[k] + w``
(eq. (1)); agent ``i`` measures ``y_i[k] = C_i x[k] + v_i`` (eq. (2)) and talks over a
switching directed graph ``G[k]``. Each agent keeps an estimate of every substate
``z^{(j)}`` of Lemma 1's decomposition (``x = T z``) and a freshness index
``tau_i^{(j)}`` (Section IV of the freshness-index paper). Every step it decides, per
substate, whom to listen to, and whether to transmit. The scripted observers of the paper
are policies of this environment (:mod:`netsense.env.policies`); the freshness policy with
everyone transmitting reproduces :class:`netsense.FreshnessObserver` exactly.

The dynamics are the ``B = 1`` case of :class:`netsense.engine.core.BatchedCore`, which calls
the kernels of :mod:`netsense.kernels.update`; the AEC form is ``pettingzoo.utils.parallel_to_aec``.

==================  ===========================================================
Import              ``netsense.make("fig1_scalar-v0")`` (see ``netsense list``)
Agents              ``sensor_0 .. sensor_{N-1}`` (all with identical spaces)
Action space        ``MultiDiscrete([D + 2] * M + [2])`` (full control), ``([2])`` or
                    ``([2] * M)`` (communication only, see Control modes)
Observation space   ``Dict(observation=Box(obs_dim), action_mask=MultiBinary(M))``
                    or ``Box(obs_dim)`` with ``action_mask_in="info"``
State space         ``Box(n + N n + N N)``: ``x``, every estimate of ``x``, ``G[k]``
Parallel API        yes (AEC through ``parallel_to_aec``)
==================  ===========================================================

Agents
------
``sensor_i`` is node ``i`` of the graph and owns substate ``i`` (possibly empty, then it
only relays). All agents act simultaneously.

Action Space
------------
``MultiDiscrete([D + 2] * M + [2])`` where ``D`` is the graph process's maximum in-degree
(slots are padded to ``D``; slot ``d`` holds the ``d``-th smallest in-neighbour id) and
``M`` the number of substates: ``M = N`` (one per agent, the paper's setting, default) or,
with the scenario key ``substates = "sources"``, the number of agents whose block of
Lemma 1 is non-empty (``env.layout.sources[j]`` is the agent of substate ``j``; an empty
substate has nothing to estimate, so estimates and rewards are unchanged).

=========  ================================================================================
entry      meaning
=========  ================================================================================
``a[j]``   substate ``j``: ``0`` keep own estimate (open loop, eqs. (11)/(12)/(14)),
           ``1..D`` adopt neighbour slot ``a[j] - 1`` (eqs. (9)/(10)), ``D + 1`` uniform
           average over self and every neighbour whose message arrived (eq. (6); its index
           is the stalest contributor's + 1, omega if any contributor has omega)
``a[M]``   transmit at the **next** step (1) or stay silent (0); costs ``message_cost``
=========  ================================================================================

Timing: messages received at step ``k`` are those of neighbours whose transmit bit was set
by their action at ``k - 1`` (the scenario's ``initial_transmit`` at ``k = 0``), so a
policy sees, before acting, exactly which slots hold a message. The source's entry for its
own substate must be 0: update (7) is not an action.

Action mask: a flat int8 vector of length ``M (D + 2) + 2`` (the concatenation of one
mask per ``MultiDiscrete`` entry, the layout sb3-contrib's ``MaskablePPO`` and TorchRL's
``MultiCategorical`` use), in ``obs["action_mask"]`` (default) or
``infos[agent]["action_mask"]`` (``action_mask_in="info"``, plain ``Box`` observations for
SuperSuit/SB3). The action space is :class:`FlatMaskMultiDiscrete`, a ``MultiDiscrete``
whose ``sample(mask)`` also accepts this flat mask. Empty slots, slots whose neighbour did
not transmit (or whose message was dropped), and every non-zero choice on an agent's own
substate are masked.

Control modes
-------------
The scenario section ``[control]`` (override ``control={"mode": ...}``) chooses what the
actions decide (:mod:`netsense.engine.control`, ``docs/communication.md``): ``"full"``
(default, the table above), ``"transmit"`` (``MultiDiscrete([2])``: transmit at the next
step or not) or ``"substates"`` (``MultiDiscrete([2] * M)``: which substates go into the next
message; a substate without an estimate is masked). In the two communication-only modes a
scripted fusion rule (``fusion = "freshness"``, ``"uniform"`` or ``"tree"``) does the
adoption on the data of step ``k`` before the bits are applied, through the same update:
with every bit set it is the full-control policy of that rule, bit for bit. A neighbour's
substate can be adopted only if the neighbour sent it. ``[channel] capacity = K``: when
more than ``K`` agents transmit at a step, every message of that step is lost.

Bad actions: out-of-range entries always raise ``ValueError``; masked entries raise
``ValueError`` by default (``invalid_actions="raise"``) or are replaced by 0 = keep
(``invalid_actions="keep"``, counted in ``infos[agent]["invalid_actions"]``). Actions are
validated before any state changes. Missing agents' actions raise ``ValueError``.

Observation Space
-----------------
A flat float32 vector (``obs_dim = 3 + r + n + 2M + 2D + 2DM``), with ``H`` the horizon:

==================  =========  ===========================================================
field               size       content
==================  =========  ===========================================================
``time``            1          ``k / H``
``y``               r          ``symlog(y_i[k])`` (0 when not arrived; padded to ``r_max``)
``y_arrived``       1          1 if the measurement arrived
``own_omega``       M          1 where ``tau_i^{(j)} = omega``
``own_age``         M          ``tau_i^{(j)} / H`` (0 for omega)
``z_dir``           n          ``z_hat_i / ||z_hat_i||`` (Lemma 1 coordinates; 0 if 0)
``z_lognorm``       1          ``log(1 + ||z_hat_i||)``
``slot_arrived``    D          1 if slot ``d`` holds a message at ``k``
``slot_id``         D          ``(l + 1) / N`` for the neighbour ``l`` in slot ``d`` (0: empty)
``slot_omega``      D x M      1 where the message's ``tau_l^{(j)} = omega`` (or no message)
``slot_age``        D x M      ``tau_l^{(j)} / H`` from the message (0 otherwise)
==================  =========  ===========================================================

``symlog(v) = sign(v) log(1 + |v|)``; all entries are clipped to ``[-1000, 1000]``. The
communication-only modes append ``news`` (M), ``silence``, ``channel_load``, ``collided``
and ``agent_id`` (:class:`netsense.engine.control.CommControl`; ``layout.comm_table()``),
then ``next_out`` (N, the agent's out-links in ``G[k+1]``) with ``[control] announce =
true`` and ``acks`` (N, delivery of its message of step ``k`` per out-link: 1 delivered,
-1 lost, 0 no link or not sent) with ``feedback = true``.
:attr:`NetSenseEnv.layout` (:class:`netsense.engine.model.ObsLayout`) gives the slices.

Rewards
-------
``r_i = -w_e((1 - w_t) e_i + w_t mean(e)) - c t_i - c_s s_i`` with ``e_i`` agent ``i``'s
estimation error normalised by ``max(||x||, floor)`` and clipped (see
:class:`netsense.engine.model.RewardConfig`), ``t_i`` its transmit bit and ``s_i`` the
substates with an estimate in its message (``c_s = 0`` unless a communication-only
scenario sets ``reward.substate_cost``).

Starting State
--------------
``x[0] ~ N(0, x0_std^2 I)``; every estimate is 0; ``tau_j^{(j)} = 0`` and omega elsewhere;
transmit flags ``initial_transmit``; ``G[0]`` is the graph process's first graph.

Episode End
-----------
Truncation after ``horizon`` steps. Termination when the scenario sets
``divergence_limit`` and some agent's normalised error exceeds it, or when the plant
state or an estimate stops being finite (numerical health, below). Then ``agents`` is
empty until :meth:`NetSenseEnv.reset`.

Numerical health: an unstable plant run long, or an estimate that blows up, reaches inf or
NaN; that never passes silently. By default (``nonfinite="terminate"``) the episode ends
at that step with ``terminated`` true for every agent, ``infos[agent]["nonfinite"] =
{"step": k, "what": w, "agent": i}`` (``w``: ``"state"`` (the plant state, ``i`` is
``None``), ``"estimate"`` (agent ``i``'s) or ``"error"`` (finite state and estimate whose
distance overflows); rewards stay finite by construction) and a
:class:`netsense.NumericalWarning` that says the same; ``nonfinite="raise"`` raises
:class:`netsense.NumericalError` from ``step`` instead (see ``docs/errors.md``).

Arguments
---------
``netsense.make(id, **overrides)`` or ``NetSenseEnv(model, ...)``:

* ``render_mode``: ``None``, ``"ansi"``, ``"rgb_array"`` or ``"human"``;
* ``invalid_actions``: ``"raise"`` (default) or ``"keep"``;
* ``action_mask_in``: ``"observation"`` (default) or ``"info"``;
* ``aoi_info``: ``False`` (default) or ``True`` to add the age-of-information field
  ``infos[agent]["aoi"]`` (see Infos; it costs ~30-60 us per step, so it is opt-in);
* ``nonfinite``: ``"terminate"`` (default) or ``"raise"`` (see Episode End);
* scenario overrides (``horizon=``, ``reward={"message_cost": 0.1}``, ...), see
  :func:`netsense.env.registry.make`.

Infos
-----
``infos[agent]``: ``error`` (normalised, clipped), ``transmitted`` (bool), plus
``action_mask`` with ``action_mask_in="info"`` and ``invalid_actions`` (count) in
``"keep"`` mode; ``faulty`` (bool) when the scenario has ``[[faults]]`` (crashed agents
and liars are faulty: their errors are left out of the team error and of their rewards);
``nonfinite`` at the step where the state or an estimate stopped being finite
(see Episode End).

Bad arguments (``reset(seed=-1)``, ``seed=1.5``, ``seed="abc"``, an action of the wrong
shape or value, unknown agents) raise ``ValueError`` naming the argument before anything
changes; the env keeps stepping exactly as before the call.

With ``aoi_info=True``, ``infos[agent]["aoi"]`` (also after :meth:`NetSenseEnv.reset`) holds the
agent's age of information over the steps ``0..k`` of the episode so far, exactly
:func:`netsense.graphs.aoi.aoi_stats` of its freshness-index history (the running form,
:class:`RunningAoI`, merges one ``aoi_stats`` call per step):

==================  ==========================================================
key                 content (arrays of length ``N``, entry ``j`` = substate ``j``)
==================  ==========================================================
``tau``             the current indices ``tau_i^{(j)}[k]`` (int, omega = ``-1``)
``mean``            time-average age over the steps with a finite index (NaN if none)
``peak``            average peak age: the age just before each refresh (NaN if none)
``max``             largest index so far (``-1`` while always omega)
``omega_fraction``  fraction of the steps spent at omega
==================  ==========================================================

Version History
---------------
* v0: initial release. Later additions keep every existing scenario's dynamics:
  ``[source_estimator]``, ``[[faults]]`` and multirate arrivals in scenario files, the
  ``faulty`` info with faults, the opt-in ``aoi`` info.
* The scenario key ``substates = "sources"`` (first used by ``large_n20_N100-v2``): actions,
  masks and observations over the M sources instead of all N agents; existing scenarios
  keep ``"all"`` and their spaces.
* The update rules run compiled (numba) since v0.1: every scenario keeps its graphs,
  noise, drops and decisions; estimates differ from earlier versions in the last bits
  (the products' summation order changed), and so do rewards (the norm and the team mean
  are summed in order since the reward pass was compiled).
* Numerical health: a member whose plant state or estimates stop
  being finite terminates with ``infos[agent]["nonfinite"]`` (before, it stepped on with
  clipped rewards and nothing flagged); bad arguments raise ``ValueError`` naming them.
* Control modes (``[control]``), the shared channel (``[channel]``) and
  ``reward.substate_cost``, first used by ``comm_process_noise-v0``, ``comm_substates-v0``
  and ``comm_channel_k2-v0``; every existing scenario keeps full control, its spaces and
  its realisations.
* ``[control] announce`` and ``feedback`` (observation fields ``next_out``, ``acks``),
  per-sender arrival channels (``scope = "sender"``) and a plant noise input ``W``, first
  used by ``comm_announced-v0``, ``comm_fading-v0`` and ``comm_schedule-v0`` (and
  ``comm_schedule-v1``); off by
  default, every existing scenario keeps its spaces and realisations.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from netsense.engine.core import BatchedCore, CoreModel
from netsense.graphs.aoi import aoi_stats
from netsense.kernels import checks

RENDER_MODES = ("ansi", "rgb_array", "human")
MASK_LOCATIONS = ("observation", "info")


class FlatMaskMultiDiscrete(spaces.MultiDiscrete):
    """``MultiDiscrete`` whose ``sample(mask)`` also takes one flat concatenated mask.

    Gymnasium's ``MultiDiscrete.sample`` wants a tuple with one mask per entry; the RL
    libraries (sb3-contrib, TorchRL) and this environment use the flat concatenation of
    length ``sum(nvec)``. Both forms are accepted here.
    """

    def sample(self, mask=None, probability=None):
        if isinstance(mask, np.ndarray) and mask.ndim == 1 and self.nvec.ndim == 1:
            if mask.shape[0] != int(self.nvec.sum()):
                raise ValueError(f"flat mask must have length {int(self.nvec.sum())}, "
                                 f"got {mask.shape[0]}")
            mask = tuple(np.split(mask.astype(np.int8), np.cumsum(self.nvec)[:-1]))
        return super().sample(mask=mask, probability=probability)


class RunningAoI:
    """Running :func:`netsense.graphs.aoi.aoi_stats` of one index sequence ``tau[0..k]``.

    Every per-step quantity comes from one ``aoi_stats`` call on the last two index
    arrays (window ``[tau[k-1], tau[k]]`` for the refresh/peak rule, window ``[tau[k],
    tau[k]]`` for the current age and omega flag); the running result merges their sums
    and counts, so :meth:`stats` equals ``aoi_stats(tau[0..k])`` up to summation order,
    at ``O(N^2)`` cost per step instead of ``O(k N^2)``.

    Parameters
    ----------
    tau0 : (N, N) int array
        Indices at ``k = 0`` (``OMEGA = -1``).
    """

    def __init__(self, tau0: np.ndarray) -> None:
        self.prev = np.array(tau0)
        zero = np.zeros(self.prev.shape)
        self.steps, self.finite, self.total = 0, zero.copy(), zero.copy()
        self.peaks, self.peak_total = zero.copy(), zero.copy()
        self.max = np.full(self.prev.shape, -np.inf)
        self._add(self.prev, None)

    def _add(self, tau: np.ndarray, peak: np.ndarray | None) -> None:
        cur = aoi_stats(np.stack([tau, tau])[:, None])  # window of the current step only
        fin = 1.0 - cur["omega_fraction"][0]
        self.steps += 1
        self.finite += fin
        self.total += np.where(fin > 0, cur["mean"][0], 0.0)
        self.max = np.maximum(self.max, cur["max"][0])
        if peak is not None:
            hit = ~np.isnan(peak)
            self.peaks += hit
            self.peak_total += np.where(hit, peak, 0.0)

    def update(self, tau: np.ndarray) -> None:
        """Append ``tau[k]``."""
        tau = np.array(tau)
        pair = aoi_stats(np.stack([self.prev, tau])[:, None])  # refresh at this step?
        self._add(tau, pair["peak"][0])
        self.prev = tau

    def stats(self) -> dict[str, np.ndarray]:
        """``mean``, ``peak``, ``max`` and ``omega_fraction`` as ``aoi_stats`` gives them
        for ``tau[0..k]`` (``(N, N)`` arrays)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return {"mean": np.where(self.finite > 0, self.total / self.finite, np.nan),
                    "peak": np.where(self.peaks > 0, self.peak_total / self.peaks, np.nan),
                    "max": self.max.copy(),
                    "omega_fraction": 1.0 - self.finite / self.steps}


class NetSenseEnv(ParallelEnv):
    """PettingZoo parallel environment; see the module docstring for the full doc page.

    Parameters
    ----------
    model : CoreModel
        Scenario dynamics (usually built by :func:`netsense.make`).
    scenario_id : str, optional
        Name reported in ``metadata`` and renders.
    render_mode : {None, "ansi", "rgb_array", "human"}
    invalid_actions : {"raise", "keep"}
    action_mask_in : {"observation", "info"}
    aoi_info : bool
        Add ``infos[agent]["aoi"]`` (age-of-information statistics, see the module doc).
    nonfinite : {"terminate", "raise"}
        Behaviour when the state or an estimate becomes non-finite (module doc).
    """

    metadata = {"name": "netsense_v0", "render_modes": list(RENDER_MODES),
                "is_parallelizable": True, "render_fps": 4}

    def __init__(self, model: CoreModel, *, scenario_id: str = "custom",
                 render_mode: str | None = None, invalid_actions: str = "raise",
                 action_mask_in: str = "observation", aoi_info: bool = False,
                 nonfinite: str = "terminate") -> None:
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be None or one of {RENDER_MODES}, "
                             f"got {render_mode!r}")
        if action_mask_in not in MASK_LOCATIONS:
            raise ValueError(f"action_mask_in must be one of {MASK_LOCATIONS}, "
                             f"got {action_mask_in!r}")
        if not isinstance(aoi_info, bool):
            raise ValueError(f"aoi_info must be True or False, got {aoi_info!r}")
        if not isinstance(scenario_id, str):
            raise ValueError(f"scenario_id must be a str, got {type(scenario_id).__name__}")
        self.core = BatchedCore(model, 1, invalid_actions=invalid_actions, nonfinite=nonfinite)
        self.aoi_info = aoi_info
        self._aoi: RunningAoI | None = None
        self.model = model
        self.scenario_id = scenario_id
        self.render_mode = render_mode
        self.action_mask_in = action_mask_in
        self.metadata = dict(self.metadata, name=f"netsense/{scenario_id}")
        c = self.core
        self.layout = c.layout
        self.possible_agents = [f"sensor_{i}" for i in range(c.N)]
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        box = spaces.Box(low=-1e3, high=1e3, shape=(c.layout.size,), dtype=np.float32)
        mask = spaces.MultiBinary(c.mask_size)
        self._obs_space = (spaces.Dict({"observation": box, "action_mask": mask})
                           if action_mask_in == "observation" else box)
        self._act_space = FlatMaskMultiDiscrete(c.nvec)
        self._state_space: spaces.Box | None = None  # built on first use (state_space)
        self._seed_rng: np.random.Generator | None = None
        self._renderer = None
        self.history: list[np.ndarray] = []

    # ------------------------------------------------------------------ spaces
    @property
    def state_space(self) -> spaces.Box:
        """The space of :meth:`state`: ``n + N n + N^2`` unbounded float64 entries.

        Built on first use and cached: gymnasium's ``Box`` holds four arrays of that
        length (18 MB at ``N = 1,000``, most of an env's memory there), which stepping
        never reads.
        """
        if getattr(self, "_state_space", None) is None:
            c = self.core
            self._state_space = spaces.Box(low=-np.inf, high=np.inf,
                                           shape=(c.n + c.N * c.n + c.N * c.N,),
                                           dtype=np.float64)
        return self._state_space

    def observation_space(self, agent: str) -> gymnasium.Space:
        """The same (cached) space object for every agent."""
        self._check_agent(agent)
        return self._obs_space

    def action_space(self, agent: str) -> gymnasium.Space:
        """The same (cached) space object for every agent."""
        self._check_agent(agent)
        return self._act_space

    def _check_agent(self, agent: str) -> None:
        if agent not in self._index:
            raise ValueError(f"unknown agent {agent!r}; agents are sensor_0..sensor_"
                             f"{len(self.possible_agents) - 1}")

    # ------------------------------------------------------------------ API
    def reset(self, seed: int | None = None, options: dict | None = None
              ) -> tuple[dict[str, Any], dict[str, dict]]:
        """Start an episode; ``seed`` makes it reproducible (``options`` is unused).

        ``seed``: an integer ``>= 0`` or None (checked before anything changes).
        """
        if seed is not None:
            seed = checks.seed_value("seed", seed)
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"options must be a dict or None, got {type(options).__name__}")
        if seed is not None:
            self._seed_rng = np.random.default_rng(seed)
            core_seed = int(seed)
        else:
            if self._seed_rng is None:
                self._seed_rng = np.random.default_rng()
            core_seed = int(self._seed_rng.integers(2**62))
        obs, mask = self.core.reset(core_seed)
        self.agents = list(self.possible_agents)
        self.history = []
        o, infos = self._package(obs[0], mask[0])
        if self.aoi_info:
            self._aoi = RunningAoI(self.core.tau[0])
            self._add_aoi(infos)
        return o, infos

    def _add_aoi(self, infos: dict[str, dict]) -> None:
        tau = self.core.tau[0]
        st = self._aoi.stats()
        for i, a in enumerate(self.possible_agents):
            infos[a]["aoi"] = {"tau": tau[i].copy(), "mean": st["mean"][i],
                               "peak": st["peak"][i], "max": st["max"][i].astype(np.int64),
                               "omega_fraction": st["omega_fraction"][i]}

    def _package(self, obs: np.ndarray, mask: np.ndarray, extra: dict | None = None):
        agents = self.possible_agents
        if self.action_mask_in == "observation":
            o = {a: {"observation": obs[i], "action_mask": mask[i]}
                 for i, a in enumerate(agents)}
        else:
            o = dict(zip(agents, obs, strict=True))
        if extra is None:
            infos = {a: {} for a in agents}
        else:
            inv = extra.get("invalid")
            infos = {a: {"error": e, "transmitted": t} for a, e, t in
                     zip(agents, extra["error"], extra["transmitted"], strict=True)}
            if inv is not None:
                for a, v in zip(agents, inv, strict=True):
                    infos[a]["invalid_actions"] = v
            if self.model.faults:
                for a, ok in zip(agents, self.core.alive.tolist(), strict=True):
                    infos[a]["faulty"] = not ok
            if extra.get("nonfinite") is not None:
                for a in agents:
                    infos[a]["nonfinite"] = dict(extra["nonfinite"])
        if self.action_mask_in == "info":
            for i, a in enumerate(agents):
                infos[a]["action_mask"] = mask[i]
        return o, infos

    def actions_to_array(self, actions: dict[str, Any]) -> np.ndarray:
        """Stack an ``{agent: action}`` dict into the core's ``(1, N, len(nvec))`` array."""
        if not isinstance(actions, dict):
            raise ValueError(f"actions must be a dict {{agent: action}}, got "
                             f"{type(actions).__name__}")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"actions are missing for agents {missing[:5]}")
        extra = [a for a in actions if a not in self._index]
        if extra:
            raise ValueError(f"actions given for unknown agents {extra[:5]}")
        width = self.core.nvec.size  # M + 1 (full control), 1 or M (communication only)
        try:
            arr = np.asarray([actions[a] for a in self.possible_agents])
        except ValueError as exc:
            raise ValueError(f"every action must be a vector of {width} "
                             f"integers: {exc}") from exc
        if arr.ndim == 1 and width == 1:  # Discrete-like scalars of MultiDiscrete([2])
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[1] != width:
            raise ValueError(f"every action must be a vector of {width} integers "
                             f"(MultiDiscrete {list(self.core.nvec)}), got shape "
                             f"{arr.shape[1:]}")
        return arr[None]

    def step(self, actions: dict[str, Any]):
        """One step for every agent; returns observations, rewards, terminations,
        truncations and infos (dicts keyed by agent)."""
        if not self.agents:
            raise ValueError("step() called on a finished episode; call reset() first")
        arr = self.actions_to_array(actions)
        out = self.core.step(arr)
        agents = self.possible_agents
        extra = {"error": self.core.errors[0].tolist(),
                 "transmitted": self.core.transmit[0].tolist()}
        if self.core.invalid_actions == "keep":
            extra["invalid"] = self.core.last_invalid[0].sum(1).tolist()
        if out.terminated[0] and self.core.nonfinite[0] is not None:
            extra["nonfinite"] = self.core.nonfinite[0]
        obs, infos = self._package(out.obs[0], out.action_mask[0], extra)
        if self.aoi_info:
            self._aoi.update(self.core.tau[0])
            self._add_aoi(infos)
        rewards = dict(zip(agents, out.reward[0].tolist(), strict=True))
        term, trunc = bool(out.terminated[0]), bool(out.truncated[0])
        terminations = dict.fromkeys(agents, term)
        truncations = dict.fromkeys(agents, trunc)
        if self.render_mode is not None:
            self.history.append(self.core.errors[0].copy())
        if term or trunc:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return obs, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """Global state: ``x``, every agent's estimate of ``x`` (row-major), ``G[k]``."""
        if not self.core._seeded:
            raise ValueError("state() before reset()")
        return self.core.state_vector()[0]

    # ------------------------------------------------------------------ render
    def render(self):
        """``ansi``: a text table; ``rgb_array``: an image; ``human``: a window."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode")
            return None
        from netsense.env import render as _render

        if self.render_mode == "ansi":
            return _render.ansi_table(self)
        if self._renderer is None:
            self._renderer = _render.FigureRenderer()
        img = self._renderer.draw(self)
        if self.render_mode == "rgb_array":
            return img
        self._renderer.show()
        return None

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __getstate__(self):
        d = self.__dict__.copy()
        d["_renderer"] = None
        return d
