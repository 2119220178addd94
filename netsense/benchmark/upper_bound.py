"""Certified upper bounds on the return of the communication tasks.

Every policy of a communication-only task (a transmit bit per agent, or one bit per agent
and substate, with the freshness rule adopting) earns, on one episode, at most the value
this module computes for that episode: decentralised, privileged, centralised, lookahead or
clairvoyant alike. It is the **perfect-information relaxation** (the realised future known:
the graphs ``G[k]``, the link arrivals, the plant and noise of the whole episode, as in
Brown, Smith and Sun, "Information relaxations and duality in stochastic dynamic programs",
*Operations Research* 58(4), 2010, with zero penalty), relaxed once more into a linear
program and solved by HiGHS (:func:`scipy.optimize.linprog`, ``method="highs"``). The
number returned is a **Lagrangian dual bound** computed from the solver's duals (any
non-negative multipliers give a valid bound, see :func:`_dual_bound`), so it does not rest
on the solver's tolerances.

The relaxation, and why each step keeps it a bound
-------------------------------------------------

1. **Error as a function of information age.** With freshness fusion an agent's estimate
   of substate ``j`` at step ``k`` is the source's own estimate of step ``k - a``
   propagated ``a`` steps, ``A_jj^a z_hat_s^{(j)}[k - a]`` (``a`` the freshness index,
   eqs. (9)-(14) of the freshness paper), or its initial estimate propagated ``k`` steps
   when it has heard nothing (index omega). Where the Lemma-1 form of the plant couples no
   other substate into ``j`` (the rows of ``A_lower`` of block ``j`` are zero), the
   source's estimate does not depend on any decision, so ``d_ij(k, a) = ||A_jj^a
   z_hat_s^{(j)}[k - a] - z_j[k]||`` is data of the episode: these substates are *exact*
   (:attr:`EpisodeData.exact`; checked on every episode by running two opposite policies
   and comparing the sources' estimates). The error of a coupled substate is bounded
   below by 0 (it is left out): on tasks whose plant couples substates (``message_cost-v0``
   and ``-v1``, ``comm_schedule-v1``) the bound is valid but loose.
2. **Ages from reachability.** ``tau_i^{(j)}[k+1] = min(tau_i^{(j)}[k], min_l
   tau_l^{(j)}[k]) + 1`` over the in-neighbours ``l`` of ``G[k]`` whose message of step
   ``k`` arrived (the engine's recursion, tested against it). With ``g[i,j,k,a] = [tau <=
   a]`` it becomes ``g[i,j,k+1,a] <= g[i,j,k,a-1] + sum_l f[l,j,k,a-1]``, ``f <= g[l]``,
   ``f <= t[l,k]``: every real policy's indicators satisfy it, fractional values are
   allowed. On a shared channel of capacity ``K`` the collision rule (every message of a
   step with more than ``K`` senders is lost) is relaxed to: at most ``K`` senders per step
   are delivered, chosen freely. Per-substate messages add ``f <= s[l,j,k] <= t[l,k]``.
3. **Monotone envelope.** The error of age ``a`` is bounded below by ``L(a) = min_{a' >=
   a} E(a')`` (omega included), non-decreasing in ``a``, so ``E(tau) >= L(tau) = L(W) -
   sum_{a < W} g_a (L(a+1) - L(a))``: linear in ``g``; ages ``>= W`` (the window) share
   the value ``L(W)``, which only loosens the bound.
4. **The norm by cutting planes.** The reward uses ``e_i = min(||z_hat_i - z|| / s_k,
   e_max)`` (:mod:`netsense.engine.rewards`, ``s_k = max(||x[k]||, floor)``). For any
   unit ``u >= 0`` and weights ``w >= 0`` summing to one, ``min(||d|| / s, e_max) >=
   sum_j min(u_j d_j / s, e_max w_j)`` (Cauchy-Schwarz, then ``min(sum_j a_j, c) >= sum_j
   min(a_j, c w_j)``), a function of each substate's age alone. Each cut ``(u, w)`` is one
   such inequality per agent and step; the first comes from the freshest ages the graphs
   allow, later ones from the previous solution's fractional ages (Kelley's cutting-plane
   loop). Every cut is valid, so every round's value is a bound.
5. **Costs** are the task's: ``message_cost`` per transmission (the last step's bit pays
   and carries nothing, so it is 0 at the optimum) and ``substate_cost`` per substate sent.

Only the first step is data rather than decision (every agent transmits at reset, so
the indices of step 1 and its error are the same under every policy).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.optimize import linprog

__all__ = ["EpisodeData", "UpperBound", "age_recursion", "episode_data", "upper_bound",
           "upper_bounds"]

#: Default age window ``W`` (ages ``>= W`` share one error value).
DEFAULT_WINDOW = 8
#: Default rounds of the cutting-plane loop.
DEFAULT_ROUNDS = 3
_NEVER = 10 ** 9  # an omega index in the integer recursion


@dataclass
class EpisodeData:
    """What the relaxation knows of one episode: its realised future.

    Attributes
    ----------
    scenario, seed :
        The episode.
    N, M, H :
        Agents, substates, horizon.
    nbr : (H, N, D) int
        In-neighbour slots of ``G[k]`` (used by the update ``k -> k + 1``), ``-1`` empty.
    arrive : (H, N, D) bool
        Whether a message sent on that slot's link at step ``k`` arrives (drops, fading).
    own : (N,) int
        Substate of which agent ``i`` is the source, ``-1`` none.
    tau1 : (N, M) int
        Freshness indices at step 1 (``-1`` omega); the same under every policy.
    err1 : float
        Team error at step 1 (mean over agents of the reward's clipped error).
    dist : (M, H + 1, H + 1) float
        ``dist[j, k, a]``: ``||A_jj^a z_hat_s^{(j)}[k - a] - z_j[k]||`` (``a <= k``).
    dist_omega : (N, M, H + 1) float
        The same for an agent that has heard nothing of ``j``.
    scale : (H + 1,) float
        ``max(||x[k]||, floor)``.
    exact : (M,) bool
        Substates whose error is a function of the age (see the module docstring).
    capacity : int or None
        Channel capacity ``K``.
    per_substate : bool
        Per-substate messages.
    error_weight, error_clip, message_cost, substate_cost : float
        The reward's constants.
    """

    scenario: str
    seed: int
    N: int
    M: int
    H: int
    nbr: np.ndarray
    arrive: np.ndarray
    own: np.ndarray
    tau1: np.ndarray
    err1: float
    dist: np.ndarray
    dist_omega: np.ndarray
    scale: np.ndarray
    exact: np.ndarray
    capacity: int | None
    per_substate: bool
    error_weight: float
    error_clip: float
    message_cost: float
    substate_cost: float
    nonempty: np.ndarray = field(default=None)  # (M,) substates with coordinates


def _run(core, seeds: Sequence[int], bits: int, record: bool):
    """Run ``core`` on ``seeds`` with every bit ``bits``; record the realisation."""
    obs, mask = core.reset(list(seeds))
    B, N = core.B, core.N
    width = mask.shape[2] // 2
    act = np.full((B, N, width), bits, dtype=np.int64)
    rec = {"nbr": [], "msg": [], "x": [core.x.copy()], "Z": [core.Z.copy()],
           "err": [], "tau": [core.tau.copy()]}
    for _ in range(core.horizon):
        if record:  # the links' own arrivals, whoever transmits (``msg`` is the
            # delivered messages: transmitted, arrived and not collided)
            nbr = core.nbr.copy()
            if core._msg_always:
                arrive = nbr >= 0
            else:
                link = core.buf_msg[np.arange(B), core.ptr]  # (B, N, N): l -> i at [i, l]
                arrive = (nbr >= 0) & np.take_along_axis(link, np.maximum(nbr, 0), axis=2)
            rec["nbr"].append(nbr)
            rec["msg"].append(arrive)
        a = act if bits == 0 else act & mask[..., 1::2].astype(np.int64)
        core.step(a)
        rec["x"].append(core.x.copy())
        rec["Z"].append(core.Z.copy())
        rec["err"].append(core.errors.copy())
        rec["tau"].append(core.tau.copy())
    return {k: np.stack(v, axis=1) for k, v in rec.items() if v}


def episode_data(scenario, seeds: Sequence[int], overrides: dict | None = None
                 ) -> list[EpisodeData]:
    """The realised future of each episode ``seeds`` of ``scenario`` (communication-only
    mode, as the protocol evaluates it).

    ``scenario`` is a scenario id (put in its communication-only mode by
    :func:`netsense.benchmark.protocol.frontier_overrides`) or a
    :class:`netsense.engine.model.CoreModel` already in one.

    Runs the episodes twice in one batched core each, all bits off and all bits on: the
    graphs, arrivals, plant and sources' estimates are read from the first, and the second
    checks that the sources' estimates of the exact substates do not depend on the
    decisions.

    Raises
    ------
    ValueError
        If the scenario has no communication-only mode, an agent holds a non-omega index
        of a substate it is not the source of at reset, or crashes silence agents.
    """
    from netsense.benchmark.protocol import frontier_overrides
    from netsense.engine.core import BatchedCore
    from netsense.env.vector import load_model

    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds must be non-empty")
    if isinstance(scenario, str):
        model, _ = load_model(scenario, **frontier_overrides(scenario, overrides))
    else:
        model, scenario = load_model(scenario)
    core = BatchedCore(model, len(seeds))
    if core.comm is None:
        raise ValueError(f"{scenario}: upper bounds need a communication-only mode")
    if core._crashes:
        raise ValueError(f"{scenario}: crashed agents are not modelled by the upper bound")
    if core.model.divergence_limit is not None:
        pass  # episodes of the communication tasks do not diverge; checked below
    off = _run(core, seeds, 0, record=True)
    on = _run(core, seeds, 1, record=False)
    N, M, H = core.N, core.M, core.horizon
    own = np.asarray(core.own)
    block_of = np.asarray(core._block_of)  # substate (column of tau) of each coordinate
    A = np.asarray(core.A_diag)
    Tinv = np.linalg.inv(core.T)
    rw = model.reward
    source_of = np.full(M, -1)
    for i, j in enumerate(own):
        if j >= 0:
            source_of[j] = i
    nonempty = np.array([(block_of == j).any() for j in range(M)])
    exact = np.array([nonempty[j] and source_of[j] >= 0
                      and not np.any(np.asarray(core.A_lower)[block_of == j]) for j in range(M)])
    out = []
    for b, seed in enumerate(seeds):
        tau0 = off["tau"][b, 0]
        for i in range(N):
            for j in range(M):
                if own[i] != j and tau0[i, j] >= 0:
                    raise ValueError(f"{scenario}: agent {i} starts with an index of "
                                     f"substate {j} it is not the source of")
        if np.any(off["x"][b] != on["x"][b]):
            raise ValueError(f"{scenario}: the plant depends on the decisions")
        z = off["x"][b] @ Tinv.T  # (H + 1, n)
        dist = np.zeros((M, H + 1, H + 1))
        dist_omega = np.zeros((N, M, H + 1))
        for j in range(M):
            cols = np.flatnonzero(block_of == j)
            if cols.size == 0:
                continue
            Ajj = A[np.ix_(cols, cols)]
            zj = z[:, cols]
            if exact[j]:
                s = source_of[j]
                zs, zs_on = off["Z"][b, :, s][:, cols], on["Z"][b, :, s][:, cols]
                if not np.allclose(zs, zs_on, rtol=0, atol=1e-9 * (1 + np.abs(zs).max())):
                    raise ValueError(f"{scenario}: the source's estimate of substate {j} "
                                     "depends on the decisions")
                P = zs.copy()  # P[k] = A^a zs[k - a] for the current a (rows k >= a)
                dist[j, :, 0] = np.linalg.norm(P - zj, axis=1)
                for a in range(1, H + 1):
                    P[a:] = P[a - 1:-1] @ Ajj.T
                    dist[j, a:, a] = np.linalg.norm(P[a:] - zj[a:], axis=1)
            for i in range(N):
                q = off["Z"][b, 0, i][cols]
                for k in range(H + 1):
                    dist_omega[i, j, k] = np.linalg.norm(q - zj[k])
                    q = Ajj @ q
        scale = np.maximum(np.linalg.norm(off["x"][b], axis=1), rw.error_floor)
        out.append(EpisodeData(
            scenario=scenario, seed=int(seed), N=N, M=M, H=H,
            nbr=off["nbr"][b].astype(np.int64), arrive=off["msg"][b].astype(bool),
            own=own, tau1=off["tau"][b, 1].astype(np.int64),
            err1=float(off["err"][b, 0].mean()), dist=dist, dist_omega=dist_omega,
            scale=scale, exact=exact, capacity=core.capacity,
            per_substate=bool(core.comm.per_substate), error_weight=rw.error_weight,
            error_clip=rw.error_clip, message_cost=rw.message_cost,
            substate_cost=rw.substate_cost, nonempty=nonempty))
    return out


def age_recursion(tau: np.ndarray, nbr: np.ndarray, arrive: np.ndarray,
                  sent: np.ndarray, own: np.ndarray) -> np.ndarray:
    """Freshness indices after one step of the freshness rule, ``(N, M)``.

    ``tau (N, M)`` (``-1`` omega), ``nbr``/``arrive (N, D)`` the slots of ``G[k]`` and
    their arrivals, ``sent (N, M)`` whether agent ``l``'s message of step ``k`` carries
    substate ``j`` (delivered: transmitted, not collided), ``own (N,)``. The recursion of
    eqs. (9)-(14): ``min(tau_i, min_l tau_l) + 1`` over the delivering in-neighbours,
    sources at 0.
    """
    t = np.where(tau < 0, _NEVER, tau)
    best = t.copy()
    N, D = nbr.shape
    for d in range(D):
        l = nbr[:, d]
        ok = (l >= 0) & arrive[:, d]
        li = np.where(ok, l, 0)
        cand = np.where(ok[:, None] & sent[li], t[li], _NEVER)
        best = np.minimum(best, cand)
    nxt = np.where(best >= _NEVER, -1, best + 1)
    for i, j in enumerate(own):
        if j >= 0:
            nxt[i, j] = 0
    return nxt


def _freshest(data: EpisodeData) -> np.ndarray:
    """``(H + 1, N, M)`` the smallest index each agent can hold at each step (every
    message delivered), ``-1`` where even that leaves omega; rows 0 unused."""
    N, M, H = data.N, data.M, data.H
    out = np.full((H + 1, N, M), -1, dtype=np.int64)
    out[1] = data.tau1
    sent = np.ones((N, M), bool)
    for k in range(1, H):
        out[k + 1] = age_recursion(out[k], data.nbr[k], data.arrive[k], sent, data.own)
    return out


@dataclass
class UpperBound:
    """One episode's bound (:func:`upper_bound`).

    ``value`` is the certified bound on the return (the Lagrangian dual bound of the last
    round); ``rounds`` the bound of each cutting-plane round; ``lp_value`` the solver's
    primal value of the last round (``<= value`` up to tolerances); ``seconds`` the time.
    """

    scenario: str
    seed: int
    value: float
    lp_value: float
    rounds: list[float]
    window: int
    mip: float | None
    variables: int
    constraints: int
    seconds: float


class _Builder:
    """Sparse rows ``A x <= b`` and variable boxes, assembled in numpy blocks."""

    def __init__(self) -> None:
        self.n = 0
        self.lo: list[np.ndarray] = []
        self.hi: list[np.ndarray] = []
        self.c: list[np.ndarray] = []
        self.rows: list[np.ndarray] = []
        self.cols: list[np.ndarray] = []
        self.vals: list[np.ndarray] = []
        self.b: list[np.ndarray] = []
        self.m = 0

    def add_vars(self, count: int, hi: np.ndarray | float = 1.0, c: np.ndarray | float = 0.0
                 ) -> np.ndarray:
        idx = np.arange(self.n, self.n + count)
        self.n += count
        self.lo.append(np.zeros(count))
        self.hi.append(np.broadcast_to(np.asarray(hi, float), (count,)).copy())
        self.c.append(np.broadcast_to(np.asarray(c, float), (count,)).copy())
        return idx

    def add_rows(self, b: np.ndarray, *entries: tuple) -> None:
        """Rows ``sum_e vals_e x[cols_e] <= b`` numbered ``0..len(b) - 1`` locally; each
        entry is ``(rows, cols, vals)`` (``vals`` a scalar or an array)."""
        for rows, cols, vals in entries:
            rows = np.asarray(rows)
            self.rows.append(rows + self.m)
            self.cols.append(np.asarray(cols))
            self.vals.append(np.broadcast_to(np.asarray(vals, float), rows.shape))
        self.b.append(np.asarray(b, float))
        self.m += len(b)

    def matrix(self):
        A = sparse.csr_matrix((np.concatenate(self.vals), (np.concatenate(self.rows),
                                                           np.concatenate(self.cols))),
                              shape=(self.m, self.n))
        return (A, np.concatenate(self.b), np.concatenate(self.c), np.concatenate(self.lo),
                np.concatenate(self.hi))


def _dual_bound(A, b, c, lo, hi, y) -> float:
    """``max c x`` over ``A x <= b, lo <= x <= hi`` is at most ``y b + sum_j max((c - A^T
    y)_j lo_j, (c - A^T y)_j hi_j)`` for every ``y >= 0`` (weak Lagrangian duality)."""
    y = np.maximum(np.asarray(y, float), 0.0)
    r = c - A.T @ y
    return float(y @ b + np.maximum(r * lo, r * hi).sum())


def upper_bound(data: EpisodeData, window: int = DEFAULT_WINDOW,
                rounds: int = DEFAULT_ROUNDS, time_limit: float | None = None) -> UpperBound:
    """The certified upper bound on the return of one episode (module docstring).

    Parameters
    ----------
    data : EpisodeData
        From :func:`episode_data`.
    window : int
        Ages ``>= window`` share one error value (smaller: faster, looser).
    rounds : int
        Cutting-plane rounds of the linear relaxation (each adds one cut per agent and
        step and re-solves).
    time_limit : float, optional
        Then the decisions (transmit bits, deliveries on a shared channel, substate bits)
        are made integral and the last round's program is solved as a mixed-integer
        program by HiGHS's branch and bound for at most this many seconds; its dual bound
        (``mip_dual_bound``, valid whether or not the search finished) replaces the linear
        relaxation's when lower.
    """
    if isinstance(window, bool) or int(window) != window or window < 2:
        raise ValueError(f"window must be an integer >= 2, got {window!r}")
    if isinstance(rounds, bool) or int(rounds) != rounds or rounds < 1:
        raise ValueError(f"rounds must be an integer >= 1, got {rounds!r}")
    if time_limit is not None and not (time_limit > 0):
        raise ValueError(f"time_limit must be > 0 seconds or None, got {time_limit!r}")
    t0 = time.perf_counter()
    W = int(window)
    amin = _freshest(data)
    lp, idx = _program(data, amin, W)
    tables = _tables(data, amin, W)
    weights = _reference_errors(data, amin)
    const = -data.error_weight * data.err1  # step 1's error, the same for every policy
    values: list[float] = []
    sol = A_mat = b_vec = c_vec = lo_v = hi_v = None
    for rnd in range(int(rounds)):
        _add_cut(lp, data, tables, weights, idx["g"], idx["e"])
        A_mat, b_vec, c_vec, lo_v, hi_v = lp.matrix()
        res = linprog(-c_vec, A_ub=A_mat, b_ub=b_vec, bounds=np.stack([lo_v, hi_v], 1),
                      method="highs")
        if res.status != 0:
            raise RuntimeError(f"{data.scenario} seed {data.seed}: HiGHS: {res.message}")
        values.append(const + _dual_bound(A_mat, b_vec, c_vec, lo_v, hi_v,
                                          -res.ineqlin.marginals))
        sol = res.x
        if rnd + 1 < rounds:
            weights = _solution_errors(data, tables, sol, idx["g"], amin)
    lp_value = const + float(c_vec @ sol)
    mip = None
    if time_limit is not None:
        from scipy.optimize import Bounds, LinearConstraint, milp

        kind = np.zeros(c_vec.size, dtype=np.uint8)
        kind[np.concatenate(idx["integral"])] = 1
        res = milp(-c_vec, integrality=kind, bounds=Bounds(lo_v, hi_v),
                   constraints=LinearConstraint(A_mat, -np.inf, b_vec),
                   options={"time_limit": float(time_limit), "disp": False})
        dual = getattr(res, "mip_dual_bound", None)
        if dual is not None and np.isfinite(dual):
            mip = const - float(dual)
            values.append(mip)
    return UpperBound(scenario=data.scenario, seed=data.seed, value=min(values),
                      lp_value=lp_value, rounds=values, window=W, mip=mip,
                      variables=int(A_mat.shape[1]), constraints=int(A_mat.shape[0]),
                      seconds=time.perf_counter() - t0)


def _program(data: EpisodeData, amin: np.ndarray, W: int) -> tuple[_Builder, dict]:
    """Variables and the constraints that do not depend on the cuts.

    ``t[k, l]`` transmit at ``k`` (the bit chosen at ``k - 1``), ``u`` delivered on a
    shared channel, ``s`` substate bits, ``g[k, i, j, a] = [tau_i^(j)[k] <= a]``,
    ``f[k, l, j, a] = [l delivers substate j of age <= a at k]``, ``e[k, i]`` the error.
    """
    N, M, H = data.N, data.M, data.H
    own, exact = data.own, data.exact
    lp = _Builder()
    integral = []
    t_idx = np.full((H, N), -1)
    t_idx[1:] = lp.add_vars((H - 1) * N, 1.0, -data.message_cost / N).reshape(H - 1, N)
    integral.append(t_idx[1:].ravel())
    carry = t_idx
    if data.capacity is not None and data.capacity < N:
        u_idx = np.full((H, N), -1)
        u_idx[1:] = lp.add_vars((H - 1) * N, 1.0, 0.0).reshape(H - 1, N)
        integral.append(u_idx[1:].ravel())
        r = np.arange((H - 1) * N)
        lp.add_rows(np.zeros(r.size), (r, u_idx[1:].ravel(), 1.0), (r, t_idx[1:].ravel(), -1.0))
        lp.add_rows(np.full(H - 1, float(data.capacity)),
                    (np.repeat(np.arange(H - 1), N), u_idx[1:].ravel(), 1.0))
        carry = u_idx
    s_idx = None
    if data.per_substate:
        s_idx = np.full((H, N, M), -1)
        s_idx[1:] = lp.add_vars((H - 1) * N * M, 1.0, -data.substate_cost / N
                                ).reshape(H - 1, N, M)
        integral.append(s_idx[1:].ravel())
        r = np.arange((H - 1) * N * M)
        lp.add_rows(np.zeros(r.size), (r, s_idx[1:].ravel(), 1.0),
                    (r, np.repeat(t_idx[1:].ravel(), M), -1.0))
    # g: pairs whose age depends on the decisions, ages amin .. W - 1, steps 2 .. H
    pair = np.zeros((N, M), bool)
    for i in range(N):
        pair[i] = exact & (np.arange(M) != own[i])
    G = np.full((H + 1, N, M, W), -1)
    ks, ii, jj = np.nonzero(pair[None] & (amin >= 0) & (amin < W))
    ks, ii, jj = ks[ks >= 2], ii[ks >= 2], jj[ks >= 2]
    for k, i, j in zip(ks, ii, jj, strict=True):
        G[k, i, j, amin[k, i, j]:] = 0
    sel = G >= 0
    G[sel] = lp.add_vars(int(sel.sum()), 1.0, 0.0)
    # f: senders with an arriving out-link at k, ages amin .. W - 2
    has_out = np.zeros((H, N), bool)
    for k in range(1, H):
        ok = (data.nbr[k] >= 0) & data.arrive[k]
        has_out[k, data.nbr[k][ok]] = True
    F = np.full((H, N, M, W), -1)
    for k in range(1, H):
        for l in np.flatnonzero(has_out[k]):
            for j in np.flatnonzero(exact):
                lo = 0 if own[l] == j else amin[k, l, j]
                if 0 <= lo < W - 1:
                    F[k, l, j, lo:W - 1] = 0
    sel = F >= 0
    F[sel] = lp.add_vars(int(sel.sum()), 1.0, 0.0)
    kk, ll, jj, aa = np.nonzero(F >= 0)
    fi = F[kk, ll, jj, aa]
    nf = fi.size
    # the sender's g (a variable from step 2 on; else a constant: 1 for the source and
    # for indices known at step 1, 0 otherwise)
    gl = np.where(kk >= 2, G[kk, ll, jj, aa], -1)
    gconst = np.zeros(nf)
    gconst[own[ll] == jj] = 1.0
    one = (kk == 1) & (own[ll] != jj)
    t1 = data.tau1[ll[one], jj[one]]
    gconst[one] = ((t1 >= 0) & (t1 <= aa[one])).astype(float)
    isv = gl >= 0
    # f <= g_l
    r = np.arange(nf)
    lp.add_rows(np.where(isv, 0.0, gconst), (r, fi, 1.0), (r[isv], gl[isv], -1.0))
    # f <= deliverer (t, or u on a channel) and f <= s with per-substate messages
    lp.add_rows(np.zeros(nf), (r, fi, 1.0), (r, carry[kk, ll], -1.0))
    bit = carry[kk, ll]
    if s_idx is not None:
        lp.add_rows(np.zeros(nf), (r, fi, 1.0), (r, s_idx[kk, ll, jj], -1.0))
        bit = s_idx[kk, ll, jj]
    # f >= g_l + bit - 1 (McCormick: f is the AND of both)
    if s_idx is not None and carry is not t_idx:  # substates on a channel: needs u and s
        pass
    else:
        lp.add_rows(np.where(isv, 1.0, 1.0 - gconst), (r[isv], gl[isv], 1.0), (r, bit, 1.0),
                    (r, fi, -1.0))
    # the recursion of the ages, for every g[k + 1, i, j, a] with a >= 1
    k1, ii, jj, aa = np.nonzero(G >= 0)
    keep = (k1 >= 2) & (aa >= 1)
    k1, ii, jj, aa = k1[keep], ii[keep], jj[keep], aa[keep]
    k0 = k1 - 1
    gi = G[k1, ii, jj, aa]
    n = gi.size
    r = np.arange(n)
    prev = G[k0, ii, jj, aa - 1]
    pv = prev >= 0
    pconst = np.zeros(n)
    at1 = k0 == 1
    t1 = data.tau1[ii[at1], jj[at1]]
    pconst[at1] = ((t1 >= 0) & (t1 <= aa[at1] - 1)).astype(float)
    links_r, links_c = [], []
    for d in range(data.nbr.shape[2]):
        lk = data.nbr[k0, ii, d]
        ok = (lk >= 0) & data.arrive[k0, ii, d]
        fv = np.where(ok, F[k0, np.where(ok, lk, 0), jj, aa - 1], -1)
        use = fv >= 0
        links_r.append(r[use])
        links_c.append(fv[use])
    lr, lc = np.concatenate(links_r), np.concatenate(links_c)
    # g[k+1, a] <= g[k, a-1] + sum_l f[l, k, a-1]
    lp.add_rows(np.where(pv, 0.0, pconst), (r, gi, 1.0), (r[pv], prev[pv], -1.0), (lr, lc, -1.0))
    # g[k+1, a] >= g[k, a-1] (what an agent holds it keeps, one step older)
    lp.add_rows(np.where(pv, 0.0, -pconst), (r, gi, -1.0), (r[pv], prev[pv], 1.0))
    # g[k+1, a] >= f[l, k, a-1] for each delivering in-neighbour (the fresher is adopted)
    m = np.arange(lr.size)
    lp.add_rows(np.zeros(lr.size), (m, lc, 1.0), (m, gi[lr], -1.0))
    # g monotone in a
    k2, i2, j2, a2 = np.nonzero(G >= 0)
    up = (a2 + 1 < W)
    k2, i2, j2, a2 = k2[up], i2[up], j2[up], a2[up]
    nxt = G[k2, i2, j2, a2 + 1]
    m = np.arange(nxt.size)
    lp.add_rows(np.zeros(nxt.size), (m, G[k2, i2, j2, a2], 1.0), (m, nxt, -1.0))
    e_idx = np.full((H + 1, N), -1)
    e_idx[2:] = lp.add_vars((H - 1) * N, data.error_clip,
                            -data.error_weight / N).reshape(H - 1, N)
    return lp, {"t": t_idx, "g": G, "f": F, "e": e_idx, "integral": integral}


def _tables(data: EpisodeData, amin: np.ndarray, W: int) -> dict:
    """Per step ``k >= 2``, agent and exact substate it is not the source of: ``(lo,
    values, tail)``: the error of each age ``lo .. W - 1`` (ages past ``k`` get the tail)
    and ``tail``, the smallest error of any possible age ``>= W`` or omega; ``lo`` is
    ``None`` when the agent cannot have heard of the substate."""
    out = {}
    for k in range(2, data.H + 1):
        for i in range(data.N):
            for j in np.flatnonzero(data.exact):
                if data.own[i] == j:
                    continue
                om = float(data.dist_omega[i, j, k])
                lo = int(amin[k, i, j])
                if lo < 0:
                    out[k, i, j] = (None, None, om)
                    continue
                older = data.dist[j, k, min(W, k + 1):k + 1]
                tail = min(om, float(older.min())) if older.size else om
                ages = np.arange(lo, W)
                vals = np.where(ages <= k, data.dist[j, k, np.minimum(ages, k)], tail)
                out[k, i, j] = (lo, vals, tail)
    return out


def _reference_errors(data: EpisodeData, amin: np.ndarray) -> np.ndarray:
    """``(H + 1, N, M)`` per-substate errors at the freshest ages (the first cut's
    direction)."""
    d = np.zeros((data.H + 1, data.N, data.M))
    for k in range(2, data.H + 1):
        for i in range(data.N):
            for j in np.flatnonzero(data.exact):
                if data.own[i] == j:
                    d[k, i, j] = data.dist[j, k, 0]
                elif amin[k, i, j] < 0:
                    d[k, i, j] = data.dist_omega[i, j, k]
                else:
                    d[k, i, j] = data.dist[j, k, amin[k, i, j]]
    return d


def _solution_errors(data: EpisodeData, tables: dict, x: np.ndarray, G: np.ndarray,
                     amin: np.ndarray) -> np.ndarray:
    """Per-substate errors under the fractional ages of a solution (the next cut's
    direction)."""
    d = _reference_errors(data, amin)
    for (k, i, j), (lo, vals, tail) in tables.items():
        if lo is None:
            continue
        if vals.size == 0:  # no age below the window is possible
            d[k, i, j] = tail
            continue
        gi = G[k, i, j, lo:]
        g = np.maximum.accumulate(np.clip(x[gi], 0.0, 1.0))
        p = np.diff(np.concatenate([[0.0], g]))
        d[k, i, j] = float(p @ vals + (1.0 - g[-1]) * tail)
    return d


def _add_cut(lp: _Builder, data: EpisodeData, tables: dict, d: np.ndarray, G: np.ndarray,
             e_idx: np.ndarray) -> None:
    """One cut per agent and step ``k >= 2``: ``e_i[k] >= sum_j V_ij(tau)`` with
    ``V(a) = min(u_j d_j(a) / s_k, e_max w_j)``, ``u ~ d``, ``w ~ u d`` (the module
    docstring, item 4), written in ``g`` as ``V(W) + sum_a g_a (V(a) - V(a + 1))``."""
    rows, cols, vals, rhs = [], [], [], []
    r = 0
    clip = data.error_clip
    ex = np.flatnonzero(data.exact)
    for k in range(2, data.H + 1):
        s = data.scale[k]
        for i in range(data.N):
            dv = np.zeros(data.M)
            dv[ex] = d[k, i, ex]
            norm = float(np.linalg.norm(dv))
            u = dv / norm if norm > 0 else np.where(data.exact, 1.0, 0.0) / math.sqrt(ex.size)
            ud = u * dv
            w = ud / ud.sum() if ud.sum() > 0 else np.where(data.exact, 1.0, 0.0) / ex.size
            const = 0.0
            rows.append(r)
            cols.append(e_idx[k, i])
            vals.append(-1.0)
            for j in ex:
                if data.own[i] == j:
                    const += min(u[j] * data.dist[j, k, 0] / s, clip * w[j])
                    continue
                lo, v, tail = tables[k, i, j]
                vt = min(u[j] * tail / s, clip * w[j])
                const += vt
                if lo is None:
                    continue
                V = np.minimum(u[j] * v / s, clip * w[j])
                coef = V - np.append(V[1:], vt)  # V(a) - V(a + 1), V(W) = tail
                gcol = G[k, i, j, lo:]
                use = coef != 0
                rows.extend([r] * int(use.sum()))
                cols.extend(gcol[use].tolist())
                vals.extend(coef[use].tolist())
            rhs.append(-const)
            r += 1
    # -e + sum_a coef_a g_a <= -const  <=>  e >= const + sum_a coef_a g_a
    lp.add_rows(np.asarray(rhs), (np.asarray(rows), np.asarray(cols), np.asarray(vals)))


def upper_bounds(scenario: str, seeds: Sequence[int], window: int = DEFAULT_WINDOW,
                 rounds: int = DEFAULT_ROUNDS, progress: bool = False) -> list[UpperBound]:
    """:func:`upper_bound` of each episode ``seeds`` of ``scenario``."""
    data = episode_data(scenario, seeds)
    it = data
    if progress:
        from tqdm import tqdm

        it = tqdm(data, desc=f"upper bound {scenario}", unit="episode")
    return [upper_bound(d, window, rounds) for d in it]


def exhaustive_optimum(scenario, seed: int, batch: int = 1 << 16) -> tuple[float, int]:
    """The best return of one episode over **every** sequence of communication bits (an
    exact optimum with the realised future known, for instances small enough: ``2^(N W
    H)`` sequences, ``W`` the bits per agent and step).

    Returns ``(best return, number of sequences)``. Each sequence is one member of a
    :class:`~netsense.engine.core.BatchedCore` seeded with ``seed`` (the realisation does
    not depend on the bits); sequence ``q`` sets bit ``(k, i, w)`` to bit ``(k N + i) W +
    w`` of ``q``.
    """
    from netsense.benchmark.protocol import frontier_overrides
    from netsense.engine.core import BatchedCore
    from netsense.env.vector import load_model

    if isinstance(scenario, str):
        model, _ = load_model(scenario, **frontier_overrides(scenario))
    else:
        model, _ = load_model(scenario)
    probe = BatchedCore(model, 1)
    _, mask = probe.reset([int(seed)])
    N, H, width = probe.N, probe.horizon, mask.shape[2] // 2
    bits = N * width * H
    if bits > 24:
        raise ValueError(f"{bits} bits per episode: 2^{bits} sequences are too many to "
                         "enumerate (at most 24)")
    total = 1 << bits
    best = -np.inf
    for start in range(0, total, batch):
        q = np.arange(start, min(total, start + batch), dtype=np.int64)
        core = BatchedCore(model, q.size)
        obs, mask = core.reset([int(seed)] * q.size)
        ret = np.zeros(q.size)
        live = np.ones(q.size, bool)
        for k in range(H):
            shift = (k * N + np.arange(N)[:, None]) * width + np.arange(width)[None, :]
            act = ((q[:, None, None] >> shift[None]) & 1).astype(np.int64)
            act &= mask[..., 1::2].astype(np.int64)  # masked bits (no estimate) are off
            out = core.step(act)
            ret[live] += out.reward.mean(1)[live]
            live &= ~(out.terminated | out.truncated)
            mask = out.action_mask
            if not live.any():
                break
        best = max(best, float(ret.max()))
    return best, total
