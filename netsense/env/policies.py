"""Scripted policies that act only through observations and action masks.

Each policy maps batched arrays ``obs (B, N, obs_dim)`` and ``mask (B, N, M)`` (as
:class:`netsense.engine.core.BatchedCore` returns them) to actions ``(B, N, M + 1)``; for the
PettingZoo environment, :meth:`Policy.act_dict` takes and returns ``{agent: ...}`` dicts.
Decoding uses the documented observation layout (:class:`netsense.engine.model.ObsLayout`).

======================  =====================================================================
policy                  rule
======================  =====================================================================
``freshness``           eqs. (8)-(14): per substate adopt the freshest slot whose message
                        arrived if it is strictly fresher than the own index (or the own is
                        omega); ties to the smallest slot (= smallest node id); transmit always
``uniform``             eq. (6) with uniform weights: average every non-own substate over self
                        and the arrived messages; transmit always
``tree``                eq. (6) with all weight on the parent in the BFS tree of ``G[k]``
                        rooted at the source (Fig. 2); needs the periodic graph schedule, so it
                        applies to :class:`netsense.graphs.processes.PeriodicGraphs` scenarios only
``open_loop``           keep every estimate (eq. (12)); never transmit
``random``              uniformly random among the unmasked choices; transmit w.p. ``p_transmit``
======================  =====================================================================

In the communication-only control modes (:mod:`netsense.engine.control`) the actions are
transmit bits ``(B, N, W)`` (``W = 1``, or ``M`` per-substate bits) and the scenario's
fusion rule adopts. There :func:`make_policy` gives, for the fusion rule's own name
(``freshness`` by default), :class:`TransmitAll` (so the policy reproduces its
full-control self exactly), for ``open_loop`` :class:`TransmitNone`, and for ``random``
bits that are 1 with probability ``p_transmit`` where allowed; the other adoption rules
do not apply. The communication baselines with a knob (periodic, Bernoulli, sources
first, event-triggered, age-based scheduler) are in :mod:`netsense.env.comm_policies`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netsense.engine.model import ObsLayout
from netsense.kernels import drivers


class Policy:
    """Base class: ``act(obs, mask) -> actions`` on batched arrays."""

    name = "policy"

    def __init__(self, layout: ObsLayout) -> None:
        self.layout = layout
        self.N, self.D, self.M = layout.N, layout.D, layout.M
        self.own = layout.own  # column of each agent's own substate (-1: none)

    def act(self, obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Actions ``(B, N, M + 1)`` for observations ``(B, N, obs_dim)``."""
        raise NotImplementedError  # pragma: no cover

    def act_dict(self, env, observations: dict, infos: dict | None = None) -> dict:
        """Actions ``{agent: action}`` for a :class:`~netsense.env.NetSenseEnv` step."""
        agents = env.possible_agents
        if env.action_mask_in == "observation":
            obs = np.stack([observations[a]["observation"] for a in agents])
            mask = np.stack([observations[a]["action_mask"] for a in agents])
        else:
            obs = np.stack([observations[a] for a in agents])
            mask = np.stack([infos[a]["action_mask"] for a in agents])
        act = self.act(obs[None], mask[None])[0]
        return {a: act[i] for i, a in enumerate(agents) if a in env.agents}

    def _base(self, obs: np.ndarray, transmit: int) -> np.ndarray:
        B, N = obs.shape[:2]
        out = np.zeros((B, N, self.M + 1), dtype=np.int64)
        out[..., self.M] = transmit
        return out

    def _keep_own(self, out: np.ndarray) -> np.ndarray:
        """Set every source's entry for its own substate to 0 (keep)."""
        src = np.flatnonzero(self.own >= 0)
        out[:, src, self.own[src]] = 0
        return out


class FreshnessPolicy(Policy):
    """The freshness-index rule, eqs. (8)-(14), read from observations."""

    name = "freshness"

    def act(self, obs, mask):
        # one compiled pass: the rule of netsense.kernels.rules.freshness_row, with the indices
        # read from the observation (omega flags and ages, slot_arrived)
        L, M = self.layout, self.M
        obs = np.asarray(obs)
        if obs.ndim != 3 or obs.shape[1:] != (self.N, L.size) or obs.dtype.kind != "f":
            raise ValueError(f"obs must be a float array of shape (B, {self.N}, {L.size}), "
                             f"got {obs.dtype} {obs.shape}")
        B, N = obs.shape[:2]
        out = np.empty((B, N, M + 1), dtype=np.int64)
        drivers.freshness_obs_all.at(obs.size, runs=B)(
            obs, L.own_omega.start, L.own_age.start, L.slot_arrived.start,
            L.slot_omega.start, L.slot_age.start, np.empty((B, self.D + 1, M)), out)
        return out


class UniformConsensusPolicy(Policy):
    """Uniform-weight consensus, eq. (6): average every substate but the own one."""

    name = "uniform"

    def act(self, obs, mask):
        out = self._base(obs, 1)
        out[..., :self.M] = self.D + 1
        return self._keep_own(out)


class CommPolicy(Policy):
    """Base of the communication-only policies: ``act`` returns bits ``(B, N, width)``.

    ``width`` is 1 (control mode ``"transmit"``) or ``M`` (``"substates"``); ``horizon``
    turns the observation's ``time``, ``news`` and ``silence`` back into steps.
    """

    def __init__(self, layout: ObsLayout, width: int, horizon: int) -> None:
        super().__init__(layout)
        if layout.news is None:
            raise ValueError("communication policies need a communication-only control mode "
                             "(scenario [control] mode = 'transmit' or 'substates')")
        self.width = int(width)
        self.horizon = int(horizon)

    def _send(self, mask: np.ndarray, send: np.ndarray) -> np.ndarray:
        """Bits sending every allowed substate (or the one transmit bit) where ``send``
        ``(B, N)`` or ``(B, N, width)`` is true."""
        allowed = np.asarray(mask)[..., 1::2] > 0
        if send.ndim == 2:
            send = send[..., None]
        return (send & allowed).astype(np.int64)

    def steps(self, obs: np.ndarray) -> np.ndarray:
        """``(B,)`` time index ``k`` read from the observation."""
        return np.rint(obs[:, 0, self.layout.time.start] * self.horizon).astype(np.int64)


class TransmitAll(CommPolicy):
    """Send everything allowed at every step (the fusion rule's full-control policy)."""

    name = "always"

    def act(self, obs, mask):
        return self._send(mask, np.ones(np.shape(obs)[:2], bool))


class TransmitNone(CommPolicy):
    """Never transmit."""

    name = "never"

    def act(self, obs, mask):
        return np.zeros(np.shape(obs)[:2] + (self.width,), dtype=np.int64)


class TreeConsensusPolicy(Policy):
    """Consensus with all weight on the BFS-tree parent (Fig. 2), for periodic graphs.

    The policy knows the scenario's periodic graph schedule (a design-time input, like
    the gains) and reads the time index from the observation; it adopts from the parent's
    slot when that slot's message arrived and keeps its own estimate otherwise.
    """

    name = "tree"

    def __init__(self, layout: ObsLayout, graphs, horizon: int) -> None:
        super().__init__(layout)
        from netsense.engine.control import tree_choice_table

        # (P, N, M): parent's slot + 1 in i's slot list (0: keep own); the table of the
        # tree fusion rule of the communication-only modes too
        self.choice = tree_choice_table(graphs, self.D, layout.sources)
        self.horizon = int(horizon)
        self.period = self.choice.shape[0]

    def act(self, obs, mask):
        L, D, M = self.layout, self.D, self.M
        out = self._base(obs, 1)
        k = np.rint(obs[:, 0, L.time.start] * self.horizon).astype(np.int64)
        choice = self.choice[k % self.period]  # (B, N, M)
        arrived = obs[..., L.slot_arrived] > 0.5
        ok = np.concatenate([np.ones(arrived.shape[:2] + (1,), bool), arrived], axis=2)
        usable = np.take_along_axis(ok, np.minimum(choice, D), axis=2)
        out[..., :M] = np.where(usable, choice, 0)
        return self._keep_own(out)


class OpenLoopPolicy(Policy):
    """Keep every estimate (eq. (12)) and never transmit."""

    name = "open_loop"

    def act(self, obs, mask):
        return self._base(obs, 0)


class RandomPolicy(Policy):
    """Uniformly random unmasked choices; transmit with probability ``p_transmit``.

    Parameters
    ----------
    layout : ObsLayout
    seed : int, sequence of int, or None
        An int (or None) seeds one generator shared by the whole batch. A sequence of
        ``B`` seeds gives batch member ``b`` its own generator ``default_rng(seed[b])``,
        from which it draws exactly what a ``B = 1`` policy with ``seed=seed[b]`` draws
        on the same observations; so a batch of seeds reproduces the single episodes
        (used by :func:`netsense.benchmark.batched.rollout_seeds`).
    p_transmit : float
        Probability of transmitting, per agent and step.
    """

    name = "random"

    def __init__(self, layout: ObsLayout, seed: int | Sequence[int] | None = None,
                 p_transmit: float = 0.5, comm_width: int | None = None) -> None:
        super().__init__(layout)
        #: bits per agent in a communication-only mode (None: full control)
        self.comm_width = comm_width
        p = float(p_transmit)
        if not 0.0 <= p <= 1.0:  # (nan fails too)
            raise ValueError(f"p_transmit must be a probability in [0, 1], got {p_transmit!r}")
        if seed is None or np.ndim(seed) == 0:
            self.rng = np.random.default_rng(None if seed is None else _seed(seed))
            self.member_rngs = None
        else:
            seeds = [_seed(s) for s in seed]
            if not seeds:
                raise ValueError("seed must be an int, None or a non-empty sequence of ints")
            self.rng = None
            self.member_rngs = [np.random.default_rng(s) for s in seeds]
        self.p_transmit = p

    def act(self, obs, mask):
        N, D, M = self.N, self.D, self.M
        B = obs.shape[0]
        if self.comm_width is not None:
            return self._act_bits(B, mask)
        m = mask[..., : M * (D + 2)].reshape(B, N, M, D + 2).astype(float)
        if self.member_rngs is None:
            u = self.rng.random(m.shape)
            t = self.rng.random((B, N))
        else:
            if B != len(self.member_rngs):
                raise ValueError(f"this random policy has {len(self.member_rngs)} member "
                                 f"generators, got a batch of {B} observations")
            # per member, the draws of a B = 1 policy: its choices, then its transmit bits
            draws = [(g.random(m.shape[1:]), g.random(N)) for g in self.member_rngs]
            u = np.stack([d[0] for d in draws])
            t = np.stack([d[1] for d in draws])
        u *= m  # masked choices score 0, allowed ones > 0
        out = self._base(obs, 0)
        out[..., :M] = np.argmax(u, axis=-1)
        out[..., M] = t < self.p_transmit
        return out

    def _act_bits(self, B: int, mask: np.ndarray) -> np.ndarray:
        """Communication-only modes: each allowed bit is 1 with probability p_transmit."""
        shape = (self.N, self.comm_width)
        if self.member_rngs is None:
            u = self.rng.random((B,) + shape)
        else:
            if B != len(self.member_rngs):
                raise ValueError(f"this random policy has {len(self.member_rngs)} member "
                                 f"generators, got a batch of {B} observations")
            u = np.stack([g.random(shape) for g in self.member_rngs])
        return ((u < self.p_transmit) & (np.asarray(mask)[..., 1::2] > 0)).astype(np.int64)


def _seed(s) -> int:
    """``s`` as a non-negative int seed; a float, bool or negative seed is an error (a
    float seed is never truncated into some other episode's seed)."""
    if isinstance(s, (bool, np.bool_)) or not isinstance(s, (int, np.integer)):
        raise ValueError(f"seeds must be non-negative integers, got {s!r}")
    if s < 0:
        raise ValueError(f"seeds must be non-negative integers, got {s}")
    return int(s)


POLICIES = ("freshness", "uniform", "tree", "open_loop", "random")


def make_policy(name: str, env, **kwargs) -> Policy:
    """A scripted policy for ``env`` (a :class:`netsense.env.pettingzoo_env.NetSenseEnv` or a
    :class:`netsense.engine.core.BatchedCore`) by name, one of :data:`POLICIES`."""
    core = getattr(env, "core", env)
    layout = core.layout
    comm = getattr(core, "comm", None)
    if comm is not None and name in POLICIES:  # communication only: the fusion rule adopts
        if name == "random":
            return RandomPolicy(layout, comm_width=comm.width, **kwargs)
        if name == "open_loop":
            return TransmitNone(layout, comm.width, core.horizon)
        if name == core.control.fusion:
            return TransmitAll(layout, comm.width, core.horizon)
        raise ValueError(f"policy {name!r} adopts by its own rule, but this scenario is "
                         f"communication-only (control.mode = {core.control.mode!r}) with "
                         f"fusion {core.control.fusion!r}: use {core.control.fusion!r} "
                         "(= transmit always), open_loop, random or a communication "
                         "baseline of netsense.env.comm_policies")
    if name == "freshness":
        return FreshnessPolicy(layout)
    if name == "uniform":
        return UniformConsensusPolicy(layout)
    if name == "tree":
        return TreeConsensusPolicy(layout, core.model.graphs, core.horizon)
    if name == "open_loop":
        return OpenLoopPolicy(layout)
    if name == "random":
        return RandomPolicy(layout, **kwargs)
    raise ValueError(f"unknown policy {name!r}; choose one of {POLICIES}")


#: Scripted policies run through the environment.
SCRIPTED_POLICIES = ("freshness", "uniform_consensus", "tree_consensus", "open_loop", "random")
