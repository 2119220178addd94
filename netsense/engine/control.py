"""Control modes and the shared channel: what the agents' actions decide.

Scenario section ``[control]`` (:class:`Control`) chooses the action space:

``mode = "full"`` (default, every scenario before the communication tasks)
    per agent and substate keep / adopt slot ``d`` / average, plus the transmit bit:
    ``MultiDiscrete([D + 2] * M + [2])`` (see :mod:`netsense.engine.core`).
``mode = "transmit"``
    communication only, one bit: ``MultiDiscrete([2])``, transmit at the next step or not.
    A scripted fusion rule (``fusion``, default ``"freshness"``) does the adoption.
``mode = "substates"``
    communication only, per-substate messages: ``MultiDiscrete([2] * M)``, bit ``j`` puts
    substate ``j`` (estimate and index) in the message of the next step; a substate the
    agent has no estimate of (index omega at ``k + 1``) is masked. A neighbour's
    substate ``j`` can be adopted only if the neighbour sent ``j``
    (:func:`netsense.kernels.update.substate_messages`). Any bit set is one transmission.

The fusion rule runs **before** the agents' bits are applied, on exactly the data a
full-control policy sees: the indices ``tau[k]`` as the network reports them, the slots
and the messages of step ``k``. Its choice is the action entries ``a[:M]`` of the full
mode (``freshness``: :func:`netsense.kernels.update.freshness_choice`, eqs. (8)-(14);
``uniform``: average every substate but the own one, eq. (6); ``tree``: the BFS parent of
Fig. 2, :func:`tree_choice_table`), the bits give ``a[M]``, and the step is the full
mode's :func:`netsense.kernels.update.apply_actions`. So "fusion rule, everyone
transmits" in a communication-only mode *is* the full-control scripted policy of that
rule, bit for bit (``tests/test_comm_control.py``). ``uniform`` needs whole messages
(``mode = "transmit"``), ``tree`` a periodic graph schedule.

Scenario section ``[channel]`` (:class:`Channel`): a shared medium with capacity ``K``.
With ``S[k] = sum_i t_i[k]`` transmitters at step ``k`` (after crash silencing), every
message of step ``k`` is delivered (links permitting) when ``S[k] <= K`` and **every**
message of step ``k`` is lost when ``S[k] > K`` (a collision; the transmitters still pay
``message_cost``). So at most ``K`` agents' messages are delivered per step.

The communication-only observation appends :data:`COMM_OBS_FIELDS` to the full mode's
vector (see :class:`CommControl`), and the optional fields of :data:`COMM_OPTION_FIELDS`
where the scenario enables them (``[control] announce = true``, ``feedback = true``):

``next_out`` (``announce``, N entries)
    agent ``i``'s out-neighbours in the *next* graph ``G[k+1]``: entry ``l`` is 1 iff
    ``i -> l`` is a link of ``G[k+1]`` (the graph its next message will travel on). The
    graph sequence is drawn ahead, so announcing it changes nothing of the realisation;
    :attr:`netsense.engine.model.CoreModel.known_ahead` is then 1 (see there: a causal
    lookahead must keep ``G[k+1]`` and resample only from ``G[k+2]`` on).
``acks`` (``feedback``, N entries)
    delivery feedback on agent ``i``'s message of step ``k``: entry ``l`` is ``1`` if
    ``i -> l`` is a link of ``G[k]`` and the message arrived (sent, link up, no
    collision), ``-1`` if it is a link of ``G[k]``, ``i`` transmitted and the message was
    lost (a dropped link, e.g. a Gilbert-Elliott channel in its bad state, or a
    collision), ``0`` otherwise (no link, or ``i`` did not transmit). A sender can infer
    the state of bursty links from this history.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from netsense.kernels import update as kernels

__all__ = ["COMM_OBS_FIELDS", "COMM_OPTION_FIELDS", "FUSIONS", "MODES", "Channel",
           "CommControl", "Control", "apply_collisions", "out_links", "tree_choice_table"]

MODES = ("full", "transmit", "substates")
FUSIONS = ("freshness", "uniform", "tree")
#: Observation fields of the communication-only modes, appended after the full mode's.
COMM_OBS_FIELDS = ("news", "silence", "channel_load", "collided", "agent_id")
#: Optional fields (``N`` entries each), appended in this order when the
#: :class:`Control` option of the same line is on: ``announce`` -> ``next_out``,
#: ``feedback`` -> ``acks``.
COMM_OPTION_FIELDS = ("next_out", "acks")
#: ``g_sent`` of a substate never sent.
NEVER = np.iinfo(np.int64).min


@dataclass(frozen=True)
class Control:
    """What the agents control (scenario section ``[control]``).

    Attributes
    ----------
    mode : {"full", "transmit", "substates"}
        Full control, communication only with one transmit bit, or communication only
        with one bit per substate (the module docstring).
    fusion : {"freshness", "uniform", "tree"}
        The scripted adoption rule of the communication-only modes (unused in ``full``).
    announce : bool
        The observation at ``k`` carries the agent's out-neighbours in ``G[k+1]``
        (field ``next_out``; communication-only modes; default off).
    feedback : bool
        The observation at ``k`` carries the delivery of the agent's message of step
        ``k`` per out-link (field ``acks``; communication-only modes; default off).
    """

    mode: str = "full"
    fusion: str = "freshness"
    announce: bool = False
    feedback: bool = False

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"control.mode must be one of {MODES}, got {self.mode!r}")
        if self.fusion not in FUSIONS:
            raise ValueError(f"control.fusion must be one of {FUSIONS}, got {self.fusion!r}")
        for name in ("announce", "feedback"):
            v = getattr(self, name)
            if not isinstance(v, (bool, np.bool_)):
                raise ValueError(f"control.{name} must be true or false, got {v!r}")
            if v and self.mode == "full":
                raise ValueError(f"control.{name} adds a field of the communication-only "
                                 "observation: it needs control.mode = 'transmit' or "
                                 "'substates'")
        if self.mode == "substates" and self.fusion == "uniform":
            raise ValueError("control.fusion = 'uniform' averages whole messages: it needs "
                             "control.mode = 'transmit' (or 'full'), not 'substates'")

    @property
    def comm_only(self) -> bool:
        """True in the communication-only modes."""
        return self.mode != "full"


@dataclass(frozen=True)
class Channel:
    """A shared channel of capacity ``K`` with collisions (scenario section ``[channel]``).

    Attributes
    ----------
    capacity : int
        ``K >= 1``: when more than ``K`` agents transmit at a step, every message of that
        step is lost.
    """

    capacity: int

    def __post_init__(self) -> None:
        K = self.capacity
        if isinstance(K, bool) or not isinstance(K, (int, np.integer)) or K < 1:
            raise ValueError(f"channel.capacity must be an integer >= 1, got {K!r}")


def apply_collisions(transmit: np.ndarray, msg: np.ndarray, capacity: int,
                     collided: np.ndarray) -> None:
    """The collision rule of :class:`Channel`, in place.

    ``transmit (B, N)``: who transmits at this step; ``msg (B, N, D)``: the message table
    (cleared for every member with more than ``capacity`` transmitters); ``collided
    (B,)`` receives which members collided.
    """
    np.greater(np.count_nonzero(transmit, axis=1), capacity, out=collided)
    if collided.any():
        msg[collided] = False


def tree_choice_table(graphs, D: int, sources) -> np.ndarray:
    """``(P, N, M)`` tree-consensus choices (Fig. 2) over a periodic schedule.

    Entry ``[p, i, m]`` is the action of agent ``i`` for substate ``m`` (source
    ``sources[m]``) at steps ``k = p mod P``: ``1 + d`` for the slot ``d`` of its parent in
    the BFS tree of ``G[k]`` rooted at the source, ``0`` (keep) when it has none or is the
    source. Used by :class:`netsense.env.policies.TreeConsensusPolicy` and by the
    ``tree`` fusion rule.

    Raises
    ------
    ValueError
        If ``graphs`` is not a :class:`netsense.graphs.processes.PeriodicGraphs`.
    """
    from netsense.graphs.processes import PeriodicGraphs, in_neighbor_slots
    from netsense.observers.consensus import tree_parents

    if not isinstance(graphs, PeriodicGraphs):
        raise ValueError("the tree rule needs a PeriodicGraphs scenario (it uses the graph "
                         f"schedule), got {type(graphs).__name__}")
    adj = np.stack(graphs.graphs)  # (P, N, N)
    nbr, valid = in_neighbor_slots(adj, D)
    parent = tree_parents(adj, nbr, valid)  # (P, i, j)
    hit = nbr[:, :, None, :] == parent[..., None]  # (P, i, j, D)
    choice = np.where(hit.any(-1), np.argmax(hit, -1) + 1, 0)  # (P, N, N)
    return np.ascontiguousarray(choice[:, :, list(sources)])


class CommControl:
    """The communication-only part of a :class:`~netsense.engine.core.BatchedCore`.

    Holds, per member, what each agent's message of the current step carries
    (``sent (B, N, M)``), the generation time ``g = k - tau`` of the information it last
    sent per substate (``g_sent``), its last transmission step (``last_tx``), and the
    fusion rule's choice for the current step with the indices it leads to
    (``choice``, ``tau_next``; computed by :meth:`fuse` when a step's messages are known,
    since they do not depend on the agents' bits).

    Observation fields appended to the full mode's (``H`` the horizon, ``g_next = k + 1 -
    tau_i^{(j)}[k+1]`` the generation time of what the agent will hold when its next
    message goes out):

    ================  ====  ============================================================
    field             size  value
    ================  ====  ============================================================
    ``news``          M     ``min(g_next - g_sent, H) / H``: how much fresher the
                            information of the next message is than the last one sent;
                            1 if substate ``j`` was never sent, 0 if ``tau[k+1]`` is omega
    ``silence``       1     ``min(k - last_tx, H) / H`` (``last_tx = -1``: never sent)
    ``channel_load``  1     fraction of the agents transmitting at step ``k``
    ``collided``      1     1 if the messages of step ``k`` collided (``[channel]``)
    ``agent_id``      1     ``(i + 1) / N``: lets one shared policy break the symmetry
                            between agents (e.g. take turns on a shared channel)
    ================  ====  ============================================================

    A substate whose block of Lemma 1 is empty (``empty[m]``: a column of an agent that
    measures nothing, with ``substates = "all"``) carries nothing: it is never news, never
    sent and its bit is masked in ``"substates"`` mode.
    """

    def __init__(self, control: Control, B: int, N: int, M: int, D: int, own: np.ndarray,
                 horizon: int, tree_table: np.ndarray | None = None,
                 empty: np.ndarray | None = None) -> None:
        self.control = control
        self.per_substate = control.mode == "substates"
        self.width = M if self.per_substate else 1
        self.nvec = np.full(self.width, 2, dtype=np.int64)
        self.mask_size = 2 * self.width
        self.B, self.N, self.M, self.D = B, N, M, D
        self.own = np.asarray(own, dtype=np.int64)
        self.horizon = int(horizon)
        self.tree_table = tree_table
        self.sent = np.zeros((B, N, M), dtype=bool)
        self.g_sent = np.full((B, N, M), NEVER, dtype=np.int64)
        self.last_tx = np.full((B, N), -1, dtype=np.int64)
        self.choice = np.zeros((B, N, M), dtype=np.int64)
        self.tau_next = np.zeros((B, N, M), dtype=np.int64)
        self._own_rows = np.flatnonzero(self.own >= 0)
        #: (M,) bool: columns of empty substates (nothing to send)
        self.empty = np.zeros(M, dtype=bool) if empty is None else np.asarray(empty, bool)

    # ------------------------------------------------------------------ state
    def reset_members(self, members: np.ndarray, transmit: np.ndarray, tau: np.ndarray,
                      k: np.ndarray) -> None:
        """Forget the members' past messages; the messages of their step 0 carry every
        substate with a finite index (``initial_transmit``)."""
        self.g_sent[members] = NEVER
        self.last_tx[members] = -1
        sent = transmit[members][..., None] & ~self.empty
        if self.per_substate:
            sent &= tau[members] >= 0
        self.sent[members] = sent
        self._record(members, transmit, tau, k)

    def _record(self, members, transmit: np.ndarray, tau: np.ndarray, k: np.ndarray) -> None:
        """Bookkeeping of what the messages of step ``k`` carry (``sent`` already set)."""
        kk = k[members][:, None, None]
        got = self.sent[members] & (tau[members] >= 0)
        self.g_sent[members] = np.where(got, kk - tau[members], self.g_sent[members])
        tx = transmit[members]
        self.last_tx[members] = np.where(tx, k[members][:, None], self.last_tx[members])

    def fuse(self, tau: np.ndarray, nbr: np.ndarray, msg: np.ndarray, k: np.ndarray) -> None:
        """The fusion rule's choice for the current step and the indices it leads to.

        ``tau`` as the network reports it (a liar's claims), ``msg`` the message table
        (after link drops and collisions) of step ``k``.
        """
        fusion = self.control.fusion
        sent = self.sent if self.per_substate else None
        if fusion == "freshness":
            src, slot = kernels.freshness_choice(tau, nbr, msg, sent=sent)
            np.add(slot, 1, out=self.choice)
            self.tau_next[...] = kernels.advance_indices(tau, src, self.own)
            return
        if fusion == "uniform":
            self.choice[...] = self.D + 1
            self.choice[:, self._own_rows, self.own[self._own_rows]] = 0
            self.tau_next[...] = kernels.average_indices(tau, nbr, msg, own=self.own)
            return
        P = self.tree_table.shape[0]
        choice = self.tree_table[k % P]  # (B, N, M)
        d = np.maximum(choice - 1, 0)
        use = kernels.usable_slots(nbr, msg, sent=sent)  # (B, N, D) or (B, N, D, M)
        if sent is None:
            ok = np.take_along_axis(use, d, axis=2)
        else:
            ok = np.take_along_axis(use, d[:, :, None, :], axis=2)[:, :, 0]
        self.choice[...] = np.where((choice > 0) & ok, choice, 0)
        self.choice[:, self._own_rows, self.own[self._own_rows]] = 0
        who = np.take_along_axis(nbr, d, axis=2)
        src = np.where(self.choice > 0, who, np.arange(self.N)[None, :, None])
        self.tau_next[...] = kernels.advance_indices(tau, src, self.own)

    # ------------------------------------------------------------------ actions
    def allowed(self) -> np.ndarray:
        """``(B, N, width)`` bool: which bits may be 1 (substates with an estimate at
        ``k + 1`` in ``"substates"`` mode; always in ``"transmit"`` mode)."""
        if self.per_substate:
            return (self.tau_next >= 0) & ~self.empty
        return np.ones((self.B, self.N, 1), dtype=bool)

    def expand(self, a: np.ndarray, invalid_actions: str) -> tuple[np.ndarray, np.ndarray,
                                                                    np.ndarray]:
        """The full mode's actions ``(B, N, M + 1)`` for the bits ``a (B, N, width)``.

        Returns ``(act, bits, masked)``: the fusion rule's choices with the transmit bit
        ``any(bits)``, the bits after masking, and the masked bits. Out-of-range bits
        raise ``ValueError``, masked ones too under ``invalid_actions = "raise"`` (else
        they become 0); nothing is changed before that.
        """
        bad = (a < 0) | (a > 1)
        if bad.any():
            b, i, j = (int(v) for v in np.argwhere(bad)[0])
            what = f"substate {j}" if self.per_substate else "transmit"
            raise ValueError(f"action of agent {i} (batch member {b}) for {what} is "
                             f"{int(a[b, i, j])}, outside 0..1")
        bits = a.astype(bool)
        masked = bits & ~self.allowed()
        if masked.any():
            if invalid_actions == "raise":
                b, i, j = (int(v) for v in np.argwhere(masked)[0])
                raise ValueError(f"masked action: agent {i} (batch member {b}) sends "
                                 f"substate {j}, of which it has no estimate (index omega "
                                 f"at the next step)")
            bits &= ~masked
        act = np.empty((self.B, self.N, self.M + 1), dtype=np.int64)
        act[..., :self.M] = self.choice
        act[..., self.M] = bits.any(-1)
        return act, bits, masked

    def after_step(self, bits: np.ndarray, transmit: np.ndarray, tau: np.ndarray,
                   k: np.ndarray, reward: np.ndarray, substate_cost: float) -> None:
        """What the messages of the new step ``k`` carry, their payload cost ``c_s`` per
        substate with an estimate (subtracted from ``reward`` in place) and the
        bookkeeping of :meth:`_record`."""
        if self.per_substate:
            np.logical_and(bits, transmit[..., None], out=self.sent)
        else:
            np.logical_and(transmit[..., None], ~self.empty, out=self.sent)
        if substate_cost:
            reward -= substate_cost * np.count_nonzero(self.sent & (tau >= 0), axis=2)
        self._record(slice(None), transmit, tau, k)

    # ------------------------------------------------------------------ observations
    def fill(self, obs: np.ndarray | None, mask: np.ndarray | None, layout, k: np.ndarray,
             nbr: np.ndarray, msg: np.ndarray, transmit: np.ndarray,
             collided: np.ndarray | None, nbr_next: np.ndarray | None = None) -> None:
        """Write the communication fields of ``obs`` (after the full mode's pass) and the
        masks ``(B, N, 2 width)``; in ``"substates"`` mode a slot's substate that was not
        sent reads as no message (omega flag 1, age 0). ``nbr_next``: the slots of
        ``G[k+1]`` (needed with ``announce``)."""
        if mask is not None:
            mask[..., 0::2] = 1
            mask[..., 1::2] = self.allowed()
        if obs is None:
            return
        B, N, H = self.B, self.N, self.horizon
        if self.per_substate:
            hide = msg[..., None] & ~kernels.substate_messages(nbr, msg, self.sent)
            hide = hide.reshape(B, N, -1)
            so, sa = obs[..., layout.slot_omega], obs[..., layout.slot_age]
            so[hide] = 1.0
            sa[hide] = 0.0
        g_next = (k[:, None, None] + 1) - self.tau_next
        gain = np.minimum(g_next - np.where(self.g_sent == NEVER, 0, self.g_sent), H)
        news = np.where(self.g_sent == NEVER, 1.0, np.maximum(gain, 0) / H)
        obs[..., layout.news] = np.where((self.tau_next >= 0) & ~self.empty, news, 0.0)
        silence = np.minimum(k[:, None] - self.last_tx, H) / H
        obs[..., layout.silence] = silence[..., None]
        load = np.count_nonzero(transmit, axis=1) / N
        obs[..., layout.channel_load] = load[:, None, None]
        obs[..., layout.collided] = (0.0 if collided is None
                                     else collided[:, None, None].astype(np.float32))
        obs[..., layout.agent_id] = ((np.arange(N, dtype=np.float32) + 1) / N)[None, :, None]
        if layout.next_out is not None:
            if nbr_next is None:
                raise ValueError("announce needs the slots of the next graph (nbr_next)")
            obs[..., layout.next_out] = out_links(nbr_next, np.ones(nbr_next.shape, bool))
        if layout.acks is not None:
            sent = np.take_along_axis(transmit, np.maximum(nbr, 0).reshape(B, -1),
                                      axis=1).reshape(nbr.shape)
            obs[..., layout.acks] = out_links(nbr, np.where(msg, 1.0, np.where(sent, -1.0,
                                                                                0.0)))


def out_links(nbr: np.ndarray, value: np.ndarray) -> np.ndarray:
    """``(B, N, N)`` float32 table of the links of a graph seen from the sender: entry
    ``[b, l, i]`` is ``value[b, i, d]`` where slot ``d`` of receiver ``i`` holds ``l``
    (``nbr (B, N, D)``, ``-1`` an empty slot), 0 where ``l -> i`` is no link."""
    B, N, D = nbr.shape
    table = np.zeros((B, N + 1, N), dtype=np.float32)  # row N: the empty slots
    rows = np.where(nbr >= 0, nbr, N)
    table[np.arange(B)[:, None, None], rows, np.arange(N)[None, :, None]] = value
    return table[:, :N]
