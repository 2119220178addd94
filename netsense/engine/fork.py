"""Forks of a :class:`~netsense.engine.core.BatchedCore`: lanes that continue chosen members.

``fork(core, members)`` builds a new core whose lane ``l`` is a copy of member
``members[l]`` of ``core`` at its current step ``k`` (members may repeat), with one of
two futures:

``future="realised"``
    the member's own future, bit for bit: the lanes take copies of its generators, graph
    process state, arrival samplers and pre-drawn chunk, so a lane stepped with the actions
    the member gets equals the member (observations, rewards, plant, estimates, indices)
    at every later step, whatever the chunk lengths of the two cores.
``future="resampled"``
    a fresh future drawn from ``seeds[l]``: everything known at step ``k`` is kept — the
    plant state ``x[k]``, estimates, indices, the loaded ``G[k]``, ``y[k]`` and the
    messages of step ``k``, fault memories, the communication state — and everything not
    yet seen is redrawn: the process noise ``w[k]`` of the step ``k -> k + 1`` (already in
    the chunk), ``G[k+1]`` and later graphs, later measurement noise and arrivals. Where a
    process state already holds randomness about the next step (the next link states of
    Markov link failures, the rest of a random jointly connected window, the next channel
    state of a Gilbert-Elliott sampler), it is redrawn from its law given what was seen
    (:meth:`~netsense.graphs.processes.GraphProcess.redraw_state`,
    :meth:`~netsense.sensing.arrivals.ArrivalSampler.redraw`). The Markov states at ``k``
    themselves (link states of ``G[k]``, positions of mobile agents, a Gilbert-Elliott
    channel's state at ``k``) count as known: forks serve full-information references.
    ``known_ahead = a`` keeps the realised graphs of steps ``k + 1 .. k + a`` (a scenario
    that announces them) and redraws from ``k + a`` on.
    Lanes with the same member and seed get the same future (common random numbers).

A resampled fork needs the generators at step ``k``: ``core`` must be built with
``chunk=1`` (a realisation never depends on the chunk, so this changes no result). A
realised fork takes any core. The fork's own chunk (``chunk``, default: the steps to the
horizon, at most :data:`~netsense.engine.core.CHUNK`) is drawn at once, per distinct
future: lanes that share a future share its draws and copy its generators only when they
step past the chunk.

Nothing of ``core`` changes (a fork of a fork first gives the source lanes their own
generators). Cost: one :class:`BatchedCore` of ``len(members)`` lanes, the state copied by
fancy indexing, one chunk drawn per distinct future (from a copy of the member's generators
for a realised one, from fresh ones for a resampled one); the lanes copy the generators
again only if they step past the chunk.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import numpy as np

from netsense.engine.core import _STREAMS, CHUNK, BatchedCore
from netsense.graphs.processes import slot_adjacency
from netsense.kernels import checks

__all__ = ["FUTURES", "fork"]

FUTURES = ("realised", "resampled")


def _members(core: BatchedCore, members) -> np.ndarray:
    m = np.asarray(members)
    if m.ndim != 1 or m.size == 0 or m.dtype.kind not in "iu":
        raise ValueError(f"members must be a non-empty 1-d sequence of member indices, got "
                         f"{m.dtype} {m.shape}")
    if m.min() < 0 or m.max() >= core.B:
        raise ValueError(f"members must lie in 0..{core.B - 1} (the core's batch), got "
                         f"{int(m.min())}..{int(m.max())}")
    return m.astype(np.int64)


def _seed_keys(seeds, lanes: int) -> list:
    if seeds is None:
        raise ValueError("future='resampled' needs seeds: one int or SeedSequence per lane")
    if isinstance(seeds, (int, np.integer, np.random.SeedSequence)):
        seeds = [seeds] * lanes
    seeds = list(seeds)
    if len(seeds) != lanes:
        raise ValueError(f"seeds must hold one seed per lane ({lanes}), got {len(seeds)}")
    out = []
    for i, s in enumerate(seeds):
        if isinstance(s, np.random.SeedSequence):
            out.append(s)
        else:
            out.append(np.random.SeedSequence(checks.seed_value(f"seeds[{i}]", s)))
    return out


def _key(ss: np.random.SeedSequence) -> tuple:
    return (repr(ss.entropy), tuple(ss.spawn_key))


def fork(core: BatchedCore, members: Sequence[int] | np.ndarray, *, future: str = "realised",
         seeds: Sequence[int | np.random.SeedSequence] | int | None = None,
         known_ahead: int = 0, chunk: int | None = None) -> BatchedCore:
    """A core whose lane ``l`` continues member ``members[l]`` of ``core`` from its
    current step (the module docstring).

    Parameters
    ----------
    core : BatchedCore
        A core after :meth:`~BatchedCore.reset` (``chunk=1`` for resampled futures).
    members : sequence of int
        The member each lane copies; repeats allowed.
    future : {"realised", "resampled"}
        Continue the members' own future, or draw a new one from ``seeds``.
    seeds : int, SeedSequence or a sequence of them, one per lane
        The resampled futures' seeds (required for, and only for, ``"resampled"``).
    known_ahead : int
        Resampled futures: how many graphs after ``G[k]`` are known and kept.
    chunk : int, optional
        Steps the fork draws at once (at least ``known_ahead + 1``).

    Returns
    -------
    BatchedCore
        ``len(members)`` lanes at the members' step ``k``, with the core's model,
        ``invalid_actions`` and ``nonfinite`` settings.
    """
    if not isinstance(core, BatchedCore):
        raise TypeError(f"core must be a BatchedCore, got {type(core).__name__}")
    core._require_reset("fork")
    m = _members(core, members)
    checks.choice("future", future, FUTURES)
    known_ahead = checks.integer("known_ahead", known_ahead, 0)
    if future == "realised":
        if seeds is not None:
            raise ValueError("seeds are for future='resampled'; a realised fork continues "
                             "the members' own generators")
        if known_ahead:
            raise ValueError("known_ahead is for future='resampled' (a realised future "
                             "keeps everything)")
        keys = [int(b) for b in m]
        sseqs = None
    else:
        sseqs = _seed_keys(seeds, m.size)
        if core.chunk != 1:
            raise ValueError(f"a resampled fork needs the core's generators at its current "
                             f"step: build the core with chunk=1 (it has chunk={core.chunk}; "
                             "the realisation does not depend on it)")
        keys = [(int(b), _key(s)) for b, s in zip(m, sseqs, strict=True)]
    avail = core.chunk - core.ptr[m]  # source steps k .. k + avail - 1 already drawn
    if chunk is None:
        chunk = int(np.clip(core.horizon - core.k[m].min() + 1, 1, CHUNK))  # (to the end)
    chunk = checks.integer("chunk", chunk, 1)
    if chunk < known_ahead + 1:
        raise ValueError(f"chunk must be >= known_ahead + 1 = {known_ahead + 1}, got {chunk}")
    chunk = max(chunk, int(avail.max()))
    core._materialise(np.unique(m))  # (lanes of a fork get their own generators first)
    # lanes grouped by future: the first lane of each group draws, the others copy it
    first: dict = {}
    group = np.array([first.setdefault(key, i) for i, key in enumerate(keys)], dtype=np.int64)
    reps = np.flatnonzero(group == np.arange(m.size))
    new = BatchedCore(core.model, m.size, invalid_actions=core.invalid_actions, chunk=chunk,
                      nonfinite=core.nonfinite_mode)
    new._alloc()
    _copy_state(core, new, m, sseqs)
    if future == "realised":
        _realised(core, new, m, reps, avail)
    else:
        _resampled(core, new, m, reps, sseqs, known_ahead)
    # the other lanes of each group: the representative's chunk; every lane of a group
    # shares the generators the chunk was drawn with, and copies them at its first refill
    # (nothing draws from the shared ones: a fork that never refills copies nothing)
    others = np.flatnonzero(group != np.arange(m.size))
    for name in ("buf_nbr", "buf_w", "buf_v", "buf_meas", "buf_msg"):
        buf = getattr(new, name)
        if buf is not None and others.size:
            buf[others] = buf[group[others]]
    snaps = {int(r): _gen_state(new, r) for r in reps}
    for lane, r in enumerate(group):
        new._snapshots[lane] = snaps[int(r)]
    for name in ("rngs", "graph_state", "graph_state_prev", "meas_sampler", "msg_sampler"):
        setattr(new, name, [None] * m.size)
    new.ptr[:] = 0
    new._adjacency = new._mask = new._obs = None  # (built on demand)
    new._seeded = True
    return new


def _gen_state(core: BatchedCore, b: int) -> tuple:
    return (core.rngs[b], core.graph_state[b], core.graph_state_prev[b],
            core.meas_sampler[b], core.msg_sampler[b])


def _copy_state(core: BatchedCore, new: BatchedCore, m: np.ndarray, sseqs) -> None:
    """Everything of the current step but the generators and the chunk."""
    new.x[:] = core.x[m]
    new.Z[:] = core.Z[m]
    new.tau[:] = core.tau[m]
    new.k[:] = core.k[m]
    new.transmit[:] = core.transmit[m]  # (in place: the core's own output buffers)
    new.errors[:] = core.errors[m]
    new.raw_errors[:] = core.raw_errors[m]
    new.messages_sent[:] = core.messages_sent[m]
    new.collided[:] = core.collided[m]
    new.nonfinite = [None if core.nonfinite[b] is None else dict(core.nonfinite[b])
                     for b in m]
    new.nbr[:] = core.nbr[m]
    if core.nbr_next is not None:  # G[k+1], announced in the observation at k
        new.nbr_next[:] = core.nbr_next[m]
    new.msg[:] = core.msg[m]
    new.y = core.y[m].copy()
    new.y_arrived = new._ones_BN if new._meas_always else core.y_arrived[m].copy()
    if hasattr(core, "last_invalid"):
        new.last_invalid = core.last_invalid[m].copy()
    new._stuck_memory = [mem[m].copy() for mem in core._stuck_memory]
    if core.comm is not None:
        for name in ("sent", "g_sent", "last_tx", "choice", "tau_next"):
            getattr(new.comm, name)[:] = getattr(core.comm, name)[m]
    rng = None
    if sseqs is not None and core.source.uses_rng:
        src = _STREAMS.index("source")
        rng = [np.random.default_rng(s.spawn(len(_STREAMS))[src]) for s in _fresh(sseqs)]
    new.source = core.source.take(m, rng)


def _fresh(sseqs):
    """Copies of the seed sequences (``spawn`` advances a SeedSequence's child counter)."""
    return [np.random.SeedSequence(s.entropy, spawn_key=s.spawn_key) for s in sseqs]


def _copy_chunk(core: BatchedCore, new: BatchedCore, b: int, lane: int, n: int,
                streams=("buf_nbr", "buf_w", "buf_v", "buf_meas", "buf_msg")) -> None:
    """Positions ``0 .. n-1`` of lane ``lane`` from member ``b``'s current chunk."""
    p = int(core.ptr[b])
    for name in streams:
        src, dst = getattr(core, name), getattr(new, name)
        if src is not None:
            dst[lane, :n] = src[b, p:p + n]


def _realised(core, new, m, reps, avail) -> None:
    for r in reps:
        b = int(m[r])
        (new.rngs[r], new.graph_state[r], new.graph_state_prev[r], new.meas_sampler[r],
         new.msg_sampler[r]) = copy.deepcopy(_gen_state(core, b))
        _copy_chunk(core, new, b, int(r), int(avail[r]))
    for n in np.unique(avail[reps]):  # draw the rest of the chunk from the copies
        sel = reps[avail[reps] == n]
        new._draw(sel, graph=int(n), process=int(n), other=int(n))


def _resampled(core, new, m, reps, sseqs, a: int) -> None:
    model = core.model
    for r in reps:
        b = int(m[r])
        kids = _fresh([sseqs[r]])[0].spawn(len(_STREAMS))
        rngs = {name: np.random.default_rng(c) for name, c in zip(_STREAMS, kids,
                                                                   strict=True)}
        # G[k] (and the announced G[k+1..k+a]) as drawn; the state after them redrawn
        _copy_chunk(core, new, b, int(r), 1, ("buf_nbr", "buf_v", "buf_meas", "buf_msg"))
        prev, state, G = core.graph_state_prev[b], core.graph_state[b], core.adjacency[b]
        if a:
            gen = copy.deepcopy(core.rngs[b]["graph"])
            for j in range(1, a + 1):
                prev = state
                nbr, (state,) = model.graphs.sample_slots_many([gen], 1, [state], core.D)
                new.buf_nbr[r, j] = nbr[0, 0]
                G = slot_adjacency(nbr[0, 0], core.N)
        new.rngs[r] = rngs
        new.graph_state[r] = model.graphs.redraw_state(rngs["graph"], state, prev, G)
        new.graph_state_prev[r] = prev
        if not core._meas_always:
            new.meas_sampler[r] = core.meas_sampler[b].redraw(rngs["measurement_arrivals"])
        if not core._msg_always:
            new.msg_sampler[r] = core.msg_sampler[b].redraw(rngs["message_arrivals"])
    new._draw(reps, graph=a + 1, process=0, other=1)
