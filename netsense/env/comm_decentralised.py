"""Decentralised communication rules with a clock, a memory or a coin (the frontier a
reviewer would try besides periodic, Bernoulli, sources-first and event-triggered).

Every rule here decides agent ``i``'s bits at ``k`` (sent at ``k + 1``) from agent ``i``'s
own observation (its row of ``obs``), its own memory of its earlier observations and
design-time constants (the scenario's ``N``, ``H``, channel capacity ``K``, which agents
are sources, the plant matrix ``A_bar`` of Lemma 1): no rule reads another agent's row
(``tests/test_comm_policies.py`` checks this by perturbing the other rows). Rules with
memory or randomness keep per-member state that restarts when a member's observation
shows ``time = 0`` (a reset; the batched core resets members one by one), and draw from
one generator per member seeded like :class:`netsense.env.comm_policies.Bernoulli`, so a
batch of seeds equals the single episodes. Call ``act`` once per step.

================  ============  ==============================================================
spec              knobs         rule (``k`` the step whose action is taken)
================  ============  ==============================================================
``until:T[,d]``   T >= 0,       transmit at the steps ``k + 1 < T`` (as ``always``, or as
                  d >= 0        ``event:d`` when ``d >= 1``), never from step ``T`` on
``settle:e[,W]``  e > 0,        transmit until the own estimate has *settled*: the relative
                  W >= 1        correction ``c_i[k] = ||z_i[k] - A_bar z_i[k-1]|| /
                                max(||z_i[k]||, 1e-3)`` stayed below ``e`` for ``W``
                                consecutive steps (counted once it has an estimate of every
                                substate); silent from then on (default ``W = 5``)
``settled[:e](BASE)``          the base rule's bits once the agent's estimate of its *own*
                  e > 0         block has settled: silent until the first step ``k >= 1`` at
                                which ``||P_i (z_i[k] - A_bar z_i[k-1])|| / max(||z_i[k]||,
                                1e-3) < e`` (``P_i`` keeps the coordinates of agent ``i``'s
                                block of Lemma 1), the base's bits from then on; agents that
                                own no block send the base's bits throughout (default
                                ``e = 0.1``; the base is a plain decentralised rule)
``aloha:g,q``     g >= 0,       threshold ALOHA on the age gain: active iff
                  q > 0         ``a_i = max_j (H news_i^{(j)} + carry_i^{(j)}) >= g N / K``,
                                an active agent transmits with probability
                                ``min(1, q K / N)``; ``carry`` adds back the news of a
                                message that collided (collision feedback)
``tdma:F``        F >= 1        the ``S`` sources take turns, ``K`` per slot in cyclic
                                order of their rank ``r``: at the step ``t = k + 1``, if
                                ``t mod F = 0``, source ``r`` transmits iff ``(r - (t / F)
                                K) mod S < K``; the others never
================  ============  ==============================================================

``K`` is the channel capacity (``N`` without a ``[channel]``). Sources:

* ``until`` is the classic "talk while the estimates converge, then stop" of the
  noiseless tasks (with freshness fusion the estimates of a noiseless plant converge in
  finite time, Theorem 1 of the freshness paper, after which a message only adds what the
  receivers can already predict).
* ``settle`` is send-on-delta / event-triggered estimation with the innovation as the
  trigger (Trimpe & D'Andrea, IEEE TAC 2014, "Event-based state estimation with
  variance-based triggering", and the send-on-delta rule of Miskowicz, Sensors 2006),
  turned into a stopping rule: the correction the agent's estimate still receives is its
  own measure of how much the network is still telling it.
* ``settled`` is the reverse of ``settle``: *wait* until the own estimate is worth
  sending. With freshness fusion a receiver adopts the freshest estimate of a substate,
  however wrong; a source whose own observer is still in its transient sends the freshest
  and, there, the worst estimate of its block. On ``message_cost-v0``/``-v1`` and
  ``comm_schedule-v1`` one source's own-block error is several times the whole state's
  norm for its first steps, and its early messages raise every receiver's error (numbers
  in docs/frontier.md). The correction of the own block comes from the agent's own
  measurements only (an agent keeps its own substate), so the gate reads nothing of the
  network.
* ``aloha`` is threshold ALOHA with the age gain of Chen, Gatsis, Hassani and Saeedi
  Bidokhti, "Age of Information in Random Access Channels", IEEE Trans. Inf. Theory 68(10),
  2022 (a packet is sent only if the age reduction it would bring exceeds a threshold, then
  with a fixed probability). For a collision channel of capacity 1 with ``n`` sources and
  generate-at-will updates, Yavascan and Uysal ("Analysis of Slotted ALOHA With an Age
  Threshold", IEEE JSAC 39(5), 2021) proved the conjectured optimum of that paper:
  threshold ``2.2 n`` and probability ``4.69 / n``, for an average age of ``1.4169 n``
  against ``e n`` for the best slotted ALOHA. ``aloha:2.2,4.69`` is that point with
  ``n = N / K`` (exact for ``K = 1``; for ``K > 1`` the same scaling, swept around it).
* ``tdma`` is time-division multiple access over the sources: a fixed, collision-free
  schedule from the time and the agent's rank among the sources, the decentralised
  counterpart of the age-based schedulers (the round robin of Kadota et al., IEEE/ACM ToN
  2018, is optimal for symmetric reliable links).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netsense.env.policies import CommPolicy, _seed

__all__ = ["GatedRule", "MemberUniforms", "Settle", "Settled", "Tdma", "ThresholdAloha",
           "Until", "decoded_estimate", "int_knob"]


class _MemberState:
    """Per-member arrays of a rule with memory, restarted where ``time = 0``."""

    def __init__(self) -> None:
        self.arrays: dict[str, np.ndarray] = {}
        self.B = -1

    def restart(self, k: np.ndarray, shapes: dict[str, tuple[tuple[int, ...], object]]
                ) -> np.ndarray:
        """``(B,)`` bool: the members whose memory was cleared now (all of them when the
        batch size changed); ``shapes`` gives each array's per-member shape and fill."""
        B = k.shape[0]
        if B != self.B:
            self.B = B
            self.arrays = {nm: np.full((B, *s), v) for nm, (s, v) in shapes.items()}
            return np.ones(B, bool)
        new = k == 0
        if new.any():
            for nm, (_, v) in shapes.items():
                self.arrays[nm][new] = v
        return new

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]


class MemberUniforms:
    """Uniform draws ``(B, *shape)``: one generator for the batch (``seed`` an int or
    None) or one per member (a sequence of ``B`` seeds: member ``b`` draws what a
    ``B = 1`` rule seeded with ``seed[b]`` draws)."""

    def __init__(self, seed: int | Sequence[int] | None) -> None:
        if seed is None or np.ndim(seed) == 0:
            self.rng = np.random.default_rng(None if seed is None else _seed(seed))
            self.member_rngs = None
        else:
            self.rng = None
            self.member_rngs = [np.random.default_rng(_seed(s)) for s in seed]

    def __call__(self, B: int, shape: tuple[int, ...]) -> np.ndarray:
        if self.member_rngs is None:
            return self.rng.random((B, *shape))
        if B != len(self.member_rngs):
            raise ValueError(f"this policy has {len(self.member_rngs)} member generators, "
                             f"got a batch of {B} observations")
        return np.stack([g.random(shape) for g in self.member_rngs])


def _news_steps(policy: CommPolicy, obs: np.ndarray) -> np.ndarray:
    """``(B, N, M)`` news in steps (``H news``)."""
    return np.rint(obs[..., policy.layout.news] * policy.horizon)


def decoded_estimate(layout, obs: np.ndarray) -> np.ndarray:
    """``(B, N, n)`` each agent's estimate ``z_i`` decoded from its observation,
    ``z_dir expm1(z_lognorm)``."""
    return (obs[..., layout.z_dir].astype(float)
            * np.expm1(obs[..., layout.z_lognorm].astype(float)))


class Until(CommPolicy):
    """Talk until step ``stop``, then stop: ``t_i[k+1] = 1{k + 1 < T}`` (times
    ``1{news >= d}`` per substate when ``threshold = d >= 1``)."""

    name = "until"

    def __init__(self, layout, width, horizon, stop: int = 30, threshold: int = 0) -> None:
        super().__init__(layout, width, horizon)
        self.stop = int_knob("until", stop, 0)
        self.threshold = int_knob("until", threshold, 0)

    def act(self, obs, mask):
        obs = np.asarray(obs)
        talk = (self.steps(obs) + 1 < self.stop)[:, None, None]
        if self.threshold:
            talk = talk & (_news_steps(self, obs) >= self.threshold)
        else:
            talk = np.broadcast_to(talk, obs.shape[:2] + (self.M,))
        return self._send(mask, talk if self.width > 1 else talk.any(-1))


class Settle(CommPolicy):
    """Talk until the own estimate has settled (relative correction below ``eps`` for
    ``window`` consecutive steps), then stay silent for the rest of the episode.

    ``A_bar``: the plant of Lemma 1's coordinates, ``(n, n)`` (a design-time constant, as
    the gains are). The estimate is read from the observation, ``z = z_dir expm1(z_lognorm)``.
    """

    name = "settle"
    floor = 1e-3

    def __init__(self, layout, width, horizon, A_bar: np.ndarray, eps: float = 0.01,
                 window: int = 5) -> None:
        super().__init__(layout, width, horizon)
        eps = float(eps)
        if not (np.isfinite(eps) and eps > 0):
            raise ValueError(f"settle: eps must be a number > 0, got {eps!r}")
        self.eps = eps
        self.window = int_knob("settle", window, 1)
        self.A_bar_T = np.ascontiguousarray(np.asarray(A_bar, dtype=float).T)
        if self.A_bar_T.shape != (layout.n, layout.n):
            raise ValueError(f"A_bar must have shape ({layout.n}, {layout.n})")
        self.mem = _MemberState()

    def estimate(self, obs: np.ndarray) -> np.ndarray:
        """``(B, N, n)`` own estimates ``z_i`` decoded from the observation."""
        return decoded_estimate(self.layout, obs)

    def corrections(self, z: np.ndarray, z_prev: np.ndarray) -> np.ndarray:
        """``(B, N)``: ``||z - A_bar z_prev|| / max(||z||, 1e-3)``."""
        d = np.linalg.norm(z - z_prev @ self.A_bar_T, axis=-1)
        return d / np.maximum(np.linalg.norm(z, axis=-1), self.floor)

    def act(self, obs, mask):
        obs = np.asarray(obs)
        N, n = self.N, self.layout.n
        k = self.steps(obs)
        new = self.mem.restart(k, {"z": ((N, n), 0.0), "calm": ((N,), 0),
                                   "done": ((N,), False)})
        z = self.estimate(obs)
        calm, done = self.mem["calm"], self.mem["done"]
        small = self.corrections(z, self.mem["z"]) < self.eps
        small[new] = False  # no previous estimate yet
        small &= ~(obs[..., self.layout.own_omega] > 0.5).any(-1)  # not before it knows all
        calm[...] = np.where(small, calm + 1, 0)
        done |= calm >= self.window
        self.mem["z"][...] = z
        return self._send(mask, ~done)


class GatedRule(CommPolicy):
    """A decentralised base rule whose bits pass only where :meth:`gate` is open (it can
    stay silent where the base would talk, never the reverse): the frame of ``settled``
    here and of the informed rules (:class:`netsense.env.comm_informed.InformedRule`).

    Parameters
    ----------
    layout, width, horizon
        As :class:`netsense.env.policies.CommPolicy`.
    base : CommPolicy
        The decentralised base rule (same layout, width and horizon).
    """

    name = "gated rule"

    def __init__(self, layout, width, horizon, base: CommPolicy) -> None:
        super().__init__(layout, width, horizon)
        if not isinstance(base, CommPolicy):
            raise ValueError(f"{self.name}: base must be a communication policy, got "
                             f"{type(base).__name__}")
        self.base = base

    def gate(self, obs: np.ndarray) -> np.ndarray:
        """``(B, N)`` bool: where the base rule's bits may pass."""
        raise NotImplementedError

    def act(self, obs, mask):
        obs = np.asarray(obs)
        bits = self.base.act(obs, mask)
        return bits * self.gate(obs)[..., None]


class Settled(GatedRule):
    """The base rule's bits once the agent's estimate of its own block has settled
    (module docstring, ``settled[:e](BASE)``). Memory per member and agent: the previous
    estimate and whether the gate is open.

    Parameters
    ----------
    layout, width, horizon
        As :class:`netsense.env.policies.CommPolicy`.
    base : CommPolicy
        The decentralised base rule (same layout, width and horizon).
    A_bar : ndarray, shape (n, n)
        The plant of Lemma 1's coordinates (a design-time constant, as in
        :class:`Settle`).
    block_of : ndarray of int, shape (n,)
        The agent whose block holds each coordinate of Lemma 1 (a design-time constant).
    eps : float
        The threshold ``e > 0`` on the own block's relative correction.
    """

    name = "settled"
    floor = Settle.floor

    def __init__(self, layout, width, horizon, base: CommPolicy, A_bar: np.ndarray,
                 block_of: np.ndarray, eps: float = 0.1) -> None:
        super().__init__(layout, width, horizon, base)
        eps = float(eps)
        if not (np.isfinite(eps) and eps > 0):
            raise ValueError(f"settled: the threshold e must be a number > 0, got {eps!r}")
        n = layout.n
        self.A_bar_T = np.ascontiguousarray(np.asarray(A_bar, dtype=float).T)
        if self.A_bar_T.shape != (n, n):
            raise ValueError(f"A_bar must have shape ({n}, {n})")
        block_of = np.asarray(block_of)
        if block_of.shape != (n,) or not np.issubdtype(block_of.dtype, np.integer) or (
                block_of.size and (block_of.min() < 0 or block_of.max() >= self.N)):
            raise ValueError(f"block_of must be {n} agent indices in [0, {self.N}), got "
                             f"{block_of!r}")
        self.eps = eps
        #: (N, n) bool: the coordinates of each agent's own block
        self.own_block = np.zeros((self.N, n), bool)
        self.own_block[block_of, np.arange(n)] = True
        self.owner = self.own_block.any(1)
        self.mem = _MemberState()

    def corrections(self, z: np.ndarray, z_prev: np.ndarray) -> np.ndarray:
        """``(B, N)``: ``||P_i (z - A_bar z_prev)|| / max(||z||, 1e-3)``."""
        d = np.where(self.own_block, z - z_prev @ self.A_bar_T, 0.0)
        return (np.linalg.norm(d, axis=-1)
                / np.maximum(np.linalg.norm(z, axis=-1), self.floor))

    def gate(self, obs: np.ndarray) -> np.ndarray:
        """``(B, N)`` bool: where the base rule's bits may pass."""
        new = self.mem.restart(self.steps(obs), {"z": ((self.N, self.layout.n), 0.0),
                                                 "open": ((self.N,), False)})
        z = decoded_estimate(self.layout, obs)
        small = self.corrections(z, self.mem["z"]) < self.eps
        small[new] = False  # no previous estimate yet
        self.mem["open"][...] |= small | ~self.owner[None]
        self.mem["z"][...] = z
        return self.mem["open"].copy()


class ThresholdAloha(CommPolicy):
    """Threshold ALOHA on the age gain, with collision feedback (module docstring).

    ``capacity``: ``K`` (``None``: no channel, ``K = N``). An agent is active when its
    largest age gain ``H news_i^{(j)} + carry_i^{(j)}`` reaches ``g N / K``; an active
    agent transmits with probability ``min(1, q K / N)``. ``carry_i^{(j)}`` is the news a
    message of ``i`` carried that was lost in a collision (seen as ``silence = 0`` and
    ``collided = 1`` at the step it went out), cleared by a message that got through:
    the gain is then measured from what the receivers last *got*, as in Chen et al.
    In ``substates`` mode an active agent sends the substates whose gain reaches the
    threshold.
    """

    name = "aloha"

    def __init__(self, layout, width, horizon, g: float = 2.2, q: float = 4.69,
                 capacity: int | None = None,
                 seed: int | Sequence[int] | None = None) -> None:
        super().__init__(layout, width, horizon)
        g, q = float(g), float(q)
        if not (np.isfinite(g) and g >= 0):
            raise ValueError(f"aloha: the threshold factor g must be >= 0, got {g!r}")
        if not (np.isfinite(q) and q > 0):
            raise ValueError(f"aloha: the probability factor q must be > 0, got {q!r}")
        K = self.N if capacity is None else int(capacity)
        self.g, self.q = g, q
        self.threshold = g * self.N / K
        self.p = min(1.0, q * K / self.N)
        self.uniforms = MemberUniforms(seed)
        self.mem = _MemberState()

    def gains(self, obs: np.ndarray) -> np.ndarray:
        """``(B, N, M)`` age gains (news in steps plus the carry), updating the carry."""
        L, N, M = self.layout, self.N, self.M
        k = self.steps(obs)
        self.mem.restart(k, {"carry": ((N, M), 0.0), "last": ((N, M), 0.0)})
        carry, last = self.mem["carry"], self.mem["last"]
        sent_now = obs[..., L.silence.start] == 0  # (B, N): transmitted at step k
        lost = sent_now & (obs[..., L.collided.start] > 0.5)
        got = sent_now & ~lost
        carry[lost] += last[lost]
        carry[got] = 0.0
        return _news_steps(self, obs) + carry

    def act(self, obs, mask):
        obs = np.asarray(obs)
        a = self.gains(obs)
        B = obs.shape[0]
        ready = a >= self.threshold
        coin = self.uniforms(B, (self.N,)) < self.p
        send = ready & coin[..., None] if self.width > 1 else (ready.any(-1) & coin)
        bits = self._send(mask, send)
        # what goes out carries this news (in transmit mode, every substate it has)
        out = bits.astype(bool) if self.width > 1 else np.broadcast_to(
            bits.astype(bool), a.shape)
        self.mem["last"][...] = np.where(out, _news_steps(self, obs), 0.0)
        return bits


class Tdma(CommPolicy):
    """Time-division multiple access over the sources, ``K`` per slot (module docstring).

    With ``S`` sources ranked ``r = 0 .. S-1`` by id, slot ``u`` (the step ``t = u F``;
    the steps between slots are silent) goes to the ``min(K, S)`` sources ``r`` with
    ``(r - u K) mod S < K``: the sources in cyclic order, ``K`` at a time, so the
    channel is full at every slot and no two senders ever exceed it.
    """

    name = "tdma"

    def __init__(self, layout, width, horizon, is_source: np.ndarray,
                 capacity: int | None = None, stretch: int = 1) -> None:
        super().__init__(layout, width, horizon)
        self.is_source = np.asarray(is_source, dtype=bool)
        if self.is_source.shape != (self.N,):
            raise ValueError(f"is_source must have shape ({self.N},)")
        self.stretch = int_knob("tdma", stretch, 1)
        self.K = self.N if capacity is None else int(capacity)
        self.S = int(self.is_source.sum())
        #: (N,) rank of each source among the sources (-1: not a source)
        self.rank = np.where(self.is_source, np.cumsum(self.is_source) - 1, -1)

    def act(self, obs, mask):
        t = self.steps(np.asarray(obs)) + 1  # the step the bits are sent at
        u = (t // self.stretch)[:, None]
        turn = (self.rank[None] - u * self.K) % max(self.S, 1) < self.K
        send = (t[:, None] % self.stretch == 0) & turn & (self.rank >= 0)[None]
        return self._send(mask, send)


def int_knob(name: str, v, low: int) -> int:
    """``v`` as an int ``>= low``, else a ``ValueError`` naming the family ``name``."""
    if isinstance(v, bool) or int(v) != v or v < low:
        raise ValueError(f"{name}: the knob must be an integer >= {low}, got {v!r}")
    return int(v)
