"""Scripted policies that act only through observations and action masks.

Each policy maps batched arrays ``obs (B, N, obs_dim)`` and ``mask (B, N, M)`` (as
:class:`netsense.envcore.BatchedCore` returns them) to actions ``(B, N, M + 1)``; for the
PettingZoo environment, :meth:`Policy.act_dict` takes and returns ``{agent: ...}`` dicts.
Decoding uses the documented observation layout (:class:`netsense.coremodel.ObsLayout`).

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
                        applies to :class:`netsense.graphs.PeriodicGraphs` scenarios only
``open_loop``           keep every estimate (eq. (12)); never transmit
``random``              uniformly random among the unmasked choices; transmit w.p. ``p_transmit``
======================  =====================================================================
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netsense import drivers
from netsense.coremodel import ObsLayout


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
        """Actions ``{agent: action}`` for a :class:`netsense.env.NetSenseEnv` step."""
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
        # one compiled pass: the rule of netsense.rules.freshness_row, with the indices
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


class TreeConsensusPolicy(Policy):
    """Consensus with all weight on the BFS-tree parent (Fig. 2), for periodic graphs.

    The policy knows the scenario's periodic graph schedule (a design-time input, like
    the gains) and reads the time index from the observation; it adopts from the parent's
    slot when that slot's message arrived and keeps its own estimate otherwise.
    """

    name = "tree"

    def __init__(self, layout: ObsLayout, graphs, horizon: int) -> None:
        super().__init__(layout)
        from netsense.graphs import PeriodicGraphs, in_neighbor_slots
        from netsense.observers.consensus import tree_parents

        if not isinstance(graphs, PeriodicGraphs):
            raise ValueError("the tree policy needs a PeriodicGraphs scenario (it uses the "
                             f"graph schedule), got {type(graphs).__name__}")
        adj = np.stack(graphs.graphs)  # (P, N, N)
        nbr, valid = in_neighbor_slots(adj, self.D)
        parent = tree_parents(adj, nbr, valid)  # (P, i, j)
        # slot of the parent in i's slot list (-1: keep own)
        hit = nbr[:, :, None, :] == parent[..., None]  # (P, i, j, D)
        choice = np.where(hit.any(-1), np.argmax(hit, -1) + 1, 0)  # (P, N, N)
        self.choice = choice[:, :, list(layout.sources)]  # (P, N, M)
        self.horizon = int(horizon)
        self.period = adj.shape[0]

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
        (used by :func:`netsense.vector.rollout_seeds`).
    p_transmit : float
        Probability of transmitting, per agent and step.
    """

    name = "random"

    def __init__(self, layout: ObsLayout, seed: int | Sequence[int] | None = None,
                 p_transmit: float = 0.5) -> None:
        super().__init__(layout)
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
    """A scripted policy for ``env`` (a :class:`netsense.env.NetSenseEnv` or a
    :class:`netsense.envcore.BatchedCore`) by name, one of :data:`POLICIES`."""
    core = getattr(env, "core", env)
    layout = core.layout
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
