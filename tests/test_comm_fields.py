"""Scenario options of the communication tasks: the announced next graph (``next_out``),
delivery feedback (``acks``), per-sender Gilbert-Elliott channels and a plant noise input
``W``. Each field against the core's state, and the options change no realisation."""

from __future__ import annotations

import numpy as np
import pytest

from netsense.engine.control import Control
from netsense.engine.core import BatchedCore
from netsense.engine.model import ObsLayout
from netsense.env.registry import load, make
from netsense.env.vector import load_model
from netsense.sensing.drops import GilbertElliottArrivals, arrival_from_dict

SID = "comm_process_noise-v0"
DROPS = {"message": {"kind": "bernoulli", "p": 0.7}}


def _pair(chunk, B=3, **over):
    """A core with both options and one without, same scenario otherwise."""
    over = {"horizon": 50, "arrivals": DROPS, **over}
    on, _ = load_model(SID, control={"announce": True, "feedback": True}, **over)
    off, _ = load_model(SID, **over)
    return BatchedCore(on, B, chunk=chunk), BatchedCore(off, B, chunk=chunk)


@pytest.mark.parametrize("chunk", [1, 3, None])
def test_next_out_is_the_next_graph_and_nothing_else_changes(chunk):
    """``next_out`` at k is row l of G[k+1] seen from the sender (also across chunk
    boundaries, where G[k+1] is peeked from the graph stream); observations, estimates
    and rewards equal those of the scenario without the options."""
    c, r = _pair(chunk)
    L = c.layout
    obs, _ = c.reset(7)
    r.reset(7)
    rng = np.random.default_rng(0)
    for _ in range(49):
        announced = obs[..., L.next_out].copy()
        bits = (rng.random((3, c.N, 1)) < 0.5).astype(int)
        out, ref = c.step(bits), r.step(bits)
        obs = out.obs
        want = np.swapaxes(c.adjacency, 1, 2).astype(np.float32)  # [b, l, i]: l -> i
        np.testing.assert_array_equal(announced, want)
        np.testing.assert_array_equal(obs[..., :r.layout.size], ref.obs)
        np.testing.assert_array_equal(out.reward, ref.reward)
        np.testing.assert_array_equal(c.Z, r.Z)


def test_acks_report_delivery_per_out_link():
    """``acks[b, l, i]``: +1 iff i's slot holding l got l's message of step k, -1 iff
    l -> i is a link of G[k], l transmitted and the message was lost, else 0."""
    c, _ = _pair(None, arrivals={"message": {"kind": "bernoulli", "p": 0.6}})
    L = c.layout
    obs, _ = c.reset(3)
    rng = np.random.default_rng(1)
    seen = set()
    for _ in range(40):
        out = c.step((rng.random((3, c.N, 1)) < 0.6).astype(int))
        acks = out.obs[..., L.acks]
        for b in range(c.B):
            want = np.zeros((c.N, c.N))
            for i in range(c.N):
                for d in range(c.D):
                    l = c.nbr[b, i, d]
                    if l < 0:
                        continue
                    want[l, i] = 1 if c.msg[b, i, d] else (-1 if c.transmit[b, l] else 0)
            np.testing.assert_array_equal(acks[b], want)
            seen |= set(np.unique(want).tolist())
    assert seen == {-1.0, 0.0, 1.0}


def test_collisions_show_as_lost_acks():
    env = make("comm_channel_k2-v0", control={"feedback": True}, horizon=5)
    obs, _ = env.reset(seed=0)  # step 0: everyone transmits, all collide
    L = env.layout
    for a in env.possible_agents:
        assert (obs[a]["observation"][L.acks] <= 0).all()
    core = env.core
    assert core.collided[0]
    lost = sum((obs[a]["observation"][L.acks] == -1).sum() for a in env.possible_agents)
    assert lost == int(core.adjacency[0].sum())


def test_fields_exist_only_when_enabled_and_need_a_comm_mode():
    plain = make(SID)
    assert plain.layout.next_out is None and plain.layout.acks is None
    assert plain.model.known_ahead == 0
    env = make(SID, control={"announce": True})
    assert env.model.known_ahead == 1
    assert env.layout.size == plain.layout.size + env.core.N
    assert [nm for nm, *_ in env.layout.comm_table()][-1] == "next_out"
    both = make(SID, control={"announce": True, "feedback": True})
    assert [nm for nm, *_ in both.layout.comm_table()][-2:] == ["next_out", "acks"]
    assert both.observation_space("sensor_0").contains(both.reset(seed=0)[0]["sensor_0"])
    with pytest.raises(ValueError, match="control.announce"):
        Control(mode="full", announce=True)
    with pytest.raises(ValueError, match="control.feedback"):
        make("message_cost-v1", control={"feedback": True})
    with pytest.raises(ValueError, match="control.announce"):
        make(SID, control={"announce": "yes"})
    with pytest.raises(ValueError, match="comm=True"):
        ObsLayout.build(3, 1, 1, 2, announce=True)


def test_per_sender_channels_are_shared_by_every_out_link():
    ge = arrival_from_dict({"kind": "gilbert_elliott", "p_good_to_bad": 0.2,
                            "p_bad_to_good": 0.1, "scope": "sender"})
    assert isinstance(ge, GilbertElliottArrivals) and ge.to_dict()["scope"] == "sender"
    assert "scope" not in arrival_from_dict({"kind": "bernoulli", "p": 0.5}).to_dict()
    s = ge.sampler(np.random.default_rng(0), (6, 6))
    draws = np.stack([s.next() for _ in range(4000)])  # [t, receiver, sender]
    assert (draws == draws[:, :1, :]).all()  # one channel per sender (column)
    assert draws.mean() == pytest.approx(1 - ge.loss_rate, abs=0.03)
    # bursts: a sender's lost steps come in runs of mean 1 / p_bad_to_good
    col = draws[:, 0, 0]
    runs = np.diff(np.flatnonzero(np.diff(np.r_[True, col, True].astype(int)) != 0))[::2]
    assert np.mean(runs[runs > 0]) == pytest.approx(10, rel=0.35)
    bern = arrival_from_dict({"kind": "bernoulli", "p": 0.5, "scope": "sender"})
    d = bern.sampler(np.random.default_rng(1), (4, 4)).next()
    assert (d == d[:1]).all()
    for bad in ({"kind": "bernoulli", "p": 0.5, "scope": "receiver"},
                {"kind": "gilbert_elliott", "p_good_to_bad": 0.1, "p_bad_to_good": 0.1,
                 "scope": 1}):
        with pytest.raises(ValueError, match="scope"):
            arrival_from_dict(bad)


def test_matrices_plant_takes_a_noise_input():
    env = make("comm_fading-v0")
    assert env.model.plant.W is None
    sc = load(SID).to_dict()
    n = len(sc["plant"]["A"])
    W = np.diag(np.linspace(0.1, 1.0, n)).tolist()
    env = make(SID, plant={"W": W})
    np.testing.assert_array_equal(env.model.plant.W_effective, W)
    with pytest.raises(ValueError, match="plant.W"):
        make(SID, plant={"W": [[1.0, 2.0]]})
