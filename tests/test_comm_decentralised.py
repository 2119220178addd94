"""The decentralised families added to the frontier (until, settle, aloha, tdma): each rule
against its formula on hand-made observations, decentralisation (an agent's bits never
depend on another agent's row), per-member memory, and the same numbers through the env,
the batched core and the benchmark in every mode they claim."""

from __future__ import annotations

import numpy as np
import pytest

import netsense.benchmark as bm
from netsense.benchmark.protocol import FAMILIES, evaluate, frontier_overrides
from netsense.engine.core import BatchedCore
from netsense.env.comm_decentralised import MemberUniforms, Settle, Tdma, ThresholdAloha
from netsense.env.comm_policies import CENTRALISED, COMM_POLICIES, make_comm_policy, parse_spec
from netsense.env.vector import load_model

SID = "comm_process_noise-v0"
NEW = ("until:30", "until:40,2", "settle:0.01", "settle:0.05,3", "aloha:2.2,4.69",
       "aloha:1,1", "tdma:1", "tdma:3")


def _core(sid=SID, B=3, seed=0, **over):
    model, _ = load_model(sid, **frontier_overrides(sid, over))
    core = BatchedCore(model, B)
    obs, mask = core.reset(seed)
    return core, obs, mask


def _blank(core, B=2):
    """Observations of zeros (every field decodable) and all-allowed masks."""
    obs = np.zeros((B, core.N, core.layout.size), np.float32)
    mask = np.ones((B, core.N, 2 * core.comm.width), np.int8)
    return obs, mask


def _set_time(core, obs, k):
    obs[..., core.layout.time] = np.float32(k / core.horizon)


def test_two_knob_specs_parse_with_defaults_and_bad_ones_fail():
    assert parse_spec("aloha:2.2,4.69") == ("aloha", (2.2, 4.69))
    assert parse_spec("aloha") == ("aloha", (2.2, 4.69))
    assert parse_spec("until:30") == ("until", (30, 0))
    assert parse_spec("settle:0.01") == ("settle", (0.01, 5))
    assert parse_spec("tdma") == ("tdma", 1)
    for bad in ("until", "settle", "aloha:1,2,3", "aloha:x,1", "until:3.5"):
        with pytest.raises(ValueError):
            parse_spec(bad)
    core, *_ = _core()
    for bad in ("until:-1", "settle:0", "settle:0.1,0", "aloha:-1,1", "aloha:1,0", "tdma:0"):
        with pytest.raises(ValueError):
            make_comm_policy(bad, core)
    for fam, knobs in FAMILIES.items():  # every frontier knob is a valid spec
        for k in knobs:
            parse_spec(f"{fam}:{k}")
    assert set(FAMILIES) <= set(COMM_POLICIES)


def test_until_transmits_before_T_only_and_gates_on_news():
    core, *_ = _core()
    obs, mask = _blank(core)
    H, L = core.horizon, core.layout
    news = np.zeros((2, core.N, core.M), np.float32)
    news[0, :, 0] = 3 / H
    news[1, :, 1] = 1 / H
    obs[..., L.news] = news
    for k in (0, 5, 28, 29, 30, 120):
        _set_time(core, obs, k)
        bits = make_comm_policy("until:30", core).act(obs, mask)[..., 0]
        assert (bits == (k + 1 < 30)).all()
        bits = make_comm_policy("until:30,2", core).act(obs, mask)[..., 0]
        want = (k + 1 < 30) & (np.rint(news * H) >= 2).any(-1)
        np.testing.assert_array_equal(bits, want)


def test_settle_stops_after_W_small_corrections_once_it_knows_everything():
    """``c = ||z[k] - A_bar z[k-1]|| / max(||z[k]||, 1e-3)``: agents 0 and 1 follow the
    model exactly (c = 0); agent 1 lacks a substate until k = 4; agent 2 is corrected
    at every step (c = 0.5). With W = 3 agent 0 stops sending at k = 3 (corrections at
    k = 1, 2, 3), agent 1 at k = 6, agent 2 never."""
    core, *_ = _core(B=1)
    L, n = core.layout, core.n
    pol = make_comm_policy("settle:0.1,3", core)
    assert isinstance(pol, Settle)
    A = core.model.design.decomposition.A_bar
    z = np.zeros((core.N, n))
    z[:, 0] = 1.0
    sent = []
    for k in range(9):
        obs, mask = _blank(core, B=1)
        _set_time(core, obs, k)
        obs[0, 1, L.own_omega.start] = 1.0 if k < 4 else 0.0
        for i in range(core.N):
            norm = np.linalg.norm(z[i])
            obs[0, i, L.z_dir] = z[i] / norm
            obs[0, i, L.z_lognorm] = np.log1p(norm)
        sent.append(pol.act(obs, mask)[0, :, 0].copy())
        z_next = z @ A.T
        z_next[2:] += 0.5 * np.linalg.norm(z_next[2:], axis=1, keepdims=True) * np.eye(n)[1]
        z = z_next
    sent = np.array(sent)  # (k, agent)
    np.testing.assert_array_equal(sent[:, 0], [1, 1, 1, 0, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(sent[:, 1], [1, 1, 1, 1, 1, 1, 0, 0, 0])
    assert sent[:, 2:].all()


def test_aloha_threshold_probability_and_collision_carry_by_hand():
    """Active iff ``max_j (H news + carry) >= g N / K``; transmit iff the member's uniform
    draw is ``< min(1, q K / N)``; a collided message adds its news to the carry."""
    core, *_ = _core("comm_channel_k2-v0", B=1)
    N, H, L = core.N, core.horizon, core.layout
    pol = make_comm_policy("aloha:1,1", core, seed=[42])
    assert isinstance(pol, ThresholdAloha)
    assert pol.threshold == pytest.approx(1 * N / 2) and pol.p == pytest.approx(2 / N)
    draws = MemberUniforms([42])
    obs, mask = _blank(core, B=1)
    news = np.zeros((1, N, core.M))
    news[0, :, 0] = np.arange(N)  # agent i has i steps of news
    obs[..., L.news] = news / H
    obs[..., L.silence] = 1.0
    _set_time(core, obs, 3)
    bits = pol.act(obs, mask)[0, :, 0]
    u = draws(1, (N,))[0]
    np.testing.assert_array_equal(bits, (np.arange(N) >= 5) & (u < pol.p))
    # next step: every agent that sent collided; its news comes back as carry
    obs2, _ = _blank(core, B=1)
    obs2[..., L.news] = 1 / H  # one new step for everyone
    obs2[..., L.silence] = np.where(bits, 0.0, 1 / H)[None, :, None]
    obs2[..., L.collided] = 1.0
    _set_time(core, obs2, 4)
    want_gain = 1 + np.where(bits, np.arange(N), 0)
    np.testing.assert_array_equal(pol.gains(obs2)[0, :, 0], want_gain)


def test_tdma_is_a_collision_free_cyclic_schedule_of_the_sources():
    core, obs, mask = _core("comm_channel_k2-v0", B=2)
    pol = make_comm_policy("tdma:1", core)
    assert isinstance(pol, Tdma)
    src = np.flatnonzero(np.bincount(core.block_of, minlength=core.N) > 0)
    S, K = src.size, core.capacity
    count = np.zeros(core.N, int)
    for k in range(40):
        bits = pol.act(obs, mask)[..., 0]
        t = k + 1
        want = np.zeros(core.N, bool)
        want[src[(np.arange(K) + t * K) % S]] = True
        np.testing.assert_array_equal(bits, np.broadcast_to(want, bits.shape))
        out = core.step(bits[..., None])
        obs, mask = out.obs, out.action_mask
        assert not core.collided.any()  # never more than K senders
        count += bits[0]
    assert (count[src] >= 40 * K // S).all() and (count[src] <= -(-40 * K // S)).all()
    assert (count[np.setdiff1d(np.arange(core.N), src)] == 0).all()
    # stretch F: a slot every F steps
    pol3 = make_comm_policy("tdma:3", core)
    for k in range(6):
        _set_time(core, obs, k)
        assert pol3.act(obs, mask).any() == ((k + 1) % 3 == 0)


@pytest.mark.parametrize("spec", NEW + ("event:2", "periodic:3", "sources:2", "bernoulli:0.5",
                                         "settled:0.3(always)", "settled(settle:0.03)"))
def test_every_decentralised_family_reads_only_its_own_row(spec):
    """Two batch members that share agent 0's observations step after step but differ in
    every other agent's row: agent 0 decides the same in both (memory included)."""
    if spec.partition(":")[0] in CENTRALISED:
        pytest.skip("centralised reference")
    core, obs, mask = _core(B=2, seed=[5, 6])
    pol = make_comm_policy(spec, core, seed=[9, 9])  # same generator for both members
    rng = np.random.default_rng(0)
    for _ in range(60):
        o, m = obs.copy(), mask.copy()
        o[1, 0], m[1, 0] = o[0, 0], m[0, 0]  # agent 0 sees the same in both members
        bits = pol.act(o, m)
        assert (bits[0, 0] == bits[1, 0]).all()
        out = core.step((rng.random(bits.shape) < 0.4).astype(int))
        obs, mask = out.obs, out.action_mask


def test_memory_restarts_with_the_member():
    """A member reset in the middle of the others' episodes acts like a fresh policy on a
    fresh single run with its seed (settle keeps per-member memory)."""
    spec = "settle:0.05,3"
    model, _ = load_model("message_cost-v1", **frontier_overrides("message_cost-v1", {}))
    core = BatchedCore(model, 2)
    obs, mask = core.reset([1, 2])
    pol = make_comm_policy(spec, core)
    for _ in range(25):
        out = core.step(pol.act(obs, mask))
        obs, mask = out.obs, out.action_mask
    obs, mask = core.reset([1, 7], members=np.array([False, True]))
    single = BatchedCore(model, 1)
    so, sm = single.reset([7])
    fresh = make_comm_policy(spec, single)
    for _ in range(40):
        bits = pol.act(obs, mask)
        sb = fresh.act(so, sm)
        np.testing.assert_array_equal(bits[1], sb[0])
        out = core.step(bits)
        obs, mask = out.obs, out.action_mask
        s_out = single.step(sb)
        so, sm = s_out.obs, s_out.action_mask


@pytest.mark.parametrize("sid,policy", [(s, p) for s in ("comm_channel_k2-v0",
                                                          "comm_substates-v0")
                                        for p in NEW[::2] + NEW[1::4]
                                        + ("settled:0.3(event:2)",)])
def test_env_batched_and_benchmark_agree(sid, policy):
    """The same episodes through the PettingZoo env (serial backend) and as one batch,
    in transmit mode on a channel and in substates mode."""
    over = {"horizon": 25}
    jobs = bm.make_jobs([sid], [policy], [3, 4], overrides=over)
    serial = bm.execute(jobs, backend="serial", progress=False)
    batched = bm.execute(jobs, backend="batched", progress=False)
    for a, b in zip(serial, batched, strict=True):
        for m in ("msgs_per_agent_step", "reward", "mean_rel_error"):
            assert a["metrics"][m] == pytest.approx(b["metrics"][m], rel=1e-12, abs=1e-12)
    direct = evaluate(sid, policy, [3, 4], over)
    for r, e in zip(batched, direct["mean_rel_error"], strict=True):
        assert r["metrics"]["mean_rel_error"] == pytest.approx(e, rel=1e-12)


def test_substates_mode_sends_only_allowed_substates():
    core, obs, mask = _core("comm_substates-v0")
    for spec in NEW:
        bits = make_comm_policy(spec, core, seed=[1, 2, 3]).act(obs, mask)
        assert bits.shape == (3, core.N, core.M)
        assert not (bits.astype(bool) & ~(mask[..., 1::2] > 0)).any()


@pytest.mark.parametrize("sid,family,knobs", [
    ("message_cost-v1", "until", (60, 30, 15)),
    ("message_cost-v1", "settle", ("0.001", "0.03", "0.3,2")),
    (SID, "aloha", ("1,1", "1,0.5", "1,0.25", "1,0.1")),
    ("comm_channel_k2-v0", "tdma", (1, 2, 4, 8)),
])
def test_each_knob_trades_messages_for_error(sid, family, knobs):
    """From the most to the fewest messages: messages fall strictly, the error rises
    (each setting within 0.01 of monotone, and clearly overall)."""
    seeds = list(range(500, 512))
    over = frontier_overrides(sid, {"horizon": 80})
    res = [evaluate(sid, f"{family}:{k}", seeds, over) for k in knobs]
    msgs = [r["msgs_per_agent_step"].mean() for r in res]
    err = [r["mean_rel_error"].mean() for r in res]
    assert all(a > b for a, b in zip(msgs[:-1], msgs[1:], strict=True)), msgs
    assert all(b > a - 0.01 for a, b in zip(err[:-1], err[1:], strict=True)), err
    assert err[-1] > err[0] + 0.02, err


def test_actor_scores_a_rule_exactly_like_its_spec():
    seeds = [11, 12]
    over = frontier_overrides(SID, {"horizon": 30})
    a = evaluate(SID, "tdma:2", seeds, over)
    b = evaluate(SID, "my rule", seeds, over,
                 actor=lambda core, s: make_comm_policy("tdma:2", core).act)
    for m in a:
        np.testing.assert_array_equal(a[m], b[m])


SETTLED_SID = "comm_schedule-v1"


@pytest.mark.parametrize("eps", [0.3, 0.03])
def test_settled_opens_at_the_first_small_own_block_correction(eps):
    """``settled:e(always)`` on ``comm_schedule-v1`` against the gate computed from the
    core's own estimates (not the observation the rule decodes): agent ``i`` sends
    from the first step ``s >= 1`` with ``||P_i (z_i[s] - A_bar z_i[s-1])|| /
    max(||z_i[s]||, 1e-3) < e`` on, where ``P_i`` keeps its block's coordinates, and
    throughout if it owns no block. At both thresholds the owners open at steps at least
    5 apart (checked), so the comparison is not vacuous."""
    core, obs, mask = _core(SETTLED_SID, B=4, seed=[11, 12, 13, 14])
    pol = make_comm_policy(f"settled:{eps}(always)", core)
    A_T = core.model.design.decomposition.A_bar.T
    own = np.zeros((core.N, core.n), bool)
    own[core.block_of, np.arange(core.n)] = True
    opened = np.broadcast_to(~own.any(1), (4, core.N)).copy()
    first = np.full((4, core.N), -1)
    z_prev = None
    for k in range(60):
        z = core.Z.copy()
        if z_prev is not None:
            d = np.linalg.norm(np.where(own, z - z_prev @ A_T, 0.0), axis=-1)
            opened |= d / np.maximum(np.linalg.norm(z, axis=-1), 1e-3) < eps
        first[(first < 0) & opened] = k
        bits = pol.act(obs, mask)
        allowed = mask[..., 1::2] > 0
        np.testing.assert_array_equal(bits.astype(bool), allowed & opened[..., None])
        z_prev = z
        out = core.step(bits)
        obs, mask = out.obs, out.action_mask
    owners = own.any(1)
    spread = first[:, owners].max() - first[:, owners].min()
    assert (first[:, owners] >= 1).all() and spread >= 5
    assert (first[:, ~owners] == 0).all()


def test_settled_knob_and_base_are_checked_by_name():
    core, *_ = _core("message_cost-v1")
    for bad in ("settled:0(always)", "settled:-0.1(always)", "settled:nan(always)",
                "settled:inf(always)"):
        with pytest.raises(ValueError, match="settled: the threshold e"):
            make_comm_policy(bad, core)
    with pytest.raises(ValueError, match="knob of settled"):
        parse_spec("settled:abc(always)")
    with pytest.raises(ValueError, match="plain rule"):
        parse_spec("settled(phased(until:40))")
    with pytest.raises(ValueError, match="decentralised"):
        parse_spec("settled(oldest:2)")
    assert parse_spec("settled(settle:0.03)") == ("settled", (0.1, "settle:0.03"))
    from netsense.benchmark.kinds import family_kind

    assert family_kind("settled:0.3(until:40)") == "decentralised"
