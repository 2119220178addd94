"""Benchmark harness: scenarios x policies x seeds, with metrics, tables and plots.

One *job* is one episode of one scenario under one policy and one seed. A job returns an
:class:`EpisodeRecord` (per-step curves) which :func:`episode_metrics` reduces to the
numbers of the table:

==========================  ================================================================
metric                      definition
==========================  ================================================================
``mean_rel_error``          mean over steps ``k = 1..K`` and agents ``i`` of
                            ``e_i[k] = ||x_hat_i[k] - x[k]|| / max(||x[k]||, floor)``
``final_rel_error``         mean over agents of ``e_i[K]`` (the last step)
``steps_to_eps``            first ``k`` from which ``max_i e_i[k'] <= eps`` for every
                            ``k' >= k`` (NaN when it is never reached)
``msgs_per_agent_step``     transmissions / (``N`` x ``K``)
``aoi_mean``, ``aoi_max``   mean / max over steps, agents and substates ``j != i`` of the
                            freshness index ``tau_i^{(j)}`` (finite entries only)
``aoi_omega_frac``          fraction of those entries still equal to omega
``reward``                  the scenario's episode return, averaged over agents
==========================  ================================================================

Policies (names accepted by :func:`run_benchmark` and ``netsense benchmark``):

``freshness``, ``uniform_consensus``, ``tree_consensus``, ``open_loop``, ``random``
    the scripted policies of :mod:`netsense.policies`, acting through the environment;
``kf_oracle``
    a centralized Kalman filter that sees every agent's measurement every step (no
    network): a lower bound on the error, no messages and no reward;
``learned`` / ``learned:PATH``
    a policy trained by :mod:`netsense.rl.sb3` and loaded from ``PATH`` (a ``.zip``); in
    ``PATH`` the text ``{scenario}`` is replaced by the scenario id.

Backends (:func:`execute`), all with a tqdm bar and the same results in job order:

``batched`` (default)
    the jobs of one (scenario, policy, overrides) run as **one** batched simulation
    (:func:`netsense.vector.rollout_seeds`, one :class:`netsense.envcore.BatchedCore`
    member per seed) instead of one episode per seed; every policy but ``learned``
    batches (``random`` with one generator per member, ``kf_oracle`` with a batched
    centralized filter), and member ``b``'s record equals the single episode of its seed.
    ``learned`` policies run episode by episode in the calling process;
``process`` / ``serial``
    one episode per job (:func:`run_job`) in worker processes / in the calling process;
``ray``
    one episode per job as Ray tasks, optionally on a cluster given by ``ray_address``
    (for learned policies or many scenarios on many machines).
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

#: Scripted policies run through the environment.
SCRIPTED_POLICIES = ("freshness", "uniform_consensus", "tree_consensus", "open_loop", "random")
#: Every policy name the harness knows (``learned`` may carry ``:PATH``).
POLICY_NAMES = SCRIPTED_POLICIES + ("kf_oracle", "learned")
#: Default policy set of ``netsense benchmark``.
DEFAULT_POLICIES = ("freshness", "uniform_consensus", "open_loop", "random", "kf_oracle")

METRICS = ("mean_rel_error", "final_rel_error", "steps_to_eps", "msgs_per_agent_step",
           "aoi_mean", "aoi_max", "aoi_omega_frac", "reward")

_FLOOR = 1e-3


# ----------------------------------------------------------------------------- records
@dataclass
class EpisodeRecord:
    """Per-step curves of one episode.

    Attributes
    ----------
    errors : (K + 1, N) array
        ``||x_hat_i[k] - x[k]||`` for ``k = 0..K`` (the oracle has ``N = 1``).
    x_norm : (K + 1,) array
        ``||x[k]||``.
    messages : (K, N) bool array or None
        Whether agent ``i`` transmitted at step ``k`` (None for the oracle).
    aoi : (K + 1, N, M) int array or None
        Freshness indices ``tau_i^{(j)}[k]``, ``-1`` for omega (None when not tracked);
        ``M = N`` or, with ``substates = "sources"``, one column per source.
    rewards : (K, N) array or None
        Per-agent rewards (None for the oracle).
    floor : float
        Smallest ``||x||`` used to normalise (the scenario's ``reward.error_floor``).
    own : (N,) int array or None
        Column of ``aoi`` holding agent ``i``'s own substate (``-1``: none); None means
        the diagonal (``M = N``).
    """

    errors: np.ndarray
    x_norm: np.ndarray
    messages: np.ndarray | None = None
    aoi: np.ndarray | None = None
    rewards: np.ndarray | None = None
    floor: float = 1e-3
    own: np.ndarray | None = None

    def relative_errors(self) -> np.ndarray:
        """``e_i[k]``, ``(K + 1, N)``: errors over ``max(||x[k]||, floor)``."""
        return relative_errors(self.errors, self.x_norm, self.floor)


class EpisodeRecorder:
    """Collects the curves of :class:`EpisodeRecord` from a core's ``B`` members.

    One recorder serves the single episode through the PettingZoo env (``B = 1``, its
    ``env.core``), the batched runs of :func:`netsense.vector.rollout_seeds` and both forms
    of the oracle, so every path builds its records the same way.

    Parameters
    ----------
    floor : float
        The scenario's ``reward.error_floor`` (:attr:`EpisodeRecord.floor`).
    network : bool
        Record freshness indices, transmissions and rewards (False for the oracle).
    """

    def __init__(self, floor: float, *, network: bool = True) -> None:
        self.floor = float(floor)
        self.network = bool(network)
        self._errs: list[np.ndarray] = []
        self._xn: list[np.ndarray] = []
        self._aoi: list[np.ndarray] = []
        self._msgs: list[np.ndarray] = []
        self._rews: list[np.ndarray] = []
        self._own: np.ndarray | None = None

    def state(self, core, estimates: np.ndarray | None = None) -> None:
        """Record step ``k``: ``||x_hat_i - x||``, ``||x||`` and (network) ``tau``.

        Parameters
        ----------
        core : netsense.envcore.BatchedCore
        estimates : (B, N', n) array, optional
            Estimates to score (default the agents' ``core.estimates``; the oracle passes
            its own, ``N' = 1``).
        """
        x = core.x
        est = core.estimates if estimates is None else estimates
        self._errs.append(np.linalg.norm(est - x[:, None, :], axis=-1))
        self._xn.append(np.linalg.norm(x, axis=-1))
        if self.network:
            self._aoi.append(core.tau.copy())
            self._own = core.own

    def step(self, transmit: np.ndarray, reward: np.ndarray | Sequence) -> None:
        """Record the transmissions ``(B, N)`` and rewards ``(B, N)`` of the last step."""
        self._msgs.append(np.array(transmit, dtype=bool))
        self._rews.append(np.array(reward, dtype=float))

    def records(self, end: Sequence[int] | None = None) -> list[EpisodeRecord]:
        """One record per member, member ``b`` cut after its last step ``end[b]``.

        Parameters
        ----------
        end : sequence of B ints, optional
            The step at which each member's episode ended (default: the last recorded).
        """
        E, X = np.stack(self._errs, 1), np.stack(self._xn, 1)
        B, K = E.shape[0], E.shape[1] - 1
        end = np.full(B, K) if end is None else np.asarray(end, dtype=np.int64)
        if end.shape != (B,) or end.min() < 0 or end.max() > K:
            raise ValueError(f"end must hold {B} steps in 0..{K}, got {end.tolist()}")
        if not self.network:
            return [EpisodeRecord(E[b, : end[b] + 1], X[b, : end[b] + 1], floor=self.floor)
                    for b in range(B)]
        A, M, R = np.stack(self._aoi, 1), np.stack(self._msgs, 1), np.stack(self._rews, 1)
        own = None if self._own.shape[0] == A.shape[-1] and np.array_equal(
            self._own, np.arange(A.shape[-1])) else self._own
        return [EpisodeRecord(E[b, : end[b] + 1], X[b, : end[b] + 1], M[b, : end[b]],
                              A[b, : end[b] + 1], R[b, : end[b]], floor=self.floor, own=own)
                for b in range(B)]


@dataclass(frozen=True)
class Job:
    """One episode to run.

    Parameters
    ----------
    scenario : str
        Scenario id (``netsense.list_scenarios()``).
    policy : str
        Policy name (see the module docstring).
    seed : int
        ``reset(seed=...)`` of the environment.
    overrides : dict
        Keyword overrides passed to ``netsense.make``.
    eps : float
        Threshold of ``steps_to_eps``.
    """

    scenario: str
    policy: str
    seed: int
    overrides: dict = field(default_factory=dict)
    eps: float = 1e-2


# ----------------------------------------------------------------------------- metrics
def relative_errors(errors: np.ndarray, x_norm: np.ndarray, floor: float = _FLOOR
                    ) -> np.ndarray:
    """Relative errors ``errors[k, i] / max(x_norm[k], floor)``.

    Parameters
    ----------
    errors : (K + 1, N) array
    x_norm : (K + 1,) array
    floor : float
        Lower bound of the denominator (a state at the origin).
    """
    errors = np.asarray(errors, dtype=float)
    x_norm = np.asarray(x_norm, dtype=float)
    if errors.ndim != 2 or x_norm.shape != errors.shape[:1]:
        raise ValueError(f"errors must be (K+1, N) and x_norm (K+1,), got {errors.shape} "
                         f"and {x_norm.shape}")
    return errors / np.maximum(x_norm, floor)[:, None]


def steps_to_epsilon(rel: np.ndarray, eps: float) -> float:
    """First ``k`` from which ``max_i rel[k', i] <= eps`` for all ``k' >= k``.

    Parameters
    ----------
    rel : (K + 1, N) array
        Relative errors; non-finite entries count as above ``eps``.
    eps : float
        Threshold, > 0.

    Returns
    -------
    float
        The step (as a float) or NaN when the last step is still above ``eps``.
    """
    if eps <= 0:
        raise ValueError(f"eps must be > 0, got {eps}")
    worst = np.max(np.where(np.isfinite(rel), rel, np.inf), axis=1)
    above = np.nonzero(~(worst <= eps))[0]
    if above.size == 0:
        return 0.0
    if above[-1] == worst.shape[0] - 1:
        return float("nan")
    return float(above[-1] + 1)


def aoi_statistics(aoi: np.ndarray | None, own: np.ndarray | None = None
                   ) -> dict[str, float]:
    """Age-of-information statistics of ``tau`` (``(K + 1, N, M)``, ``-1`` = omega).

    Only the entries of other agents' substates count (a source's own index is always
    0). Returns ``aoi_mean``, ``aoi_max`` over finite entries and ``aoi_omega_frac``; NaN
    when ``aoi`` is None or no entry counts (a single agent).

    Parameters
    ----------
    aoi : (K + 1, N, M) int array or None
    own : (N,) int array, optional
        Column of agent ``i``'s own substate (``-1``: none); default the diagonal, which
        needs ``M = N``.
    """
    nan = {"aoi_mean": float("nan"), "aoi_max": float("nan"), "aoi_omega_frac": float("nan")}
    if aoi is None:
        return nan
    aoi = np.asarray(aoi)
    if aoi.ndim != 3:
        raise ValueError(f"aoi must have shape (K+1, N, M), got {aoi.shape}")
    N, M = aoi.shape[1:]
    if own is None:
        if M != N:
            raise ValueError(f"aoi of shape {aoi.shape} has M != N columns: pass own")
        own = np.arange(N)
    own = np.asarray(own, dtype=np.int64)
    if own.shape != (N,) or own.max(initial=-1) >= M or own.min(initial=-1) < -1:
        raise ValueError(f"own must hold N = {N} columns in -1..{M - 1}, got {own.tolist()}")
    others = np.ones((N, M), dtype=bool)
    has = own >= 0
    others[np.flatnonzero(has), own[has]] = False
    if not others.any():
        return nan
    off = aoi[:, others]
    finite = off[off >= 0]
    return {
        "aoi_mean": float(finite.mean()) if finite.size else float("nan"),
        "aoi_max": float(finite.max()) if finite.size else float("nan"),
        "aoi_omega_frac": float(np.mean(off < 0)),
    }


def episode_metrics(rec: EpisodeRecord, eps: float = 1e-2) -> dict[str, float]:
    """Reduce one :class:`EpisodeRecord` to the metrics listed in the module docstring."""
    rel = rec.relative_errors()
    K = rel.shape[0] - 1
    if K < 1:
        raise ValueError("an episode needs at least one step")
    out = {
        "mean_rel_error": float(np.mean(rel[1:])),
        "final_rel_error": float(np.mean(rel[-1])),
        "steps_to_eps": steps_to_epsilon(rel, eps),
        "msgs_per_agent_step": (float(np.mean(rec.messages)) if rec.messages is not None
                                else float("nan")),
        "reward": (float(np.mean(np.sum(rec.rewards, axis=0))) if rec.rewards is not None
                   else float("nan")),
    }
    out.update(aoi_statistics(rec.aoi, rec.own))
    return {m: out[m] for m in METRICS}


# ------------------------------------------------------------------- centralized oracle
class CentralizedKF:
    """Centralized Kalman one-step predictor on the stacked ``y = C x + v`` (the oracle).

    At step ``k`` it updates with every agent's measurement ``y_i[k]`` that arrived and
    predicts ``x_hat[k+1|k] = A x_hat[k|k]`` — the same information timing as the
    distributed agents (whose estimate of ``x[k+1]`` uses measurements up to ``k``) but
    with no network in between, so its error is a lower bound. Covariances come from the
    plant's noise models; a noise-free plant gets ``jitter`` so the filter stays well
    posed (it then acts like a near-deadbeat centralized observer).

    With ``batch_size=B`` it runs ``B`` independent filters (one per member of a
    :class:`netsense.envcore.BatchedCore`) as stacked arrays: members whose arrived
    measurements coincide share one stacked update, and every member computes exactly
    what a single filter computes on its data.

    Parameters
    ----------
    plant : netsense.systems.Plant
    x0_std : float
        Prior ``x[0] ~ N(0, x0_std^2 I)`` (the scenario's initial-state law).
    jitter : float
        Covariance floor for noise-free plants.
    batch_size : int, optional
        ``B`` filters; then :attr:`x` is ``(B, n)``, :attr:`P` ``(B, n, n)`` and
        :meth:`step` takes ``(B, N, r_max)`` measurements. Default: one filter with
        unbatched shapes.
    """

    def __init__(self, plant, *, x0_std: float = 1.0, jitter: float = 1e-9,
                 batch_size: int | None = None) -> None:
        if batch_size is not None and (isinstance(batch_size, bool) or int(batch_size) < 1
                                       or int(batch_size) != batch_size):
            raise ValueError(f"batch_size must be an integer >= 1 or None, got {batch_size!r}")
        self.A = np.asarray(plant.A, dtype=float)
        W = plant.W_effective
        self.Qw = max(_noise_variance(plant.process_noise), jitter) * (W @ W.T)
        self.C_pad = plant.C_padded  # (N, r_max, n)
        self.rows = plant.output_mask  # (N, r_max)
        self.r_var = max(_noise_variance(plant.measurement_noise), jitter)
        n = self.A.shape[0]
        self.batch_size = None if batch_size is None else int(batch_size)
        B = self.batch_size or 1
        self._x = np.zeros((B, n))
        self._P = np.repeat((max(x0_std, jitter) ** 2 * np.eye(n))[None], B, axis=0)

    @property
    def x(self) -> np.ndarray:
        """Prediction of ``x[k]``: ``(n,)``, or ``(B, n)`` when batched (a view)."""
        return self._x if self.batch_size is not None else self._x[0]

    @property
    def P(self) -> np.ndarray:
        """Its covariance: ``(n, n)``, or ``(B, n, n)`` when batched (a view)."""
        return self._P if self.batch_size is not None else self._P[0]

    @property
    def estimate(self) -> np.ndarray:
        """Copy of the current prediction of ``x[k]`` (shape of :attr:`x`)."""
        return self.x.copy()

    def step(self, y_padded: np.ndarray, arrived: np.ndarray | None = None,
             members: np.ndarray | None = None) -> np.ndarray:
        """Update with ``y[k]`` (rows of the ``arrived`` agents) and predict ``x[k+1]``.

        Parameters
        ----------
        y_padded : (N, r_max) array, or (B, N, r_max) when batched
        arrived : (N,) bool, or (B, N) when batched, optional
            Agents whose ``y_i[k]`` arrived (default all).
        members : (B,) bool, optional
            Batched only: advance just these filters (the others are left as they are,
            e.g. members whose episode already ended).

        Returns
        -------
        array
            :attr:`x`, the new prediction.
        """
        B, (N, r) = self._x.shape[0], self.rows.shape
        y = np.asarray(y_padded, dtype=float)
        arr = None if arrived is None else np.asarray(arrived, dtype=bool)
        if self.batch_size is None:
            if members is not None:
                raise ValueError("members needs a batched filter (batch_size=B)")
            y = y[None]
            arr = None if arr is None else arr[None]
        if y.shape != (B, N, r) or (arr is not None and arr.shape != (B, N)):
            lead = () if self.batch_size is None else (B,)
            raise ValueError(f"y_padded must have shape {lead + (N, r)} and arrived "
                             f"{lead + (N,)}, got {np.shape(y_padded)} and "
                             f"{None if arrived is None else np.shape(arrived)}")
        use = (np.broadcast_to(self.rows, (B, N, r)) if arr is None
               else self.rows & arr[..., None])
        if members is None:
            live = np.arange(B)
        else:
            sel = np.asarray(members, dtype=bool)
            if sel.shape != (B,):
                raise ValueError(f"members must have shape ({B},), got {sel.shape}")
            live = np.flatnonzero(sel)
        if live.size == 0:
            return self.x
        # members with the same measurement rows share one stacked update
        pattern = use[live].reshape(live.size, -1)
        if (pattern == pattern[:1]).all():
            groups = [live]
        else:
            _, inv = np.unique(pattern, axis=0, return_inverse=True)
            inv = inv.reshape(-1)
            groups = [live[inv == g] for g in range(int(inv.max()) + 1)]
        for g in groups:
            self._update(g, use[g[0]], y[g])
        x, P = self._x[live], self._P[live]
        x = (self.A @ x[..., None])[..., 0]
        P = self.A @ P @ self.A.T + self.Qw
        self._x[live] = x
        self._P[live] = 0.5 * (P + np.swapaxes(P, -1, -2))
        return self.x

    def _update(self, g: np.ndarray, use: np.ndarray, y: np.ndarray) -> None:
        """Measurement update of filters ``g`` whose measurement rows are ``use``."""
        C = self.C_pad[use]  # (m, n)
        if not C.shape[0]:
            return
        x, P = self._x[g], self._P[g]
        S = C @ P @ C.T + self.r_var * np.eye(C.shape[0])
        K = np.swapaxes(np.linalg.solve(S, C @ P), -1, -2)  # (G, n, m)
        innov = y[:, use] - (C @ x[..., None])[..., 0]
        x = x + (K @ innov[..., None])[..., 0]
        I_KC = np.eye(x.shape[-1]) - K @ C
        P = I_KC @ P @ np.swapaxes(I_KC, -1, -2) + self.r_var * K @ np.swapaxes(K, -1, -2)
        self._x[g], self._P[g] = x, P


def _noise_variance(model) -> float:
    d = model.to_dict()
    if d.get("kind") == "gaussian":
        return float(d["std"]) ** 2
    if d.get("kind") == "uniform":
        return float(d["half_width"]) ** 2 / 3.0
    return 0.0


# ---------------------------------------------------------------------------- rollouts
class NotApplicable(ValueError):
    """A policy that does not apply to a scenario (e.g. tree consensus on random graphs)."""


def _make_env(scenario: str, overrides: dict | None):
    from netsense.scenarios import make

    return make(scenario, **dict(overrides or {}))


#: Benchmark policy name -> name in :mod:`netsense.policies`.
_SCRIPTED = {"freshness": "freshness", "uniform_consensus": "uniform",
             "tree_consensus": "tree", "open_loop": "open_loop", "random": "random"}


def scripted_policy(name: str, env, seed: int | Sequence[int]):
    """The scripted policy ``name`` (a benchmark name) of :mod:`netsense.policies`.

    Parameters
    ----------
    name : str
        One of :data:`SCRIPTED_POLICIES`.
    env : netsense.env.NetSenseEnv or netsense.envcore.BatchedCore
    seed : int or sequence of int
        Seeds ``random`` (a sequence: one generator per batch member, see
        :class:`netsense.policies.RandomPolicy`); unused by the other policies.

    Raises
    ------
    NotApplicable
        ``tree_consensus`` on a scenario without a periodic graph schedule.
    """
    from netsense.policies import make_policy

    if name not in _SCRIPTED:
        raise ValueError(f"unknown scripted policy {name!r}; choose from "
                         f"{', '.join(SCRIPTED_POLICIES)}")
    kwargs = {"seed": seed} if name == "random" else {}
    try:
        return make_policy(_SCRIPTED[name], env, **kwargs)
    except ValueError as exc:
        if name == "tree_consensus":  # needs a periodic graph schedule
            raise NotApplicable(str(exc)) from exc
        raise


def rollout(scenario: str, policy: str, seed: int, overrides: dict | None = None
            ) -> EpisodeRecord:
    """One episode of ``scenario`` under ``policy`` through the PettingZoo API.

    The true state, every estimate and the freshness indices are read from the
    environment's core after each step (``env.core``); transmissions are the transmit
    bits the agents chose. :func:`netsense.vector.rollout_seeds` is the batched
    counterpart (one run for many seeds, the same record per seed).
    """
    env = _make_env(scenario, overrides)
    core = env.core
    learned = policy.startswith("learned")
    if learned:
        from netsense.rl.sb3 import LearnedPolicy
        from netsense.rl.wrappers import MaskedFlatObs

        path = policy.split(":", 1)[1] if ":" in policy else None
        if not path:
            raise ValueError("the learned policy needs a path: learned:PATH")
        agent_env = MaskedFlatObs(env)
        model = LearnedPolicy(path)

        def act(o, i):
            return model.act(o, agent_env)
    else:
        agent_env = env
        pol = scripted_policy(policy, env, seed)

        def act(o, i):
            return pol.act_dict(env, o, i)
    obs, infos = agent_env.reset(seed=seed)
    rec = EpisodeRecorder(env.model.reward.error_floor)
    rec.state(core)
    while env.agents:
        actions = act(obs, infos)
        obs, rew, term, trunc, infos = agent_env.step(actions)
        rec.state(core)
        rec.step(core.transmit, [[rew[a] for a in env.possible_agents]])
    return rec.records()[0]


def rollout_oracle(scenario: str, seed: int, overrides: dict | None = None) -> EpisodeRecord:
    """The centralized KF on the same realisation (same seed) as the policies see.

    The environment is stepped with the always-valid "keep everything, stay silent"
    action just to advance the plant and draw the measurements; only ``x[k]`` and
    ``y[k]`` are used. ``rollout_seeds(scenario, "kf_oracle", seeds)`` of
    :mod:`netsense.vector` runs many seeds as one batch with the same records.
    """
    env = _make_env(scenario, overrides)
    core = env.core
    kf = CentralizedKF(env.model.plant, x0_std=env.model.x0_std, batch_size=1)
    env.reset(seed=seed)
    idle = {a: np.zeros(core.M + 1, dtype=np.int64) for a in env.possible_agents}
    rec = EpisodeRecorder(env.model.reward.error_floor, network=False)
    while True:
        rec.state(core, kf.x[:, None, :])
        if not env.agents:
            break
        kf.step(core.y, core.y_arrived)
        env.step(idle)
    return rec.records()[0]


# ---------------------------------------------------------------------------- runners
def _result(job: Job, rec: EpisodeRecord) -> dict:
    """The result dict of ``job`` from its record (shared by every backend)."""
    rel = rec.relative_errors()
    return {"job": asdict(job), "metrics": episode_metrics(rec, job.eps),
            "curve": np.mean(rel, axis=1)}


def run_job(job: Job) -> dict | None:
    """Run one episode; returns ``{"job": ..., "metrics": ..., "curve": ...}``.

    ``curve`` is the mean-over-agents relative error per step (for the plots); None when
    the policy does not apply to the scenario. Module level so that worker processes and
    Ray tasks can import it.
    """
    try:
        if job.policy == "kf_oracle":
            rec = rollout_oracle(job.scenario, job.seed, job.overrides)
        else:
            rec = rollout(job.scenario, job.policy, job.seed, job.overrides)
    except NotApplicable:
        return None
    return _result(job, rec)


#: Memory budget (bytes) of the records of one batch of the batched backend; larger
#: groups of seeds run as several batches (e.g. 16 seeds of a 100-agent, 200-step
#: scenario, whose freshness indices alone take 16 MB per episode).
BATCH_BYTES = 256 * 2**20


def _members_per_batch(model) -> int:
    """Seeds per batch so that the records of one batch stay within :data:`BATCH_BYTES`."""
    N, K = model.plant.num_agents, int(model.horizon)
    per_member = (K + 1) * (8 * N * N + 8 * N + 8) + K * 9 * N  # indices, errors, ...
    return max(1, BATCH_BYTES // per_member)


def run_batched(jobs: Sequence[Job], *, runner: Callable[[Job], dict | None] = run_job,
                on_done: Callable[[int], object] | None = None) -> list[dict | None]:
    """Run ``jobs`` as batched simulations, one per (scenario, policy, overrides) group.

    The seeds of a group run as one :func:`netsense.vector.rollout_seeds` batch (split
    into batches whose records fit :data:`BATCH_BYTES`), so a group costs about one
    episode of Python per step instead of one per seed. Policies outside
    :data:`netsense.vector.BATCHABLE_POLICIES` (``learned``) run job by job through
    ``runner`` in this process. A group whose policy does not apply to the scenario
    (:class:`NotApplicable`) gives None for each of its jobs, as :func:`run_job` does.

    Parameters
    ----------
    jobs : sequence of Job
    runner : callable
        Per-job function for the policies that cannot batch.
    on_done : callable, optional
        Called with the number of jobs just finished (progress).

    Returns
    -------
    list of dict or None
        One entry per job, in job order, equal to ``[runner(job) for job in jobs]``
        (estimates up to the last bits of the matrix products).
    """
    from netsense.vector import BATCHABLE_POLICIES, load_model, rollout_seeds

    jobs = list(jobs)
    done = on_done or (lambda count: None)
    results: list[dict | None] = [None] * len(jobs)
    groups: list[tuple[tuple, list[int]]] = []  # overrides are dicts: compared, not hashed
    for i, job in enumerate(jobs):
        key = (job.scenario, job.policy, job.overrides)
        for k, members in groups:
            if k == key:
                members.append(i)
                break
        else:
            groups.append((key, [i]))
    for (scenario, policy, overrides), idx in groups:
        if policy not in BATCHABLE_POLICIES:
            for i in idx:
                results[i] = runner(jobs[i])
                done(1)
            continue
        model, _ = load_model(scenario, **overrides)
        size = _members_per_batch(model)
        for start in range(0, len(idx), size):
            part = idx[start:start + size]
            try:
                recs = rollout_seeds(model, policy, [jobs[i].seed for i in part])
            except NotApplicable:
                done(len(idx) - start)  # the whole group is skipped
                break
            for i, rec in zip(part, recs, strict=True):
                results[i] = _result(jobs[i], rec)
            done(len(part))
    return results


def _progress(total: int, desc: str, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, disable=not enabled, unit="ep")


#: Backends of :func:`execute`.
BACKENDS = ("batched", "process", "serial", "ray")


def execute(jobs: Sequence[Job], *, backend: str = "batched", workers: int | None = None,
            ray_address: str | None = None, progress: bool = True,
            runner: Callable[[Job], dict | None] = run_job) -> list[dict]:
    """Run ``jobs`` and return their results in job order (skipping inapplicable ones).

    Parameters
    ----------
    jobs : sequence of Job
    backend : {"batched", "process", "serial", "ray"}
        ``batched``: the seeds of each (scenario, policy, overrides) as one batched run
        in this process (:func:`run_batched`; learned policies episode by episode);
        ``process``: one episode per job in worker processes; ``serial``: one episode per
        job in this process; ``ray``: one episode per job as Ray tasks. All return the
        same results (batched: estimates up to the last bits of the matrix products).
    workers : int, optional
        Process count of ``process`` (default ``min(len(jobs), os.cpu_count())``); the
        other backends ignore it.
    ray_address : str, optional
        ``ray.init(address=...)`` (e.g. ``"auto"`` or ``"ray://head:10001"``); default a
        local Ray instance.
    progress : bool
        Show a tqdm bar (per episode; per batch of seeds with ``batched``).
    runner : callable
        The per-job function (module level, picklable); with ``batched`` it runs only
        the jobs whose policy cannot batch.

    Returns
    -------
    list of dict
        ``{"job", "metrics", "curve"}`` per applicable job (see :func:`run_job`).
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(map(repr, BACKENDS))}, "
                         f"got {backend!r}")
    jobs = list(jobs)
    results: list[dict | None] = [None] * len(jobs)
    bar = _progress(len(jobs), f"benchmark ({backend})", progress)
    try:
        if backend == "batched":
            results = run_batched(jobs, runner=runner, on_done=bar.update)
        elif backend == "serial" or (backend == "process" and (workers or 2) <= 1):
            for i, job in enumerate(jobs):
                results[i] = runner(job)
                bar.update()
        elif backend == "process":
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor, as_completed

            n = workers or min(len(jobs), os.cpu_count() or 1)
            ctx = mp.get_context("spawn")
            with ProcessPoolExecutor(max_workers=max(n, 1), mp_context=ctx,
                                     initializer=_worker_init) as pool:
                futs = {pool.submit(runner, job): i for i, job in enumerate(jobs)}
                for fut in as_completed(futs):
                    results[futs[fut]] = fut.result()
                    bar.update()
        else:
            import ray

            if not ray.is_initialized():
                ray.init(address=ray_address, include_dashboard=False,
                         ignore_reinit_error=True, log_to_driver=False)
            remote = ray.remote(num_cpus=1)(runner)
            refs = {remote.remote(job): i for i, job in enumerate(jobs)}
            pending = list(refs)
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for ref in done:
                    results[refs[ref]] = ray.get(ref)
                    bar.update()
    finally:
        bar.close()
    return [r for r in results if r is not None]


def _worker_init() -> None:
    # one thread per worker (numpy BLAS, torch if a learned policy loads it later)
    os.environ.setdefault("OMP_NUM_THREADS", "1")


# ---------------------------------------------------------------------------- reports
def aggregate(results: Iterable[dict]) -> list[dict]:
    """Mean and standard deviation over seeds per (scenario, policy), in first-seen order."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in results:
        groups.setdefault((r["job"]["scenario"], _label(r["job"]["policy"])), []).append(r)
    rows = []
    for (scenario, policy), rs in groups.items():
        row: dict = {"scenario": scenario, "policy": policy, "seeds": len(rs)}
        for m in METRICS:
            vals = np.array([r["metrics"][m] for r in rs], dtype=float)
            fin = vals[np.isfinite(vals)]
            row[f"{m}_mean"] = float(fin.mean()) if fin.size else float("nan")
            row[f"{m}_std"] = float(fin.std()) if fin.size > 1 else 0.0 if fin.size else \
                float("nan")
            if m == "steps_to_eps":
                row["reached_eps"] = int(fin.size)
        rows.append(row)
    return rows


def _label(policy: str) -> str:
    return "learned" if policy.startswith("learned") else policy


def _color(label: str) -> str:
    """The same colour for a policy in every plot and panel."""
    order = ("learned",) + SCRIPTED_POLICIES + ("kf_oracle",)
    return f"C{order.index(label) % 10}" if label in order else "k"


def write_csv(results: Sequence[dict], path: str | Path) -> Path:
    """One row per episode: scenario, policy, seed and every metric."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["scenario", "policy", "seed", *METRICS])
        for r in results:
            j = r["job"]
            w.writerow([j["scenario"], _label(j["policy"]), j["seed"],
                        *[_fmt_csv(r["metrics"][m]) for m in METRICS]])
    return path


def _fmt_csv(v: float) -> str:
    return "nan" if not math.isfinite(v) else f"{v:.6g}"


def _fmt(mean: float, std: float, digits: int = 3) -> str:
    if not math.isfinite(mean):
        return "–"
    s = f"{mean:.{digits}g}"
    if not math.isfinite(std) or std <= 1e-9 * abs(mean):  # identical up to rounding
        return s
    return f"{s} ± {std:.2g}"


def markdown_table(rows: Sequence[dict], eps: float = 1e-2) -> str:
    """The aggregated table in Markdown (mean ± std over seeds).

    ``steps to eps`` averages the seeds that reached ``eps`` (their count in brackets);
    AoI cells read ``ω`` when no index ever became finite, ``–`` when not tracked.
    """
    head = ("| scenario | policy | mean rel. error | final rel. error | "
            f"steps to {eps:g} (reached) | msgs / agent-step | mean AoI | max AoI | reward |")
    lines = [head, "|" + "---|" * 9]
    for r in rows:
        reach = f"{_fmt(r['steps_to_eps_mean'], r['steps_to_eps_std'])} " \
                f"({r['reached_eps']}/{r['seeds']})"
        cells = [r["scenario"], r["policy"],
                 _fmt(r["mean_rel_error_mean"], r["mean_rel_error_std"]),
                 _fmt(r["final_rel_error_mean"], r["final_rel_error_std"]), reach,
                 _fmt(r["msgs_per_agent_step_mean"], r["msgs_per_agent_step_std"]),
                 _aoi(r, "aoi_mean"), _aoi(r, "aoi_max"),
                 _fmt(r["reward_mean"], r["reward_std"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _aoi(row: dict, key: str) -> str:
    """AoI cell; ``ω`` when every index stayed omega (e.g. uniform averages, whose age is
    the stalest contributor's), ``–`` when AoI is not tracked (the oracle)."""
    if not math.isfinite(row[f"{key}_mean"]) and row.get("aoi_omega_frac_mean", 0) == 1:
        return "ω"
    return _fmt(row[f"{key}_mean"], row[f"{key}_std"])


def plot_errors(results: Sequence[dict], path: str | Path, scenario: str) -> Path:
    """Error vs time per policy for one scenario: median over seeds, inter-quartile band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    curves: dict[str, list[np.ndarray]] = {}
    for r in results:
        if r["job"]["scenario"] == scenario:
            curves.setdefault(_label(r["job"]["policy"]), []).append(np.asarray(r["curve"]))
    for label, cs in curves.items():
        c = np.vstack(cs)
        c = np.maximum(c, 1e-16)  # exact zeros (deadbeat) drawn at the bottom of the log axis
        k = np.arange(c.shape[1])
        med = np.median(c, axis=0)
        ax.plot(k, med, label=label, color=_color(label))
        if c.shape[0] > 1:
            ax.fill_between(k, np.percentile(c, 25, axis=0), np.percentile(c, 75, axis=0),
                            alpha=0.2, color=_color(label))
    ax.set_yscale("log")
    ax.set_xlabel("step k")
    ax.set_ylabel("relative error (mean over agents)")
    ax.set_title(scenario)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_reward_vs_messages(rows: Sequence[dict], path: str | Path) -> Path:
    """Scenario reward against messages per agent-step, one panel per scenario."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenarios = list(dict.fromkeys(r["scenario"] for r in rows))
    fig, axes = plt.subplots(1, len(scenarios), figsize=(4.2 * len(scenarios), 3.6),
                             squeeze=False)
    for ax, sc in zip(axes[0], scenarios, strict=True):
        for r in rows:
            if r["scenario"] != sc or not math.isfinite(r["reward_mean"]):
                continue
            ax.errorbar(r["msgs_per_agent_step_mean"], r["reward_mean"],
                        xerr=r["msgs_per_agent_step_std"], yerr=r["reward_std"], fmt="o",
                        label=r["policy"], capsize=3, color=_color(r["policy"]))
        ax.set_xlabel("messages per agent-step")
        ax.set_ylabel("episode reward (mean over agents)")
        ax.set_title(sc, fontsize=9)
        ax.legend(fontsize=7)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ------------------------------------------------------------------------ entry point
def make_jobs(scenarios: Sequence[str], policies: Sequence[str], seeds: Sequence[int], *,
              overrides: dict | None = None, eps: float = 1e-2) -> list[Job]:
    """Cartesian product of scenarios x policies x seeds (unknown policy names raise)."""
    for p in policies:
        if p.split(":", 1)[0] not in POLICY_NAMES:
            raise ValueError(f"unknown policy {p!r}; choose from {', '.join(POLICY_NAMES)} "
                             "(learned may be written learned:PATH)")
    if not scenarios or not policies or not seeds:
        raise ValueError("scenarios, policies and seeds must each be non-empty")
    return [Job(s, p.replace("{scenario}", s), int(seed), dict(overrides or {}), eps)
            for s in scenarios for p in policies for seed in seeds]


def run_benchmark(scenarios: Sequence[str], policies: Sequence[str] = DEFAULT_POLICIES,
                  seeds: Sequence[int] = range(5), *, out: str | Path | None = None,
                  overrides: dict | None = None, eps: float = 1e-2, backend: str = "batched",
                  workers: int | None = None, ray_address: str | None = None,
                  progress: bool = True) -> tuple[list[dict], list[dict]]:
    """Run the benchmark and (when ``out`` is given) write its CSV, table and plots.

    Writes ``episodes.csv`` (one row per episode), ``summary.csv`` and ``summary.md``
    (mean ± std over seeds), ``errors_<scenario>.png`` and ``reward_vs_messages.png``.

    Parameters
    ----------
    scenarios : sequence of str
        Scenario ids.
    policies : sequence of str
        Policy names (see the module docstring).
    seeds : sequence of int
        Seeds of every (scenario, policy).
    out : str or Path, optional
        Output directory (nothing is written without it).
    overrides : dict, optional
        Scenario overrides for every scenario.
    eps : float
        Threshold of ``steps_to_eps``.
    backend, workers, ray_address, progress
        As in :func:`execute` (default ``backend="batched"``).

    Returns
    -------
    results, rows
        Per-episode results and the aggregated rows.
    """
    jobs = make_jobs(scenarios, policies, seeds, overrides=overrides, eps=eps)
    results = execute(jobs, backend=backend, workers=workers, ray_address=ray_address,
                      progress=progress)
    rows = aggregate(results)
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        write_csv(results, out / "episodes.csv")
        with (out / "summary.csv").open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows({k: _fmt_csv(v) if isinstance(v, float) else v for k, v in r.items()}
                        for r in rows)
        (out / "summary.md").write_text(markdown_table(rows, eps))
        for sc in dict.fromkeys(scenarios):
            plot_errors(results, out / f"errors_{sc}.png", sc)
        plot_reward_vs_messages(rows, out / "reward_vs_messages.png")
    return results, rows
