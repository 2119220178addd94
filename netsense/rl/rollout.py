"""Training pipeline, stage *collection*: ``T`` steps of ``B`` environments with the actor.

:class:`Collector` steps a :class:`netsense.rl.envs.NetSenseBatchedEnv` through its array
interface (:meth:`~netsense.rl.envs.NetSenseBatchedEnv.advance`, the same step its TorchRL
``_step`` runs) and the actor network directly: observations go from the core's numpy
buffers to torch without a copy, one forward pass of the shared actor per step for all
``B x N`` agents, masked sampling, no TensorDict per step. What a rollout holds
(:class:`Rollout`) is what the update needs: observations, masks, actions, their
log-probabilities, rewards, episode boundaries, the critic's inputs, the recurrent state.

Staggered episodes. All members start together and every episode lasts the horizon
``H``, so without care every rollout window of ``T < H`` steps would cover the same phase
of the episode in all members (all early transients, or all late steady states), and the
value targets' scale would swing from one iteration to the next. With ``stagger=True``
(training) the collector first runs ``H`` steps of uniformly random allowed actions in
which member ``b`` restarts at a random step ``s_b``; afterwards the members' episode
phases are spread over ``[0, H)`` and stay so. Those warm-up steps are not part of any
rollout.

Episode ends. Every episode ends at the scenario's horizon (``truncated``) or when a
member's state stops being finite (``terminated``); the time ``k / H`` is part of the
observation and the return really stops there, so both ends are terminal for the returns
(no bootstrap past an episode's end). Finished members restart at once (partial reset,
seeds from the env's generator); a recurrent actor's hidden state is zeroed for them only.

Imports: numpy, torch and the stages below (envs, distributions, memory).
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import torch

from netsense.rl.distributions import MaskedMultiCategorical
from netsense.rl.envs import NetSenseBatchedEnv, global_state
from netsense.rl.memory import is_recurrent

__all__ = ["STAGGER_STEP", "CollectAhead", "Collector", "Rollout"]

#: Granularity of the staggered episode phases (env-steps).
STAGGER_STEP = 8


@dataclass
class Rollout:
    """``T`` steps of ``B`` members (time first). Tensors live on the learner's device."""

    obs: torch.Tensor  #: (T + 1, B, N, O) float32; [T] is the observation after the last step
    mask: torch.Tensor  #: (T, B, N, K) bool
    action: torch.Tensor  #: (T, B, N, A) int64
    log_prob: torch.Tensor  #: (T, B, N) float32
    reward: torch.Tensor  #: (T, B, N) float32
    done: torch.Tensor  #: (T, B) bool: the episode ended with step t
    first: torch.Tensor  #: (T, B) bool: step t is the first of an episode
    state: torch.Tensor | None  #: (T + 1, B, S) float32 global state (state critic)
    hidden: torch.Tensor | None  #: (T, B, N, m) recurrent state before step t
    error: torch.Tensor  #: (T, B, N) clipped normalised errors after step t
    sent: torch.Tensor  #: (T, B, N) transmit flags chosen at step t
    returns: list[float]  #: returns (mean over agents) of the episodes that ended


class Collector:
    """Rollouts of ``T`` steps from ``env`` under the actor ``net``.

    Parameters
    ----------
    env : NetSenseBatchedEnv
        Its core is stepped through :meth:`~NetSenseBatchedEnv.advance`.
    net : torch module
        The actor's logits network (feed-forward ``net(obs)`` or recurrent
        ``net(obs, h)``, :mod:`netsense.rl.memory`).
    steps : int
        ``T``.
    device : torch device
        Where the actor runs and the rollout is stored.
    with_state : bool
        Record the global state (:func:`netsense.rl.envs.global_state`) for a state critic.
    update_obs_norm : bool
        Feed every observation collected to the actor's normaliser
        (:class:`netsense.rl.policy.ObsNormActor`; training only, not evaluation).
    stagger : bool
        Spread the members' episode phases first (see the module docstring; training).
    seed : int
        Seeds the collector's own random streams: the stagger's restart steps and random
        actions, and the sampled actions of every rollout. The collector never draws from
        torch's global generator, so a rollout's actions do not depend on what else the
        process draws in the meantime (a learner in another thread, an evaluation).
    """

    def __init__(self, env: NetSenseBatchedEnv, net: torch.nn.Module, steps: int, *,
                 device: torch.device | str = "cpu", with_state: bool = False,
                 update_obs_norm: bool = False, stagger: bool = False,
                 seed: int = 0) -> None:
        self.env, self.net, self.T = env, net, int(steps)
        self.device = torch.device(device)
        self.with_state = with_state
        self.obs_norm = net if update_obs_norm and hasattr(net, "update") else None
        self.nvec = tuple(int(v) for v in env.nvec)
        core = env.core
        self.B, self.N = int(core.B), int(core.N)
        self.recurrent = is_recurrent(net)
        obs, mask = env.restart()
        gen = torch.Generator().manual_seed(int(seed))
        if stagger:
            obs, mask = self._stagger(obs, mask, gen)
        self._obs, self._mask = obs, mask
        self._first = np.ones(self.B, bool)
        self._h = (torch.zeros(self.B, self.N, net.memory, device=self.device)
                   if self.recurrent else None)
        self._acc = np.zeros((self.B, self.N))
        # the actions' generator, on the actor's device, seeded from the stagger's stream
        # (the same seed on both would replay the stagger's draws)
        self._gen = torch.Generator(self.device).manual_seed(
            int(torch.randint(0, 2**62, (), generator=gen)))

    def state(self) -> bytes:
        """Everything the next :meth:`collect` depends on besides the actor's weights, as
        bytes (:func:`netsense.rl.resume.dumps_state`): the environments' core (every
        member mid-episode, its generators), the env's seed stream, the observation and
        mask acted on next, the running returns, a recurrent actor's state and the
        actions' generator. Call it only while no collection runs."""
        from netsense.rl.resume import dumps_state

        env = self.env
        return dumps_state({
            "core": env.core, "seed": env._seed, "seed_rng": env._seed_rng,
            "started": env._started, "obs": self._obs, "mask": self._mask,
            "first": self._first, "acc": self._acc,
            "h": None if self._h is None else self._h.cpu().numpy(),
            "gen": self._gen.get_state().numpy()})

    def load_state(self, data: bytes, where: str = "collector state") -> None:
        """Continue from :meth:`state`'s ``data`` (the env's core is replaced by the saved
        one). ``ValueError`` naming ``where`` when it does not fit this collector."""
        from netsense.rl.resume import loads_state

        st = loads_state(data, where)
        core = st.get("core") if isinstance(st, dict) else None
        old = self.env.core
        if core is None or type(core) is not type(old) or (core.B, core.N) != (old.B, old.N) \
                or tuple(core.nvec) != tuple(old.nvec):
            raise ValueError(f"{where}: the saved environments do not fit this run's "
                             f"({old.B} members of {old.N} agents)")
        self.env.core = core
        self.env._seed, self.env._seed_rng = st["seed"], st["seed_rng"]
        self.env._started = st["started"]
        self._obs, self._mask, self._first, self._acc = (st["obs"], st["mask"], st["first"],
                                                         st["acc"])
        if self._h is not None:
            self._h = torch.as_tensor(st["h"], device=self.device)
        self._gen.set_state(torch.from_numpy(st["gen"]))

    def _actor(self, o: torch.Tensor) -> torch.Tensor:
        """Logits of the current observations (a recurrent actor advances its state)."""
        if self.recurrent:
            logits, self._h = self.net(o, self._h)
            return logits
        return self.net(o)

    def _sample(self, logits: torch.Tensor, m: torch.Tensor,
                deterministic: bool) -> tuple[torch.Tensor, torch.Tensor]:
        """Allowed actions (sampled or most likely) and their log-probabilities."""
        d = MaskedMultiCategorical(logits, m, self.nvec)
        if deterministic:
            a = d.deterministic_sample
        else:  # the distribution's own sampling, from the collector's generator
            p = d.base_dist.probs
            a = torch.multinomial(p.reshape(-1, p.shape[-1]), 1,
                                  generator=self._gen).reshape(p.shape[:-1])
        return a, d.log_prob(a)

    def _stagger(self, obs: np.ndarray, mask: np.ndarray, gen: torch.Generator):
        """``H`` steps of random allowed actions; member ``b`` restarts at step ``s_b``."""
        env, H = self.env, int(self.env.core.horizon)
        # restarts on a grid of STAGGER_STEP steps: members end in groups afterwards, so a
        # partial reset (whose fixed cost is that of a whole observation pass) runs every
        # STAGGER_STEP steps, not at every step
        grid = max(1, H // STAGGER_STEP)
        restart_at = (torch.randint(0, grid, (self.B,), generator=gen) * STAGGER_STEP).numpy()
        for k in range(H):
            m = torch.from_numpy(np.ascontiguousarray(mask.view(np.bool_)))
            logits = torch.zeros(m.shape)
            d = MaskedMultiCategorical(logits, m, self.nvec)
            probs = d.base_dist.probs.reshape(-1, d.base_dist.probs.shape[-1])
            a = torch.multinomial(probs, 1, generator=gen).reshape(d.base_dist.probs.shape[:-1])
            obs, mask, _, term, trunc = env.advance(a.numpy())
            again = (term | trunc) | (restart_at == k)
            if again.any():
                obs, mask = env.restart(again)
        return obs, mask

    def _tensor(self, a: np.ndarray, dtype=None) -> torch.Tensor:
        t = torch.from_numpy(np.ascontiguousarray(a))
        if dtype is not None:
            t = t.to(dtype)
        return t.to(self.device, non_blocking=True)

    def timed_collect(self) -> tuple[Rollout, float]:
        """:meth:`collect` and the seconds it took."""
        t = time.perf_counter()
        ro = self.collect()
        return ro, time.perf_counter() - t

    @torch.no_grad()
    def collect(self, *, deterministic: bool = False) -> Rollout:
        """The next ``T`` steps (the collector keeps its members' episodes going)."""
        T, B, N = self.T, self.B, self.N
        env, dev = self.env, self.device
        O = self._obs.shape[-1]
        obs_t = torch.empty(T + 1, B, N, O, device=dev)
        mask_t = torch.empty(T, B, N, int(sum(self.nvec)), dtype=torch.bool, device=dev)
        act_t = torch.empty(T, B, N, len(self.nvec), dtype=torch.int64, device=dev)
        logp_t = torch.empty(T, B, N, device=dev)
        rew = np.empty((T, B, N), np.float32)
        done = np.empty((T, B), bool)
        first = np.empty((T, B), bool)
        err = np.empty((T, B, N), np.float32)
        sent = np.empty((T, B, N), np.float32)
        state = (np.empty((T + 1, B, env.state_dim), np.float32) if self.with_state
                 else None)
        hid = (torch.empty(T, B, N, self.net.memory, device=dev) if self.recurrent
               else None)
        returns: list[float] = []
        for t in range(T):
            o = self._tensor(self._obs)
            if self.obs_norm is not None:
                self.obs_norm.update(o)
            m = self._tensor(self._mask.view(np.bool_))
            obs_t[t], mask_t[t] = o, m
            first[t] = self._first
            if state is not None:
                state[t] = global_state(env.core)
            if self.recurrent:
                hid[t] = self._h
            logits = self._actor(o)
            a, logp = self._sample(logits, m, deterministic)
            act_t[t] = a
            logp_t[t] = logp
            obs, mask, r, term, trunc = env.advance(a.cpu().numpy())
            rew[t] = r
            ended = term | trunc
            done[t] = ended
            err[t] = env.core.errors
            sent[t] = env.core.transmit
            self._acc += r
            if ended.any():
                returns += self._acc[ended].mean(-1).tolist()
                self._acc[ended] = 0.0
                obs, mask = env.restart(ended)
                if self.recurrent:
                    self._h[torch.as_tensor(ended, device=dev)] = 0.0
            self._obs, self._mask, self._first = obs, mask, ended
        obs_t[T] = self._tensor(self._obs)
        if state is not None:
            state[T] = global_state(env.core)
        as_t = self._tensor
        return Rollout(obs_t, mask_t, act_t, logp_t, as_t(rew), as_t(done), as_t(first),
                       None if state is None else as_t(state), hid, as_t(err), as_t(sent),
                       returns)


class CollectAhead:
    """A :class:`Collector` one rollout ahead of the learner, in a second Python thread.

    :meth:`next` returns the rollout collected meanwhile (the first one is collected on the
    spot), hands the collector the learner's parameters and the learner the collector's
    buffers (:func:`sync`), and starts the next collection, which then runs while the
    learner trains on the returned rollout: each rollout comes from the parameters the
    learner had one update earlier. The core's compiled passes and torch's operations
    release the GIL, so the two threads run at once.

    Parameters
    ----------
    collector : Collector
        Its actor network must be a copy of ``learner``'s, not the same module.
    learner : torch module
        The actor network the learner trains.
    initializer, initargs
        Run in the collection thread first (per-thread settings such as numba's thread
        count).
    """

    def __init__(self, collector: Collector, learner: torch.nn.Module, *,
                 initializer=None, initargs: tuple = ()) -> None:
        if collector.net is learner:
            raise ValueError("CollectAhead: the collector needs its own copy of the actor "
                             "(it acts while the learner's changes)")
        self.collector, self.learner = collector, learner
        self._pool = ThreadPoolExecutor(1, "netsense-collect", initializer=initializer,
                                        initargs=initargs)
        self._pending: Future | None = None
        self.snapshot: tuple[bytes, dict] | None = None

    def next(self, *, more: bool = True, snapshot: bool = False) -> tuple[Rollout, float]:
        """The next rollout and its collection's seconds; ``more=False``: collect no
        further one (the last iteration). ``snapshot=True`` keeps, in :attr:`snapshot`,
        the collector's state and its actor's weights as they are when the next
        collection starts (what a resumed run continues from)."""
        if self._pending is None:
            ro, took = self.collector.timed_collect()
        else:
            ro, took = self._pending.result()
            self._pending = None
        sync(self.learner, self.collector.net)
        if snapshot:
            #: ``(Collector.state(), actor state_dict)`` before the collection ahead
            self.snapshot = (self.collector.state(),
                             {k: v.detach().cpu().clone()
                              for k, v in self.collector.net.state_dict().items()})
        if more:
            self._pending = self._pool.submit(self.collector.timed_collect)
        return ro, took

    def close(self) -> None:
        """Wait for a running collection and stop the thread."""
        self._pool.shutdown(cancel_futures=True)


@torch.no_grad()
def sync(learner: torch.nn.Module, collector: torch.nn.Module) -> None:
    """Between two collections ahead: the collector's actor takes the learner's
    parameters, the learner's actor the collector's buffers (the observation normaliser's
    statistics, which only collection updates; :class:`netsense.rl.policy.ObsNormActor`)."""
    for mine, theirs in zip(collector.parameters(), learner.parameters(), strict=True):
        mine.copy_(theirs)
    for mine, theirs in zip(learner.buffers(), collector.buffers(), strict=True):
        mine.copy_(theirs)
