"""Forks of the batched core (netsense.engine.fork) and the conditional redraws behind them.

A realised fork continues its members bit for bit; a resampled one keeps what is known at
step k and redraws the rest; every piece of per-member state is classified, so a new one
that a fork does not copy fails here.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from netsense.benchmark.protocol import frontier_overrides
from netsense.engine.control import CommControl
from netsense.engine.core import BatchedCore
from netsense.engine.fork import fork
from netsense.env.policies import make_policy
from netsense.env.registry import build_model, load, with_overrides
from netsense.graphs.conditional import hamiltonian_cycle, redraw_window
from netsense.graphs.processes import GraphProcess, PeriodicGraphs, RandomJointlyConnected
from netsense.sensing.drops import GilbertElliottArrivals

COMM = ["comm_process_noise-v0", "comm_substates-v0", "comm_channel_k2-v0",
        "message_cost-v0", "message_cost-v1", "comm_announced-v0", "comm_fading-v0",
        "comm_schedule-v0", "comm_schedule-v1"]
OTHERS = ["drops_kfio-v0", "link_failures-v0", "fault_stuck_sensor-v0", "fault_liar-v0",
          "fault_crash-v0", "multirate-v0", "fault_bursty_drops-v0", "delayed_equalized-v0"]

# --------------------------------------------------------------------------- classification
#: per-member state a fork copies (compared lane by lane below)
STATE = {"x", "Z", "tau", "k", "transmit", "errors", "raw_errors", "messages_sent",
         "collided", "nonfinite", "nbr", "nbr_next", "msg", "y", "y_arrived", "last_invalid",
         "_stuck_memory", "graph_state", "graph_state_prev", "meas_sampler", "msg_sampler",
         "rngs", "source", "comm"}
#: the pre-drawn chunk and its bookkeeping (positions differ with the chunk length)
CHUNK = {"buf_nbr", "buf_w", "buf_v", "buf_meas", "buf_msg", "ptr", "chunk", "_snapshots"}
#: aliases, caches and working buffers rebuilt by the core itself
SCRATCH = {"_err_buf", "_raw_buf", "_tx_buf", "_obs", "_mask", "_adjacency", "_step_bufs",
           "_turn", "_fill_bufs", "_y_load", "_ones_BN", "_bidx", "_no_v", "_no_link",
           "_seeded"}
#: model constants set at the first reset
CONSTANT = {"_claim"}
#: CommControl's per-member arrays
COMM_STATE = {"sent", "g_sent", "last_tx", "choice", "tau_next"}


def model_of(sid, **over):
    if sid in COMM:
        over = frontier_overrides(sid, over)
    return build_model(with_overrides(load(sid), **over))


def test_every_attribute_of_the_core_is_classified():
    """A new piece of state in BatchedCore or CommControl must be added to one of the
    classes above (and to the fork, if it is per-member state)."""
    B = 3
    core = BatchedCore(model_of("comm_channel_k2-v0", horizon=10), B, chunk=1)
    made_in_init = set(vars(core))
    core.reset(0)
    core.step(np.ones((B, core.N, 1), dtype=np.int64))
    known = STATE | CHUNK | SCRATCH | CONSTANT
    unknown = set(vars(core)) - made_in_init - known
    # (an attribute of __init__ sized by the batch is per-member too)
    unknown |= {a for a in made_in_init - known
                if (isinstance(v := getattr(core, a), np.ndarray) and v.shape[:1] == (B,))
                or (isinstance(v, list) and len(v) == B)}
    assert not unknown, f"classify these BatchedCore attributes in tests/test_fork.py: {unknown}"
    fresh = set(vars(CommControl(core.control, B, core.N, core.M, core.D, core.own,
                                 core.horizon)))
    per_member = {a for a, v in vars(core.comm).items()
                  if isinstance(v, np.ndarray) and v.shape[:1] == (B,)}
    assert per_member == COMM_STATE and set(vars(core.comm)) == fresh


def _same(a, b, where: str) -> None:
    """Deep equality of states (arrays, tuples, dicts, generators, plain objects)."""
    if isinstance(a, np.random.Generator):
        assert a.bit_generator.state == b.bit_generator.state, where
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), where
        for i, (u, v) in enumerate(zip(a, b, strict=True)):
            _same(u, v, f"{where}[{i}]")
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for key in a:
            _same(a[key], b[key], f"{where}[{key!r}]")
    elif hasattr(a, "__dict__") and not isinstance(a, type):
        _same(vars(a), vars(b), where)
    else:
        assert a == b, where


def _assert_lanes(fk: BatchedCore, core: BatchedCore, members, deep: bool) -> None:
    for name in ("x", "Z", "tau", "k", "transmit", "errors", "raw_errors", "messages_sent",
                 "collided", "nbr", "msg", "y", "y_arrived", "last_invalid"):
        np.testing.assert_array_equal(getattr(fk, name), getattr(core, name)[members],
                                      err_msg=name)
    assert fk.nonfinite == [core.nonfinite[b] for b in members]
    if core.nbr_next is not None:
        np.testing.assert_array_equal(fk.nbr_next, core.nbr_next[members], err_msg="nbr_next")
    for a, b in zip(fk._stuck_memory, core._stuck_memory, strict=True):
        np.testing.assert_array_equal(a, b[members])
    if core.comm is not None:
        for name in COMM_STATE:
            np.testing.assert_array_equal(getattr(fk.comm, name),
                                          getattr(core.comm, name)[members], err_msg=name)
    if deep:  # same chunk lengths: generators, graph states and samplers in step too
        fk._materialise(np.arange(fk.B))
        for lane, b in enumerate(members):
            for name in ("graph_state", "graph_state_prev", "meas_sampler", "msg_sampler"):
                _same(getattr(fk, name)[lane], getattr(core, name)[b], f"{name}[{lane}]")
            # (the "source" stream belongs to the source estimator after a reset: it
            # holds it, and the trajectory compares what it draws)
            _same({s: g for s, g in fk.rngs[lane].items() if s != "source"},
                  {s: g for s, g in core.rngs[b].items() if s != "source"}, "rngs")


def _actions(core, obs, mask, rng):
    if core.comm is not None:
        return rng.integers(0, 2, (core.B, core.N, core.nvec.size)) * mask[..., 1::2]
    return make_policy("random", core, seed=int(rng.integers(2**31))).act(obs, mask)


@pytest.mark.parametrize("sid", COMM + OTHERS)
@pytest.mark.parametrize("chunks", [(1, 1), (1, 4), (5, 3)])
def test_a_realised_fork_continues_its_members_bit_for_bit(sid, chunks):
    src_chunk, fork_chunk = chunks
    core = BatchedCore(model_of(sid, horizon=60), 3, chunk=src_chunk)
    obs, mask = core.reset(11)
    rng = np.random.default_rng(0)
    for _ in range(23):  # (after the stuck sensor's step 20: its memory is set)
        out = core.step(_actions(core, obs, mask, rng))
        obs, mask = out.obs, out.action_mask
    members = np.array([2, 0, 2, 1])
    fk = fork(core, members, chunk=fork_chunk)
    f_obs, f_mask = fk.observe()
    for _ in range(30):  # past several refills of both cores and the copy-on-refill lanes
        np.testing.assert_array_equal(f_obs, obs[members])
        np.testing.assert_array_equal(f_mask, mask[members])
        _assert_lanes(fk, core, members, deep=chunks == (1, 1))
        act = _actions(core, obs, mask, rng)
        out, f_out = core.step(act), fk.step(act[members])
        np.testing.assert_array_equal(f_out.reward, out.reward[members])
        np.testing.assert_array_equal(f_out.terminated, out.terminated[members])
        np.testing.assert_array_equal(f_out.truncated, out.truncated[members])
        obs, mask, f_obs, f_mask = out.obs, out.action_mask, f_out.obs, f_out.action_mask


def test_a_fork_of_a_fork_and_partial_resets_of_lanes():
    core = BatchedCore(model_of("comm_process_noise-v0", horizon=30), 2, chunk=1)
    obs, mask = core.reset(3)
    fk = fork(core, [1, 1, 0], chunk=4)
    fk2 = fork(fk, [2, 0], chunk=2)  # lanes 0 and 1 of fk still share a snapshot
    fk.reset(99, members=np.array([False, True, False]))  # drops lane 1's snapshot
    twin = BatchedCore(core.model, 1, chunk=1)
    twin.reset([99 + 1])
    rng = np.random.default_rng(1)
    for _ in range(12):
        act = _actions(core, obs, mask, rng)
        out = core.step(act)
        obs, mask = out.obs, out.action_mask
        np.testing.assert_array_equal(fk2.step(act[[0, 1]]).obs, obs[[0, 1]])
        f = fk.step(act[[1, 1, 0]])
        np.testing.assert_array_equal(f.obs[[0, 2]], obs[[1, 0]])
        np.testing.assert_array_equal(f.obs[1], twin.step(act[[1]]).obs[0])


# --------------------------------------------------------------------------- resampled
@pytest.mark.parametrize("sid", COMM + ["link_failures-v0", "drops_kfio-v0",
                                        "fault_bursty_drops-v0", "multirate-v0"])
def test_a_resampled_fork_keeps_step_k_and_redraws_the_future(sid):
    # ("keep": the same bits go to lanes whose futures, and so masks, differ)
    core = BatchedCore(model_of(sid, horizon=40), 2, chunk=1, invalid_actions="keep")
    obs, mask = core.reset(5)
    rng = np.random.default_rng(2)
    for _ in range(6):  # k = 6: inside a random jointly connected window (T = 2)
        out = core.step(_actions(core, obs, mask, rng))
        obs, mask = out.obs, out.action_mask
    members = np.array([0, 0, 1, 0])
    seeds = [7, 7, 7, 8]
    fk = fork(core, members, future="resampled", seeds=seeds, chunk=6)
    again = fork(core, members, future="resampled", seeds=seeds, chunk=2)
    f_obs, f_mask = fk.observe()
    np.testing.assert_array_equal(f_obs, obs[members])  # what is known at k is kept
    np.testing.assert_array_equal(f_mask, mask[members])
    _assert_lanes(fk, core, members, deep=False)
    real = fork(core, members, chunk=6)
    differs = []
    for _ in range(20):
        act = _actions(fk, f_obs, f_mask, rng)
        act[1] = act[0]
        f, g, r = fk.step(act), again.step(act), real.step(act)
        np.testing.assert_array_equal(f.obs, g.obs)  # a seed gives one future
        np.testing.assert_array_equal(f.reward, g.reward)
        np.testing.assert_array_equal(f.obs[0], f.obs[1])  # same member and seed
        differs.append(not np.array_equal(f.obs[[0, 3]], r.obs[[0, 3]]))
        f_obs, f_mask = f.obs, f.action_mask
    assert any(differs)  # ... and not the realised one
    if core._has_pnoise:  # w[k] was in the chunk but is not known at k
        assert not np.array_equal(fk.x[0], real.x[0])
    if not core._has_pnoise and core._msg_always and core._meas_always:
        # noiseless plant: only the graphs can differ, G[k+1] among them
        fresh = fork(core, [0] * 6, future="resampled", seeds=range(6), chunk=2)
        nxt = fork(core, [0], chunk=2)
        fresh.step(np.zeros((6, core.N, core.nvec.size), dtype=np.int64))
        nxt.step(np.zeros((1, core.N, core.nvec.size), dtype=np.int64))
        redrawn = [not np.array_equal(fresh.nbr[i], nxt.nbr[0]) for i in range(6)]
        # a fixed schedule is known ahead: every future has its G[k+1]
        assert any(redrawn) != isinstance(core.model.graphs, PeriodicGraphs)


def test_known_ahead_keeps_the_announced_graphs():
    core = BatchedCore(model_of("comm_process_noise-v0", horizon=30), 1, chunk=1)
    core.reset(4)
    for _ in range(4):  # k = 4: the start of a window, G[k+1] is in the graph state
        core.step(np.ones((1, core.N, 1), dtype=np.int64))
    real = fork(core, [0], chunk=8)
    a2 = fork(core, [0] * 8, future="resampled", seeds=range(8), known_ahead=2, chunk=8)
    a0 = fork(core, [0] * 8, future="resampled", seeds=range(8), chunk=8)
    for j in (1, 2):
        np.testing.assert_array_equal(a2.buf_nbr[:, j], np.repeat(real.buf_nbr[:, j], 8, 0))
    assert any(not np.array_equal(a2.buf_nbr[i, 3], real.buf_nbr[0, 3]) for i in range(8))
    assert any(not np.array_equal(a0.buf_nbr[i, 1], real.buf_nbr[0, 1]) for i in range(8))


def test_fork_refuses_bad_arguments():
    core = BatchedCore(model_of("comm_process_noise-v0", horizon=10), 2, chunk=1)
    with pytest.raises(ValueError, match="reset"):
        fork(core, [0])
    core.reset(0)
    with pytest.raises(TypeError, match="core"):
        fork("core", [0])
    for bad in ([], [2], [-1], [0.5], [[0]]):
        with pytest.raises(ValueError, match="members"):
            fork(core, bad)
    with pytest.raises(ValueError, match="future"):
        fork(core, [0], future="clairvoyant")
    with pytest.raises(ValueError, match="seeds"):
        fork(core, [0], future="resampled")
    with pytest.raises(ValueError, match="seeds"):
        fork(core, [0, 1], future="resampled", seeds=[1, 2, 3])
    with pytest.raises(ValueError, match="seeds"):
        fork(core, [0], seeds=[1])
    with pytest.raises(ValueError, match="known_ahead"):
        fork(core, [0], known_ahead=1)
    with pytest.raises(ValueError, match="known_ahead"):
        fork(core, [0], future="resampled", seeds=[1], known_ahead=-1)
    with pytest.raises(ValueError, match="chunk"):
        fork(core, [0], future="resampled", seeds=[1], known_ahead=2, chunk=2)
    long = BatchedCore(core.model, 2, chunk=8)
    long.reset(0)
    with pytest.raises(ValueError, match="chunk=1"):
        fork(long, [0], future="resampled", seeds=[1])
    x = core.x.copy()
    fork(core, [1, 0], future="resampled", seeds=[3, 4])
    np.testing.assert_array_equal(core.x, x)  # the source is untouched


# --------------------------------------------------------------------------- redraws
def _exact_window_law(N: int, T: int, p: float, pos: int, shown: np.ndarray) -> dict:
    """P(window[pos:] | window[:pos] = shown) by enumerating every window of the process
    (permutation, extra pairs, and the step of every pair)."""
    pairs = [(i, l) for i in range(N) for l in range(N) if i != l]
    law: dict = {}
    for perm in itertools.permutations(range(N)):
        cycle = {(perm[(m + 1) % N], perm[m]) for m in range(N)}  # [i, l]: l -> i
        for extra in itertools.product((0, 1), repeat=len(pairs)):
            union = {e for e, x in zip(pairs, extra, strict=True) if x} | cycle
            w_extra = np.prod([p if x else 1 - p for x in extra])
            for when in itertools.product(range(T), repeat=len(union)):
                win = np.zeros((T, N, N), dtype=bool)
                for (i, l), s in zip(sorted(union), when, strict=True):
                    win[s, i, l] = True
                if np.array_equal(win[:pos], shown):
                    key = win[pos:].tobytes()
                    law[key] = law.get(key, 0.0) + w_extra * T ** -len(union)
    total = sum(law.values())
    return {k: v / total for k, v in law.items()}


@pytest.mark.parametrize("T,pos,p", [(2, 1, 0.3), (3, 1, 0.2), (3, 2, 0.5), (2, 1, 0.0)])
def test_redrawn_window_follows_the_exact_conditional_law(T, pos, p):
    N = 3
    proc = RandomJointlyConnected(N, T, p)
    rng = np.random.default_rng(3)
    _, (_, window) = proc.sample(rng, 1, proc.initial_state(rng))  # a drawn window
    law = _exact_window_law(N, T, p, pos, window[:pos])
    draws = 20000
    counts: dict = {}
    for _ in range(draws):
        w = redraw_window(window, pos, p, rng)
        np.testing.assert_array_equal(w[:pos], window[:pos])
        counts[w[pos:].tobytes()] = counts.get(w[pos:].tobytes(), 0) + 1
    assert set(counts) <= set(law)  # nothing impossible
    probs = np.array(list(law.values()))
    tv = 0.5 * np.abs(np.array([counts.get(k, 0) for k in law]) / draws - probs).sum()
    # the total variation distance of exact draws: its 99.9 % quantile over 1000 samples
    null = 0.5 * np.abs(rng.multinomial(draws, probs, size=1000) / draws - probs).sum(1)
    assert tv <= np.quantile(null, 0.999), (tv, np.quantile(null, [0.5, 0.999]))


def test_hamiltonian_cycle_weights():
    rng = np.random.default_rng(0)
    N = 5
    only = np.zeros((N, N))
    order = [0, 3, 1, 4, 2]
    for a, b in zip(order, order[1:] + order[:1], strict=True):
        only[a, b] = 1.0
    succ = hamiltonian_cycle(only + 0.0, rng)  # a single cycle has weight
    assert all(succ[a] == b for a, b in zip(order, order[1:] + order[:1], strict=True))
    # on the complete graph every one of the (N - 1)! cycles is equally likely
    seen: dict = {}
    for _ in range(4800):
        key = tuple(hamiltonian_cycle(np.ones((N, N)), rng))
        seen[key] = seen.get(key, 0) + 1
    assert len(seen) == 24 and min(seen.values()) > 130
    with pytest.raises(ValueError, match="no Hamiltonian cycle"):
        hamiltonian_cycle(np.eye(N), rng)
    with pytest.raises(ValueError, match="N <="):
        hamiltonian_cycle(np.ones((17, 17)), rng)


class _CoinGraphs(GraphProcess):
    """G[k] drawn at random with a state that is not a function of it."""

    num_nodes = 3

    def sample(self, rng, num_steps, state):
        return rng.random((num_steps, 3, 3)) < 0.5, state


def test_redraw_state_default_and_its_refusal():
    from netsense.graphs.processes import MarkovLinkFailures

    base = ~np.eye(4, dtype=bool)
    proc = MarkovLinkFailures(base, p_fail=1.0, p_recover=1.0)  # links flip every step
    rng = np.random.default_rng(0)
    prev = proc.initial_state(rng)
    adj, state = proc.sample(rng, 1, prev)
    redrawn = proc.redraw_state(np.random.default_rng(9), state, prev, adj[0])
    np.testing.assert_array_equal(redrawn, base & ~prev)  # the law of the next state
    with pytest.raises(NotImplementedError, match="redraw_state"):
        _CoinGraphs().redraw_state(rng, 0, 0, np.zeros((3, 3), bool))


def test_gilbert_elliott_redraw_moves_on_from_the_last_state():
    ge = GilbertElliottArrivals(p_good_to_bad=1.0, p_bad_to_good=1.0, start="good")
    s = ge.sampler(np.random.default_rng(0), (6,))
    with pytest.raises(ValueError, match="drawn a step"):
        s.redraw(np.random.default_rng(1))
    s.next()
    before = s.bad.copy()
    r = s.redraw(np.random.default_rng(1))
    np.testing.assert_array_equal(r.bad, before)  # deterministic flip from "good"
    np.testing.assert_array_equal(s.bad, before)  # the sampler itself is unchanged
