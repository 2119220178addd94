"""Full-information reference schedulers of the communication tasks: centralised lookahead.

Two reference schedulers, **not deployable policies**: they read the whole state of the
simulation (plant, every estimate and index, the current graph) and simulate the future on
forked copies of the evaluated core (:func:`netsense.engine.fork.fork`; there is no second
simulator). Their returns are *achieved*: they say what is reachable with full
information, not what is possible (they are no upper bounds; a policy may beat them).
Their policy names are ``reference:causal`` and ``reference:clairvoyant`` (family and kind
``reference`` in the frontier; labelled "full-information reference (causal)" and
"(clairvoyant)").

Receding-horizon lookahead (a rollout algorithm in the sense of Bertsekas, *Rollout,
Policy Iteration, and Distributed Reinforcement Learning*, 2020, ch. 2). At every step
``k`` and for every member, each candidate bit pattern ``c`` for step ``k`` (the
communication bits of the control mode: one per agent in ``transmit`` mode, one per agent
and substate in ``substates`` mode) is scored by

.. math::

    Q(c) = \\frac{1}{F} \\sum_{f=1}^{F} \\sum_{j=0}^{h-1} \\bar r_{k+j}^{(f)}(c),

the return (reward per step averaged over agents, as the protocol's ``reward``) of
``h`` steps on a fork whose lane applies ``c`` at ``k`` and a continuation policy ``p_c``
at ``k + 1 .. k + h - 1``, over ``F`` futures; the evaluated core takes the best
candidate: with one future ``argmax_c Q(c)`` (ties: the earliest candidate, the base
policy's own action first); with ``F > 1`` the candidate of the largest lower confidence
confidence bound ``mean_f d_f(c) - z sd_f(d(c)) / sqrt(F)`` of its paired gain ``d_f(c) = Q_f(c) -
Q_f(c_0)`` over the base action ``c_0``, and ``c_0`` when none is positive (the
futures are shared by all candidates, common random numbers, and the maximum of many
noisy estimates is biased upwards). By default no terminal value is added (a truncated
rollout); steps past the episode end count nothing.

* ``reference:causal`` -- the futures are **resampled** from the state at ``k``
  (``future="resampled"`` forks: the plant state, estimates, indices, ``G[k]``, ``y[k]``
  and the messages of ``k`` are known; the noise of ``k -> k + 1``, ``G[k+1]`` and
  everything later are redrawn, see :mod:`netsense.engine.fork`). It never reads the
  realised future: the best a centralised scheduler that knows the present exactly could
  do, up to the search.
* ``reference:clairvoyant`` -- the one **realised** future (``F = 1``): the lookahead knows
  the future noise and graphs (who will receive a message sent now). Above anything causal
  in general (it knows what no causal scheduler can).

Search (:class:`LookaheadConfig`):

* candidates ``"flips"`` (default): the action of every continuation policy (paired with
  that policy as its continuation), then, paired with the first continuation (the base):
  every allowed bit on, every bit off, and the base action with one bit flipped (one per
  agent in ``transmit`` mode; one per agent and substate, plus each agent's whole row on
  or off, in ``substates`` mode), and on a shared channel (``[channel]``) every swap of
  one of the base's senders for a silent agent (who talks matters more than how many
  there); duplicates are dropped per member. With ``rounds = 2`` (default) a second fork,
  on the same futures, scores the base action with *every* single flip that gained
  (past the margin below) applied at once against the first round's choice: one step of
  greedy coordinate improvement, so that several agents can change at once (e.g. every
  agent without a receiver falls silent). ``"exhaustive"``:
  every pattern of allowed bits (``2^(N W)``) at each of the first ``depth`` steps (for
  small tasks and the tests), then the base.
* continuation: scripted communication policies of :mod:`netsense.env.comm_policies` (any
  family, decentralised or centralised: the reference is centralised anyway) that act on the
  current observation only; ``bernoulli`` (random) is refused. With the realised future,
  a horizon reaching the episode end and each continuation's own action among the
  candidates, the lookahead's return is at least every continuation policy's, episode by
  episode (sequential improvement of rollout with several base heuristics; tested).
* futures: member ``b``'s future ``f`` at step ``k`` is drawn from
  ``SeedSequence([seed, s_b, k, f])`` with ``s_b`` the member's evaluation seed, so a
  reference's result depends on (configuration, evaluation seeds) only.

Cost: one fork per decision step holding every member x candidate x future as a lane,
stepped ``h`` times: ``sum_b C_b F h`` core lane-steps per step of the evaluated core
(plus ``2 F h`` per member that has a combination to try in the second round;
:attr:`LookaheadReference.lane_steps`). ``docs/communication.md`` gives the measured figures.
The settings are :class:`~netsense.benchmark.lookahead_config.LookaheadConfig`
(:mod:`netsense.benchmark.lookahead_config`).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Sequence

import numpy as np

from netsense.benchmark.lookahead_config import (
    CANDIDATES,
    MAX_EXHAUSTIVE,
    REFERENCE_KINDS,
    LookaheadConfig,
    parse_reference,
)
from netsense.kernels import checks

__all__ = ["CANDIDATES", "REFERENCE_KINDS", "LookaheadConfig", "LookaheadReference",
           "parse_reference"]


class LookaheadReference:
    """The lookahead as a policy of the core it evaluates.

    Parameters
    ----------
    core : BatchedCore
        The evaluated core (a communication-only mode; built with ``chunk=1`` for
        ``causal``), stepped by the caller with the bits :meth:`act` returns.
    config : LookaheadConfig
    seeds : sequence of int
        The evaluation seed of every member (seeds the futures).

    Attributes
    ----------
    lane_steps : int
        Core lane-steps spent so far (forked lanes x steps).
    decisions : int
        Decision steps taken.
    seconds : float
        Wall time spent deciding.
    scores : list of (F, C_b) arrays
        The returns of the last decision, per member, future and candidate (in the order
        of :meth:`candidates`).
    """

    def __init__(self, core, config: LookaheadConfig, seeds: Sequence[int]) -> None:
        from netsense.env.comm_policies import make_comm_policy

        if core.comm is None:
            raise ValueError("the references act in a communication-only control mode "
                             "(scenario [control] mode = 'transmit' or 'substates')")
        if not isinstance(config, LookaheadConfig):
            raise TypeError(f"config must be a LookaheadConfig, got {type(config).__name__}")
        seeds = [checks.seed_value(f"seeds[{b}]", s) for b, s in enumerate(seeds)]
        if len(seeds) != core.B:
            raise ValueError(f"seeds must hold one evaluation seed per member ({core.B}), "
                             f"got {len(seeds)}")
        if config.kind == "causal" and core.chunk != 1:
            raise ValueError("reference:causal forks with resampled futures: build the evaluated "
                             "core with chunk=1")
        self.core, self.config, self.seeds = core, config, seeds
        #: graphs after G[k] known at k: the configuration's, or the scenario's own
        #: (a model attribute ``known_ahead``: a schedule announced ahead)
        self.known_ahead = max(config.known_ahead, int(getattr(core.model, "known_ahead", 0)))
        self.width = core.comm.width
        self.policies = [make_comm_policy(s, core) for s in config.continuation]
        if config.candidates == "exhaustive":
            bits = core.N * self.width
            if 2 ** (bits * config.depth) > MAX_EXHAUSTIVE:
                raise ValueError(f"candidates='exhaustive' enumerates 2^(N W depth) = "
                                 f"2^{bits * config.depth} sequences; at most "
                                 f"{MAX_EXHAUSTIVE}")
        self.lane_steps = 0
        self.decisions = 0
        self.seconds = 0.0
        self.scores: list[np.ndarray] = []

    # ------------------------------------------------------------------ candidates
    def candidates(self, obs: np.ndarray, mask: np.ndarray
                   ) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Per member: patterns ``(C_b, depth, N, W)`` int and continuation ids ``(C_b,)``."""
        allowed = mask[..., 1::2] > 0  # (B, N, W)
        acts = [p.act(obs, mask) for p in self.policies]  # (B, N, W) each
        B, N, W = allowed.shape
        pats, conts = [], []
        for b in range(B):
            if self.config.candidates == "exhaustive":
                grid = np.array(list(itertools.product((0, 1), repeat=N * W)), dtype=np.int64)
                grid = grid.reshape(-1, N, W) * allowed[b]
                one = [np.unique(grid, axis=0)]
                seqs = np.array(list(itertools.product(range(len(one[0])),
                                                       repeat=self.config.depth)))
                cand = one[0][seqs]  # (S, depth, N, W)
                # the base policy's own action first (ties go to it)
                first = np.flatnonzero((cand[:, 0] == acts[0][b]).all((1, 2)))
                order = np.r_[first, np.setdiff1d(np.arange(len(cand)), first)]
                pats.append(cand[order])
                conts.append(np.zeros(len(cand), dtype=np.int64))
                continue
            own = [a[b] for a in acts]
            base = own[0]
            extra = [allowed[b].astype(np.int64), np.zeros((N, W), dtype=np.int64)]
            for i in range(N):
                for j in range(W):
                    if allowed[b, i, j]:
                        flip = base.copy()
                        flip[i, j] ^= 1
                        extra.append(flip)
                if W > 1:
                    for row in (allowed[b, i], np.zeros(W, bool)):
                        whole = base.copy()
                        whole[i] = row
                        extra.append(whole)
            if self.core.capacity is not None:  # a shared channel: who, not how many
                talk = base.any(-1)
                for i, j in itertools.product(np.flatnonzero(talk), np.flatnonzero(~talk)):
                    swap = base.copy()
                    swap[i], swap[j] = 0, allowed[b, j]
                    extra.append(swap)
            cand = np.stack(own + extra)
            cid = np.r_[np.arange(len(own)), np.zeros(len(extra), dtype=np.int64)]
            key = np.concatenate([cand.reshape(len(cand), -1), cid[:, None]], axis=1)
            _, first = np.unique(key, axis=0, return_index=True)
            keep = np.sort(first)  # first occurrences, in order
            pats.append(cand[keep][:, None])
            conts.append(cid[keep])
        return pats, conts

    # ------------------------------------------------------------------ decision
    def act(self, obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """The bits ``(B, N, W)`` of the current step of the evaluated core."""
        return self.decide(obs, mask)

    def decide(self, obs: np.ndarray | None = None, mask: np.ndarray | None = None
               ) -> np.ndarray:
        """Score every candidate of every member on one fork and return the best bits
        (with ``rounds = 2``, then the combination of every improving single flip
        against the first round's choice, on a second fork with the same futures)."""
        t0 = time.perf_counter()
        core, cfg = self.core, self.config
        if obs is None or mask is None:
            obs, mask = core.observe()
        pats, conts = self.candidates(obs, mask)
        members = np.arange(core.B)
        self.scores = self._score(obs, mask, members, pats, conts)
        pick = [self._choose(q) for q in self.scores]
        best = np.stack([p[c, 0] for p, c in zip(pats, pick, strict=True)])
        if cfg.rounds > 1 and cfg.candidates == "flips":
            combo = [self._combination(p[:, 0], c, q)
                     for p, c, q in zip(pats, conts, self.scores, strict=True)]
            again = np.flatnonzero([x is not None for x in combo])
            if again.size:
                pats2 = [np.stack([best[b], combo[b]])[:, None] for b in again]
                conts2 = [np.array([conts[b][pick[b]], 0]) for b in again]
                for b, q in zip(again, self._score(obs, mask, again, pats2, conts2),
                                strict=True):
                    if self._choose(q):
                        best[b] = combo[b]
        self.decisions += 1
        self.seconds += time.perf_counter() - t0
        return best

    def _combination(self, pats: np.ndarray, conts: np.ndarray, q: np.ndarray
                     ) -> np.ndarray | None:
        """The base action with every single-bit flip whose paired gain passes the
        margin of :meth:`_choose` flipped at once (None: fewer than two such flips)."""
        base = pats[0]
        diff = (pats != base).reshape(len(pats), -1)
        single = (diff.sum(1) == 1) & (conts == 0)
        F = q.shape[0]
        d = q - q[:, :1]
        gain = d.mean(0)
        if F > 1 and self.config.confidence:
            gain = gain - self.config.confidence * d.std(0, ddof=1) / np.sqrt(F)
        good = single & (gain > 0)
        if good.sum() < 2:
            return None
        flip = diff[good].any(0).reshape(base.shape)
        return np.where(flip, 1 - base, base)

    def _score(self, obs: np.ndarray, mask: np.ndarray, members: np.ndarray,
               pats: list[np.ndarray], conts: list[np.ndarray]) -> list[np.ndarray]:
        """Returns ``(F, C_b)`` of every candidate of ``members`` (one fork: a lane per
        member, future and candidate, in that order)."""
        from netsense.engine.fork import fork

        core, cfg = self.core, self.config
        F = cfg.num_futures
        sizes = np.array([len(p) for p in pats])
        member = np.repeat(members, sizes * F)
        fut = np.concatenate([np.repeat(np.arange(F), s) for s in sizes])
        cand = np.concatenate([np.tile(np.arange(s), F) for s in sizes])
        offsets = np.r_[0, np.cumsum(sizes)[:-1]]
        flat_pats = np.concatenate(pats)  # (sum C_b, depth, N, W)
        row = np.repeat(offsets, sizes * F) + cand
        lane_cont = np.concatenate(conts)[row]
        steps = max(int(min(cfg.horizon, core.horizon - int(core.k[members].min()))), 1)
        if cfg.kind == "causal":
            ss = {(b, f): np.random.SeedSequence([cfg.seed, self.seeds[b], int(core.k[b]), f])
                  for b in members.tolist() for f in range(F)}
            seeds = [ss[b, f] for b, f in zip(member.tolist(), fut.tolist(), strict=True)]
            # (chunk steps + 1: the last step loads position `steps`, and no lane refills)
            lanes = fork(core, member, future="resampled", seeds=seeds,
                         known_ahead=self.known_ahead,
                         chunk=max(steps + 1, self.known_ahead + 1))
        else:
            lanes = fork(core, member, chunk=steps + 1)
        lanes.invalid_actions = "keep"  # later patterns of a sequence may be masked
        policies = self._policies(lanes)
        total = np.zeros(len(member))
        live = np.ones(len(member), dtype=bool)
        l_obs, l_mask = obs[member], mask[member]
        for j in range(steps):
            if j < cfg.depth:
                act = flat_pats[row, j]
            else:
                act = self._continue(policies, lane_cont, l_obs, l_mask)
            out = lanes.step(act, observe=j + 1 < steps)
            last = out.reward.mean(1)
            total[live] += last[live]
            live &= ~(out.terminated | out.truncated)
            l_obs, l_mask = out.obs, out.action_mask
        if cfg.terminal:  # the last step's reward for the steps after the lookahead
            tail = np.minimum(cfg.terminal, np.maximum(lanes.horizon - lanes.k, 0))
            total[live] += (tail * last)[live]
        self.lane_steps += len(member) * steps
        edges = np.r_[0, np.cumsum(sizes * F)]
        return [total[edges[i]:edges[i + 1]].reshape(F, sizes[i])  # (future, cand.)
                for i in range(len(members))]

    def _choose(self, q: np.ndarray) -> int:
        """The candidate of the highest mean return over futures, or with ``confidence``
        ``z > 0`` the highest lower confidence bound of its paired gain over candidate 0
        (``mean - z sd / sqrt(F)``; candidate 0 when none is positive)."""
        F = q.shape[0]
        z = self.config.confidence
        if not z or F < 2:
            return int(np.argmax(q.mean(0)))
        d = q - q[:, :1]
        lcb = d.mean(0) - z * d.std(0, ddof=1) / np.sqrt(F)
        lcb[0] = 0.0
        return int(np.argmax(lcb))

    def _policies(self, lanes) -> list:
        from netsense.env.comm_policies import make_comm_policy

        return [make_comm_policy(s, lanes) for s in self.config.continuation]

    @staticmethod
    def _continue(policies, lane_cont, obs, mask) -> np.ndarray:
        if len(policies) == 1:
            return policies[0].act(obs, mask)
        out = policies[0].act(obs, mask)
        for i, p in enumerate(policies[1:], start=1):
            sel = lane_cont == i
            if sel.any():
                out[sel] = p.act(obs[sel], mask[sel])
        return out

    def cost(self) -> dict[str, float]:
        """``lane_steps``, ``decisions``, ``seconds`` and lane-steps per decision."""
        per = self.lane_steps / max(self.decisions, 1)
        return {"lane_steps": self.lane_steps, "decisions": self.decisions,
                "seconds": self.seconds, "lane_steps_per_decision": per}
