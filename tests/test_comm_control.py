"""Communication-only control modes, per-substate messages and the shared channel."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test
from pettingzoo.utils import parallel_to_aec

from netsense.engine.control import NEVER, Channel, Control, apply_collisions
from netsense.engine.core import BatchedCore
from netsense.env.comm_policies import make_comm_policy
from netsense.env.policies import make_policy
from netsense.env.registry import list_scenarios, load, make
from netsense.env.vector import load_model
from netsense.kernels import update as kernels
from netsense.kernels.rules import OMEGA

FULL = [s for s in list_scenarios() if not load(s).control]


def short(sid: str) -> dict:
    return {"horizon": 4 if sid.startswith("large") else 25}


def _fusions(sid: str) -> list[str]:
    """The adoption rules that apply to a scenario (tree needs a periodic schedule)."""
    out = ["freshness", "uniform"]
    try:
        make_policy("tree", make(sid, **short(sid)))
        out.append("tree")
    except ValueError:
        pass
    return out


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


# ------------------------------------------------------------------ one implementation
@pytest.mark.parametrize("sid", FULL)
def test_fusion_with_everyone_transmitting_is_the_full_control_policy_bit_for_bit(sid):
    """Transmit-only control with the fusion rule F and every bit set is the full-control
    scripted policy F: observations (the full mode's fields), rewards, estimates, indices,
    transmissions and the plant, at every step of the episode."""
    for fusion in _fusions(sid):
        full = make(sid, **short(sid))
        comm = make(sid, control={"mode": "transmit", "fusion": fusion}, **short(sid))
        pf, pc = make_policy(fusion, full), make_policy(fusion, comm)
        assert type(pc).__name__ == "TransmitAll"
        of, inf_f = full.reset(seed=11)
        oc, inf_c = comm.reset(seed=11)
        L = full.layout.size
        while full.agents:
            of, rf, _, tf, inf_f = full.step(pf.act_dict(full, of, inf_f))
            oc, rc, _, tc, inf_c = comm.step(pc.act_dict(comm, oc, inf_c))
            assert rf == rc and tf == tc
            for a in full.possible_agents:
                np.testing.assert_array_equal(of[a]["observation"], oc[a]["observation"][:L])
                assert inf_f[a]["transmitted"] == inf_c[a]["transmitted"]
            for name in ("Z", "tau", "x", "transmit", "msg"):
                np.testing.assert_array_equal(getattr(full.core, name),
                                              getattr(comm.core, name), err_msg=name)
        assert not comm.agents


@pytest.mark.parametrize("sid", ["message_cost-v1", "fault_liar-v0", "link_failures-v0",
                                 "large_n20_N100-v2"])
def test_per_substate_messages_sending_everything_keep_the_freshness_estimates(sid):
    """With every substate that has an estimate sent, per-substate messages change nothing
    the freshness rule uses (omega entries are never adopted): same estimates and
    non-empty indices as full control, batched."""
    model, _ = load_model(sid, **short(sid))
    sub, _ = load_model(sid, control={"mode": "substates"}, **short(sid))
    a, b = BatchedCore(model, 3), BatchedCore(sub, 3)
    oa, ma = a.reset(5)
    ob, mb = b.reset(5)
    pa, pb = make_policy("freshness", a), make_comm_policy("always", b)
    keep = ~b.comm.empty
    for _ in range(short(sid)["horizon"]):
        ra, rb = a.step(pa.act(oa, ma)), b.step(pb.act(ob, mb))
        oa, ma, ob, mb = ra.obs, ra.action_mask, rb.obs, rb.action_mask
        np.testing.assert_array_equal(a.Z, b.Z)
        np.testing.assert_array_equal(a.tau[..., keep], b.tau[..., keep])


def test_empty_substates_are_never_sent():
    """With substates = "all", the columns of agents that measure nothing are empty: their
    bits are masked and they are never news."""
    env = make("fig1_scalar-v0", control={"mode": "substates"})
    obs, _ = env.reset(seed=1)
    assert env.core.comm.empty.tolist() == [False, True, True]
    for a in env.possible_agents:
        assert list(obs[a]["action_mask"][2:]) == [1, 0, 1, 0]
        assert (obs[a]["observation"][env.layout.news][1:] == 0).all()


def test_action_spaces_masks_and_observations_of_each_mode():
    for mode, width in (("full", None), ("transmit", 1), ("substates", None)):
        env = make("random_structured_n20_N10-v0", control={"mode": mode})
        c = env.core
        M, D = c.M, c.D
        want = {"full": [D + 2] * M + [2], "transmit": [2], "substates": [2] * M}[mode]
        assert list(env.action_space("sensor_0").nvec) == want
        obs, _ = env.reset(seed=0)
        o = obs["sensor_3"]
        assert o["action_mask"].shape == (sum(want),)
        assert env.observation_space("sensor_3").contains(o)
        comm = env.layout.comm_table()
        assert (len(comm) == 0) == (mode == "full")
        if comm:
            assert [name for name, *_ in comm] == ["news", "silence", "channel_load",
                                                   "collided", "agent_id"]
            assert env.layout.size == comm[-1][2]
            assert o["observation"][env.layout.agent_id][0] == np.float32(4 / c.N)
        assert width is None or len(want) == width


def test_substates_mask_allows_only_substates_with_an_estimate_and_raises_otherwise():
    over = {"control": {"mode": "substates"}, "substates": "sources"}  # M = 1
    env = make("fig1_scalar-v0", **over)
    obs, _ = env.reset(seed=1)
    # step 0: only the source (agent 0) knows its substate; relays have omega
    masks = {a: obs[a]["action_mask"] for a in env.possible_agents}
    assert list(masks["sensor_0"]) == [1, 1]
    # agent 1 hears agent 0 at step 0 (initial transmit) in graph (a): estimate at k + 1
    allowed = {a: bool(m[1]) for a, m in masks.items()}
    c = env.core
    np.testing.assert_array_equal([allowed[a] for a in env.possible_agents],
                                  c.comm.tau_next[0, :, 0] >= 0)
    bad = next((a for a, ok in allowed.items() if not ok), None)
    assert bad is not None
    acts = {a: np.array([1 if allowed[a] else 0]) for a in env.possible_agents}
    acts[bad] = np.array([1])
    with pytest.raises(ValueError, match="no estimate"):
        env.step(acts)
    keep = make("fig1_scalar-v0", invalid_actions="keep", **over)
    keep.reset(seed=1)
    _, _, _, _, infos = keep.step(acts)
    assert infos[bad]["invalid_actions"] == 1
    with pytest.raises(ValueError, match="outside 0..1"):
        keep.step({a: np.array([2]) for a in keep.possible_agents})


# ------------------------------------------------------------------ per-substate messages
def test_a_substate_that_was_not_sent_cannot_be_adopted_hand_built():
    """Agent 0 hears agents 1 and 2. Agent 1 is the freshest for both substates but sent
    only substate 0; so substate 0 comes from agent 1, substate 1 from agent 2 (fresher
    than agent 0's own), and with nobody sending substate 1 agent 0 keeps its own."""
    tau = np.array([[[5, 6], [1, 1], [3, 2]]])  # (B=1, N=3, M=2)
    nbr = np.array([[[1, 2], [-1, -1], [-1, -1]]])
    msg = np.array([[[True, True], [False, False], [False, False]]])
    sent = np.array([[[True, True], [True, False], [True, True]]])
    src, slot = kernels.freshness_choice(tau, nbr, msg, sent=sent)
    assert src[0, 0].tolist() == [1, 2] and slot[0, 0].tolist() == [0, 1]
    src, slot = kernels.freshness_choice(tau, nbr, msg)  # whole messages: agent 1 for both
    assert src[0, 0].tolist() == [1, 1]
    sent[0, 2, 1] = False
    src, slot = kernels.freshness_choice(tau, nbr, msg, sent=sent)
    assert src[0, 0].tolist() == [1, 0] and slot[0, 0].tolist() == [0, -1]
    use = kernels.usable_slots(nbr, msg, sent=sent)
    assert use.shape == (1, 3, 2, 2)
    assert use[0, 0].tolist() == [[True, False], [True, False]]
    with pytest.raises(ValueError, match="sent must have"):
        kernels.freshness_choice(tau, nbr, msg, sent=sent[..., :1])


def test_in_substates_mode_only_sent_substates_are_adopted_and_observed():
    """Random bits on a random scenario: every adoption of the fusion rule uses a
    (slot, substate) that was sent, and the observation shows an unsent substate of a
    message as no message (omega flag 1, age 0)."""
    model, _ = load_model("message_cost-v1", control={"mode": "substates"}, horizon=40)
    core = BatchedCore(model, 4)
    obs, mask = core.reset(0)
    pol = make_policy("random", core, seed=[1, 2, 3, 4], p_transmit=0.5)
    L, D, M = core.layout, core.D, core.M
    hidden = adopted = 0
    for _ in range(40):
        ch, sent, nbr, msg = core.comm.choice, core.comm.sent, core.nbr, core.msg
        b, i, j = np.nonzero(ch > 0)
        d = ch[b, i, j] - 1
        assert msg[b, i, d].all() and sent[b, nbr[b, i, d], j].all()
        adopted += len(b)
        carried = kernels.substate_messages(nbr, msg, sent)  # (B, N, D, M)
        so = obs[..., L.slot_omega].reshape(4, core.N, D, M)
        sa = obs[..., L.slot_age].reshape(4, core.N, D, M)
        off = msg[..., None] & ~carried
        assert (so[off] == 1).all() and (sa[off] == 0).all()
        hidden += off.sum()
        out = core.step(pol.act(obs, mask))
        obs, mask = out.obs, out.action_mask
    assert adopted > 50 and hidden > 50


def test_substate_cost_is_charged_per_substate_sent():
    model, _ = load_model("comm_substates-v0", horizon=6)
    core = BatchedCore(model, 2)
    obs, mask = core.reset(3)
    c, c_s = model.reward.message_cost, model.reward.substate_cost
    assert c > 0 and c_s > 0
    for _ in range(5):
        bits = make_policy("random", core, seed=[0, 1]).act(obs, mask)
        out = core.step(bits)
        t, s = core.transmit, core.comm.sent.sum(-1)
        err_part = out.reward + c * t + c_s * s  # what is left is the team error term
        np.testing.assert_allclose(err_part, err_part[:, :1] * np.ones((1, core.N)),
                                   rtol=0, atol=1e-12)
        assert ((s > 0) == t).all()
        obs, mask = out.obs, out.action_mask


def test_news_silence_and_agent_id_follow_their_definitions():
    env = make("fig1_scalar-v0", control={"mode": "transmit"})
    c, L, H = env.core, env.layout, env.core.horizon
    obs, _ = env.reset(seed=0)
    o = np.stack([obs[a]["observation"] for a in env.possible_agents])
    # step 0: everyone transmitted (initial_transmit); the source sent its substate
    # (generated at 0), the next message carries the estimate of k + 1 = 1: news 1 / H
    assert o[0, L.news][0] == np.float32(1 / H)
    assert (o[:, L.silence] == 0).all()
    np.testing.assert_array_equal(o[:, L.agent_id][:, 0], np.float32([1 / 3, 2 / 3, 1]))
    for k in range(1, 4):  # stay silent: news and silence grow by one step each
        obs, *_ = env.step({a: np.array([0]) for a in env.possible_agents})
        o = np.stack([obs[a]["observation"] for a in env.possible_agents])
        assert o[0, L.news][0] == np.float32(min(k + 1, H) / H)
        np.testing.assert_array_equal(o[:, L.silence][:, 0], np.float32(k / H))
    assert (c.comm.g_sent[0, 1:, 0] == NEVER).all()  # relays never sent substate 0


# ------------------------------------------------------------------ the shared channel
def test_collision_rule_by_hand():
    transmit = np.array([[True, True, False], [True, True, True]])
    msg = np.ones((2, 3, 2), bool)
    collided = np.empty(2, bool)
    apply_collisions(transmit, msg, 2, collided)
    assert collided.tolist() == [False, True]
    assert msg[0].all() and not msg[1].any()
    with pytest.raises(ValueError, match="capacity"):
        Channel(0)


@pytest.mark.parametrize("p", [0.1, 0.25, 0.6])
def test_never_more_than_K_senders_get_through(p):
    model, _ = load_model("comm_channel_k2-v0", horizon=60)
    K = model.channel.capacity
    core = BatchedCore(model, 8)
    obs, mask = core.reset(7)
    pol = make_comm_policy(f"bernoulli:{p}", core, seed=list(range(8)))
    coll = ok = 0
    for _ in range(60):
        tx = core.transmit
        senders = np.zeros(core.B, int)
        for b in range(core.B):
            got = core.nbr[b][core.msg[b]]
            senders[b] = len(np.unique(got))
        assert (senders <= K).all()
        over = tx.sum(1) > K
        np.testing.assert_array_equal(core.collided, over)
        assert not core.msg[over].any()
        # below capacity the message table is the channel-free one (no link drops here)
        want = kernels.slot_messages(core.nbr, tx)
        np.testing.assert_array_equal(core.msg[~over], want[~over])
        np.testing.assert_array_equal(obs[..., core.layout.collided][:, 0, 0], over)
        coll += over.sum()
        ok += (~over & tx.any(1)).sum()
        out = core.step(pol.act(obs, mask))
        obs, mask = out.obs, out.action_mask
    assert ok > 0 and (coll > 0 or p < 0.2)


# ------------------------------------------------------------------ configuration
@pytest.mark.parametrize("over,match", [
    ({"control": {"mode": "talk"}}, "control.mode"),
    ({"control": {"fusion": "median"}}, "control.fusion"),
    ({"control": {"mode": "substates", "fusion": "uniform"}}, "control.fusion"),
    ({"control": {"mode": "transmit", "rate": 1}}, "control.rate"),
    ({"channel": {"capacity": 0}}, "channel.capacity"),
    ({"channel": {"slots": 2}}, "channel.slots"),
    ({"reward": {"substate_cost": 0.1}}, "substate_cost needs"),
    ({"control": {"mode": "transmit", "fusion": "tree"}}, "periodic"),
])
def test_control_and_channel_sections_are_checked(over, match):
    with pytest.raises(ValueError, match=match):
        make("message_cost-v1", **over)


def test_control_dataclasses():
    assert not Control().comm_only and Control("transmit").comm_only
    with pytest.raises(ValueError):
        Control("substates", "uniform")


@pytest.mark.parametrize("sid,mode", [("fig1_scalar-v0", "transmit"),
                                      ("fig1_scalar-v0", "substates"),
                                      ("comm_channel_k2-v0", "full"),
                                      ("comm_substates-v0", "transmit")])
def test_pettingzoo_checkers_in_every_mode(sid, mode):
    over = {"control": {"mode": mode}, "horizon": 15}
    parallel_api_test(make(sid, **over), num_cycles=100)
    parallel_seed_test(lambda: make(sid, invalid_actions="keep", **over), num_cycles=30)
    api_test(parallel_to_aec(make(sid, **over)), num_cycles=20)


def test_omega_stays_encoded_as_minus_one():
    assert OMEGA == -1  # the comm bookkeeping reads tau >= 0 as "has an estimate"


def test_vector_envs_take_the_communication_modes():
    from netsense.env.vector import AgentVectorEnv, BatchedEnv

    be = BatchedEnv("comm_substates-v0", 3, horizon=5)
    obs, info = be.reset(seed=0)
    assert obs.shape == (3, 10, be.obs_dim) and info["action_mask"].shape == (3, 10, 10)
    bits = (info["action_mask"][..., 1::2] > 0).astype(np.int64)
    for _ in range(6):  # past the horizon: auto-reset
        obs, rew, term, trunc, info = be.step(bits)
        bits = (info["action_mask"][..., 1::2] > 0).astype(np.int64)
    av = AgentVectorEnv("comm_channel_k2-v0", 2, horizon=5)
    obs, info = av.reset(seed=1)
    assert av.action_masks().shape == (20, 2)
    obs, rew, term, trunc, info = av.step(np.ones((20, 1), dtype=np.int64))
    assert rew.shape == (20,)
    with pytest.raises(ValueError, match="len\\(nvec\\)"):
        av.step(np.ones((20, 2), dtype=np.int64))
