"""Credit assignment for messages: team, per-agent and counterfactual sender rewards.

The core's reward (:class:`netsense.engine.model.RewardConfig`, scenario section
``[reward]``) is, for agent ``i`` after the step ``k -> k + 1``,

.. math:: r_i = -w_e \\big((1 - w_t) e_i + w_t \\bar e\\big) - c\\, t_i ,

with ``e_i`` the clipped normalised error, ``\\bar e`` its mean over the agents that count
(``alive``; the others get ``-c t_i``) and ``t_i`` the transmit bit chosen at ``k``. A
learner may be trained on the reward of one of these options instead
(:data:`REWARDS`; ``netsense train --backend torchrl --reward ...``):

``scenario``
    ``r_i`` as configured.
``team``
    every agent gets the team mean, :math:`r^{team}_i = \\frac1N \\sum_l r_l`: the
    message cost is shared (``c \\bar t``) and so is the error.
``own_cost``
    the team's error and the agent's own message cost at the team's weight: the team
    reward without the other agents' costs,

    .. math:: r^{own}_i = \\frac1N \\sum_l r^{err}_l - \\frac{c\\, t_i}{N}
              = r^{team}_i + \\frac{c}{N} \\sum_{l \\ne i} t_l ,

    with :math:`r^{err}_l = -w_e((1 - w_t) e_l + w_t \\bar e)` (0 for the agents that do
    not count). The other agents' transmit bits of the same step are drawn independently
    of agent ``i``'s given the observations, so dropping them leaves the expected policy
    gradient of that step unchanged and removes their noise from ``i``'s return; the
    other agents' costs of later steps are dropped as well, which ignores how ``i``'s
    message changes their later sends (a bias; the team's error is kept whole).
    Computed from the core's reward (the costs are :math:`r^{err}_l - r_l`), so substate
    costs count as message costs.
``agent``
    individual error and own cost, :math:`r^{agent}_i = -w_e e_i - c\\, t_i` for the
    agents that count (``-c t_i`` otherwise); computed from the core's reward as
    :math:`r_i - w_e w_t (e_i - \\bar e)` so that no knowledge of the action encoding is
    needed.
``counterfactual``
    the per-agent reward plus a sender credit for the error reduction its message brought
    at the receivers that adopted it:

    .. math:: r^{cf}_i = r^{agent}_i + w_e \\sum_{(l, j) \\in \\mathcal A_i[k]}
              \\big(\\varepsilon_{l j}[k] - \\varepsilon_{i j}[k]\\big),\\qquad
              \\varepsilon_{l j}[k] = \\min\\Big(\\frac{\\|\\hat z^{(j)}_l[k] - z^{(j)}[k]\\|}
              {\\max(\\|x[k]\\|, f)}, e_{\\max}\\Big),

    where :math:`\\mathcal A_i[k]` holds the (receiver ``l``, substate ``j``) pairs in
    which ``l`` adopted the message of ``i`` at step ``k`` (eqs. (9)/(10)),
    :math:`z^{(j)}` the block of substate ``j`` in the coordinates of Lemma 1
    (``z = T^{-1} x``) and :math:`\\hat z^{(j)}_l` agent ``l``'s estimate of it. The
    credit compares what the receiver had (keep) with what it took (adopt) before the
    common propagation by ``A``; it is negative when a receiver adopted a worse estimate.
    Uniform averages (eq. (6)) credit nobody. The message adopted at ``k`` was sent on
    the transmit bit chosen at ``k - 1`` (:mod:`netsense.engine.core`, timing protocol),
    so the credit reaches the transmitting action one step late, through the discount.

``lifetime``
    the per-agent reward plus a sender credit that follows each adopted estimate over the
    steps it stays in use (a difference reward, Wolpert & Tumer): when receiver ``l``
    adopts substate ``j`` from sender ``i`` at step ``k``, the chain keeps
    :math:`\\delta_{lj} = \\hat z_l - \\hat z_i` on block ``j`` (what ``l`` would hold had it
    kept), propagated as the receiver's estimate is (eqs. (10)/(12): by the diagonal
    block of Lemma 1's ``A`` at the adoption, by the whole block-triangular matrix after
    it), and at every later step credits ``i`` with

    .. math:: e\\big(\\hat z_l[t] + \\delta_{lj}[t]\\big) - e\\big(\\hat z_l[t]\\big),

    the receiver's clipped normalised error with the kept estimate minus its error as it
    is, until ``l`` adopts substate ``j`` again (from anyone: that message would have
    replaced the kept one as well) or the episode ends. Summed over the steps this is the
    sender's share of the team's error reduction that the one-step ``counterfactual``
    credit counts only at the adoption (:class:`LifetimeCredit`).

Which slot a receiver adopted: in full control the action of substate ``j`` *is* the
adopted slot (``a_j = d + 1``); in a communication-only mode the fusion rule's choice of
the step (``core.comm.choice``) is (:func:`adopted_slots`). Only numpy here; the TorchRL
env calls these functions.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CREDITED", "REWARDS", "LifetimeCredit", "adopted_slots", "agent_reward",
           "check_adoptions", "full_control", "own_cost_reward", "sender_credit",
           "shaped_reward", "team_reward"]

#: Reward options, see the module docstring.
REWARDS = ("scenario", "team", "own_cost", "agent", "counterfactual", "lifetime")
#: The options that add a sender credit to the per-agent reward.
CREDITED = ("counterfactual", "lifetime")


def full_control(core) -> bool:
    """True when ``core.nvec`` is the full-control layout ``[D + 2] * M + [2]``."""
    nvec = np.asarray(core.nvec)
    return (nvec.size == core.M + 1 and bool(np.all(nvec[:-1] == core.D + 2))
            and int(nvec[-1]) == 2)


def adopted_slots(core, actions: np.ndarray) -> np.ndarray:
    """``(B, N, M)`` int: the slot each agent adopts per substate at this step, ``-1`` none.

    Call it before ``core.step(actions)``. In a communication-only control mode
    (``core.comm``, :class:`netsense.engine.control.CommControl`) the fusion rule has
    already chosen the adoptions of this step (``core.comm.choice``, the full mode's
    entries ``a[:M]``); a uniform fusion averages and adopts no single slot, so it has no
    sender to credit (``ValueError``). In full control ``a[..., j] = d + 1`` adopts slot
    ``d``.
    """
    check_adoptions(core)
    comm = getattr(core, "comm", None)
    a = comm.choice if comm is not None else np.asarray(actions)[..., :core.M]
    return np.where((a >= 1) & (a <= core.D), a - 1, -1)


def check_adoptions(core) -> None:
    """Raise ``ValueError`` unless :func:`adopted_slots` can tell the adoptions of
    ``core``: full control, or a communication-only mode whose fusion adopts single slots
    (not ``uniform``, which averages every message and credits nobody)."""
    comm = getattr(core, "comm", None)
    if comm is not None:
        if comm.control.fusion == "uniform":
            raise ValueError("fusion 'uniform' averages every message: no receiver adopts "
                             "one sender's slot, so the counterfactual reward has nothing "
                             "to credit (use fusion 'freshness' or 'tree')")
    elif not full_control(core):
        raise ValueError(f"action layout {list(np.asarray(core.nvec))} reports no "
                         "adoptions: the counterfactual reward needs full control or a "
                         "communication-only mode")


def team_reward(reward: np.ndarray) -> np.ndarray:
    """:math:`\\frac1N \\sum_l r_l` for every agent, ``(B, N)``."""
    return np.broadcast_to(reward.mean(axis=1, keepdims=True), reward.shape).copy()


def own_cost_reward(reward: np.ndarray, errors: np.ndarray, alive: np.ndarray,
                    error_weight: float, team_weight: float) -> np.ndarray:
    """:math:`\\frac1N \\sum_l r^{err}_l - \\mathrm{cost}_i / N`, ``(B, N)``: the team reward
    without the other agents' message costs (the ``own_cost`` option, module docstring).

    Parameters
    ----------
    reward : (B, N)
        The core's reward.
    errors : (B, N)
        Clipped normalised errors ``e_i`` of the same step.
    alive : (N,) bool
        Agents whose errors count.
    error_weight, team_weight : float
        ``w_e`` and ``w_t`` of the scenario.
    """
    alive = np.asarray(alive, bool)
    ebar = errors[:, alive].mean(axis=1, keepdims=True) if alive.any() else 0.0
    err = -error_weight * ((1.0 - team_weight) * errors + team_weight * ebar) * alive
    cost = err - reward  # c t_i (and the substate costs) per agent
    return err.mean(axis=1, keepdims=True) - cost / reward.shape[1]


def agent_reward(reward: np.ndarray, errors: np.ndarray, alive: np.ndarray,
                 error_weight: float, team_weight: float) -> np.ndarray:
    """:math:`r_i - w_e w_t (e_i - \\bar e)` on the agents that count, ``(B, N)``.

    Parameters
    ----------
    reward : (B, N)
        The core's reward.
    errors : (B, N)
        Clipped normalised errors ``e_i`` of the same step.
    alive : (N,) bool
        Agents whose errors count.
    error_weight, team_weight : float
        ``w_e`` and ``w_t`` of the scenario.
    """
    alive = np.asarray(alive, bool)
    ebar = errors[:, alive].mean(axis=1, keepdims=True) if alive.any() else 0.0
    return reward - error_weight * team_weight * (errors - ebar) * alive


def block_errors(Z: np.ndarray, x: np.ndarray, T_inv: np.ndarray, blocks: np.ndarray,
                 floor: float, clip: float) -> np.ndarray:
    """``(B, N, M)``: :math:`\\varepsilon_{l j}` of every agent and substate.

    Parameters
    ----------
    Z : (B, N, n)
        Estimates in Lemma 1 coordinates.
    x : (B, n)
        True state.
    T_inv : (n, n)
        ``T^{-1}`` (``z = T^{-1} x``).
    blocks : (n, M)
        One-hot: coordinate ``c`` belongs to substate ``j``.
    floor, clip : float
        ``f`` and ``e_max`` of the scenario.
    """
    z = x @ T_inv.T
    sq = (Z - z[:, None, :]) ** 2
    scale = np.maximum(np.linalg.norm(x, axis=1), floor)[:, None, None]
    eps = np.sqrt(sq @ blocks) / scale
    return np.where(np.isfinite(eps), np.minimum(eps, clip), clip)


def sender_credit(eps: np.ndarray, adopted: np.ndarray, nbr: np.ndarray,
                  alive: np.ndarray) -> np.ndarray:
    """``(B, N)``: :math:`\\sum_{(l, j) \\in \\mathcal A_i} (\\varepsilon_{lj} -
    \\varepsilon_{ij})` per sender ``i``.

    Parameters
    ----------
    eps : (B, N, M)
        :func:`block_errors` at step ``k``.
    adopted : (B, N, M) int
        :func:`adopted_slots` (``-1``: no adoption).
    nbr : (B, N, D) int
        In-neighbour of each slot at ``k`` (``-1``: empty).
    alive : (N,) bool
        Receivers whose errors count (others give no credit).
    """
    B, N, M = eps.shape
    b, l, j = np.nonzero((adopted >= 0) & np.asarray(alive, bool)[None, :, None])
    sender = nbr[b, l, adopted[b, l, j]]
    ok = sender >= 0
    b, l, j, sender = b[ok], l[ok], j[ok], sender[ok]
    gain = eps[b, l, j] - eps[b, sender, j]
    out = np.zeros((B, N))
    np.add.at(out, (b, sender), gain)
    return out


def shaped_reward(option: str, reward: np.ndarray, errors: np.ndarray, alive: np.ndarray,
                  error_weight: float, team_weight: float,
                  credit: np.ndarray | None = None) -> np.ndarray:
    """The reward of ``option`` (:data:`REWARDS`) from the core's reward, ``(B, N)``.

    ``credit`` (:func:`sender_credit`, :meth:`LifetimeCredit.after`) is required for the
    options of :data:`CREDITED`.
    """
    if option == "scenario":
        return reward
    if option == "team":
        return team_reward(reward)
    if option == "own_cost":
        return own_cost_reward(reward, errors, alive, error_weight, team_weight)
    if option not in REWARDS:
        raise ValueError(f"reward must be one of {REWARDS}, got {option!r}")
    out = agent_reward(reward, errors, alive, error_weight, team_weight)
    if option in CREDITED:
        if credit is None:
            raise ValueError(f"the {option} reward needs the sender credit")
        out = out + error_weight * credit
    return out


class LifetimeCredit:
    """The sender credit of the ``"lifetime"`` reward (module docstring), kept per batch
    member across steps.

    Call :meth:`before` with the actions before ``core.step``, :meth:`after` after it
    (it returns the ``(B, N)`` credit of that step) and :meth:`restart` for the members
    whose episodes start again. Only the receivers in ``alive`` give credit.
    """

    def __init__(self, core, alive: np.ndarray) -> None:
        check_adoptions(core)
        B, N, M, n = int(core.B), int(core.N), int(core.M), int(core.n)
        col = np.full(N, -1)
        col[np.asarray(core.sources)] = np.arange(M)
        cols = col[np.asarray(core.block_of)]  # the substate of every coordinate
        self._block = np.zeros((M, n))
        self._block[cols[cols >= 0], np.flatnonzero(cols >= 0)] = 1.0
        self._diag_T = np.asarray(core.A_diag, float).T
        self._full_T = (np.asarray(core.A_diag, float) + np.asarray(core.A_lower, float)).T
        self._T_inv_T = np.linalg.inv(np.asarray(core.T, float)).T
        rc = core.model.reward
        self._floor, self._clip = float(rc.error_floor), float(rc.error_clip)
        self._alive = np.asarray(alive, bool)
        #: (B, N, M, n): the kept-minus-adopted difference of each chain (0: none)
        self.delta = np.zeros((B, N, M, n))
        #: (B, N, M): the sender each chain credits, -1 none
        self.sender = np.full((B, N, M), -1, dtype=np.int64)
        self._fresh = np.zeros((B, N, M), bool)

    def restart(self, members: np.ndarray | None = None) -> None:
        """End the chains of ``members`` (a ``(B,)`` bool mask; ``None``: all)."""
        sel = slice(None) if members is None else np.asarray(members, bool)
        self.sender[sel] = -1
        self.delta[sel] = 0.0

    def before(self, core, actions: np.ndarray) -> None:
        """Start a chain for every adoption of this step (replacing the receiver's chain
        on that substate)."""
        adopted = adopted_slots(core, actions)
        b, l, j = np.nonzero((adopted >= 0) & self._alive[None, :, None])
        s = np.asarray(core.nbr)[b, l, adopted[b, l, j]]
        ok = s >= 0
        b, l, j, s = b[ok], l[ok], j[ok], s[ok]
        self._fresh[...] = False
        self._fresh[b, l, j] = True
        self.sender[b, l, j] = s
        Z = np.asarray(core.Z)
        self.delta[b, l, j] = (Z[b, l] - Z[b, s]) * self._block[j]

    def after(self, core) -> np.ndarray:
        """``(B, N)``: each sender's credit for the step just taken (errors at ``k + 1``)."""
        d = self.delta
        fresh = self._fresh  # chains adopted this step: the diagonal block only
        d[~fresh] = d[~fresh] @ self._full_T  # older chains: the whole triangular A
        if fresh.any():
            d[fresh] = d[fresh] @ self._diag_T
        x = np.asarray(core.x)
        e = np.asarray(core.Z) - (x @ self._T_inv_T)[:, None, :]  # (B, N, n)
        scale = np.maximum(np.linalg.norm(x, axis=1), self._floor)[:, None]

        def clipped(v):
            v = np.where(np.isfinite(v), v, self._clip)
            return np.minimum(v, self._clip)

        now = clipped(np.linalg.norm(e, axis=-1) / scale)  # (B, N)
        b, l, j = np.nonzero(self.sender >= 0)
        kept = clipped(np.linalg.norm(e[b, l] + d[b, l, j], axis=-1) / scale[b, 0])
        out = np.zeros(self.sender.shape[:2])
        np.add.at(out, (b, self.sender[b, l, j]), kept - now[b, l])
        return out
