"""The communication baselines: rules by hand, knobs that trade messages for error, and
the same numbers through the env, the batched core and the benchmark."""

from __future__ import annotations

import numpy as np
import pytest

import netsense.benchmark as bm
from netsense.benchmark.protocol import evaluate
from netsense.engine.core import BatchedCore
from netsense.env.comm_policies import COMM_POLICIES, AgeScheduler, make_comm_policy, parse_spec
from netsense.env.registry import make
from netsense.env.vector import load_model

SID = "comm_process_noise-v0"


def _core(sid=SID, B=4, **over):
    model, _ = load_model(sid, **over)
    core = BatchedCore(model, B)
    obs, mask = core.reset(0)
    return core, obs, mask


def test_specs_parse_and_bad_ones_fail():
    assert parse_spec("periodic:4") == ("periodic", 4)
    assert parse_spec("bernoulli") == ("bernoulli", 0.5)
    assert parse_spec("always") == ("always", None)
    for bad in ("gossip:2", "periodic:x", "always:3"):
        with pytest.raises(ValueError):
            parse_spec(bad)
    core, *_ = _core()
    for bad in ("periodic:0", "event:0", "bernoulli:1.5", "whittle:0", "sources:-1"):
        with pytest.raises(ValueError):
            make_comm_policy(bad, core)
    with pytest.raises(ValueError, match="communication-only"):
        make_comm_policy("periodic:2", make("message_cost-v1"))


def test_periodic_is_a_staggered_round_robin():
    core, obs, mask = _core()
    N = core.N
    for P in (1, 2, 5):
        pol = make_comm_policy(f"periodic:{P}", core)
        o, m = obs, mask
        for k in range(2 * P):
            bits = pol.act(o, m)[..., 0]
            want = (k + 1 + np.arange(N)) % P == 0  # sent at k + 1
            np.testing.assert_array_equal(bits, np.broadcast_to(want, bits.shape))
            out = core.step(bits[..., None])
            o, m = out.obs, out.action_mask
        core.reset(0)
        obs, mask = core.observe()


def test_sources_first_and_event_rules_by_hand():
    core, obs, mask = _core()
    src = np.bincount(core.block_of, minlength=core.N) > 0
    bits = make_comm_policy("sources:0", core).act(obs, mask)[..., 0]
    np.testing.assert_array_equal(bits, np.broadcast_to(src, bits.shape))
    # event: transmit iff some substate's news (in steps) reaches the threshold
    L, H = core.layout, core.horizon
    news = np.rint(obs[..., L.news] * H)
    for d in (1, 2, 3):
        got = make_comm_policy(f"event:{d}", core).act(obs, mask)[..., 0]
        np.testing.assert_array_equal(got, (news >= d).any(-1))


def test_event_in_substates_mode_sends_only_the_substates_with_news():
    core, obs, mask = _core("comm_substates-v0")
    pol = make_comm_policy("event:2", core)
    for _ in range(30):
        bits = pol.act(obs, mask)
        news = np.rint(obs[..., core.layout.news] * core.horizon) >= 2
        np.testing.assert_array_equal(bits.astype(bool), news & (mask[..., 1::2] > 0))
        out = core.step(bits)
        obs, mask = out.obs, out.action_mask


def test_scheduler_index_and_choice_against_the_formula():
    """``I_l = sum_{i != l, j} W([tau_i^j - tau_l^j]_+)`` with omega as H at a receiver
    and 0 at a sender; the ``m`` largest send (ties: smaller id)."""
    core, obs, mask = _core()
    for _ in range(7):
        out = core.step(make_comm_policy("bernoulli:0.3", core, seed=1).act(obs, mask))
        obs, mask = out.obs, out.action_mask
    tau, H = core.reported_indices(), core.horizon
    for index in ("oldest", "whittle"):
        pol = make_comm_policy(f"{index}:3", core)
        assert isinstance(pol, AgeScheduler)
        g = pol.gains(obs)
        for b in range(core.B):
            for l in range(core.N):
                for j in range(core.M):
                    tot = 0.0
                    for i in range(core.N):
                        if i == l or tau[b, l, j] < 0:
                            continue
                        ti = H if tau[b, i, j] < 0 else tau[b, i, j]
                        h = max(ti - tau[b, l, j], 0)
                        tot += h if index == "oldest" else h * (h + 1) / 2
                    assert g[b, l, j] == pytest.approx(tot)
        bits = pol.act(obs, mask)[..., 0]
        total = g.sum(-1)
        for b in range(core.B):
            want = np.argsort(-total[b], kind="stable")[:3]
            want = want[total[b, want] > 0]
            assert sorted(np.flatnonzero(bits[b])) == sorted(want)


@pytest.mark.parametrize("family,knobs", [
    ("periodic", (1, 2, 4, 8)),
    ("bernoulli", (1.0, 0.5, 0.25, 0.1)),
    ("event", (1, 2, 4, 8)),
    ("sources", (1, 4, 0)),
    ("whittle", (6, 3, 1)),
    ("oldest", (6, 3, 1)),
])
def test_each_knob_trades_messages_for_error(family, knobs):
    """From the most to the fewest messages: messages fall strictly, the error rises
    (loosely: each setting within 0.01 of monotone, and clearly overall)."""
    seeds = list(range(500, 516))
    res = [evaluate(SID, f"{family}:{k}", seeds, {"horizon": 80}) for k in knobs]
    msgs = [r["msgs_per_agent_step"].mean() for r in res]
    err = [r["mean_rel_error"].mean() for r in res]
    assert all(a > b for a, b in zip(msgs[:-1], msgs[1:], strict=True)), msgs
    assert all(b > a - 0.01 for a, b in zip(err[:-1], err[1:], strict=True)), err
    assert err[-1] > err[0] + 0.02, err


def test_always_and_never_are_the_ends():
    seeds = list(range(500, 508))
    always = evaluate(SID, "always", seeds, {"horizon": 60})
    never = evaluate(SID, "never", seeds, {"horizon": 60})
    assert (always["msgs_per_agent_step"] == 1).all() and (never["msgs_per_agent_step"] == 0).all()
    assert (always["mean_rel_error"] < never["mean_rel_error"]).all()
    fresh = evaluate(SID, "freshness", seeds, {"horizon": 60})  # the fusion's own name
    for m in always:
        np.testing.assert_array_equal(always[m], fresh[m])


@pytest.mark.parametrize("policy", ["bernoulli:0.3", "event:3", "whittle:2", "sources:4",
                                    "random", "freshness"])
def test_env_batched_and_benchmark_agree(policy):
    """The same episodes through the PettingZoo env (serial backend) and as one batch
    (batched backend): the baselines run like every scripted policy."""
    over = {"horizon": 20}
    jobs = bm.make_jobs(["comm_channel_k2-v0"], [policy], [3, 4, 5], overrides=over)
    serial = bm.execute(jobs, backend="serial", progress=False)
    batched = bm.execute(jobs, backend="batched", progress=False)
    for a, b in zip(serial, batched, strict=True):
        for m in ("msgs_per_agent_step", "reward", "mean_rel_error"):
            assert a["metrics"][m] == pytest.approx(b["metrics"][m], rel=1e-12, abs=1e-12)
    direct = evaluate("comm_channel_k2-v0", policy, [3, 4, 5], over)
    for r, e in zip(batched, direct["mean_rel_error"], strict=True):
        assert r["metrics"]["mean_rel_error"] == pytest.approx(e, rel=1e-12)


def test_benchmark_skips_what_does_not_apply():
    jobs = bm.make_jobs(["message_cost-v1", SID], ["periodic:2", "uniform_consensus"], [0],
                        overrides={"horizon": 5})
    res = bm.execute(jobs, backend="batched", progress=False)
    ran = {(r["job"]["scenario"], r["job"]["policy"]) for r in res}
    assert ran == {("message_cost-v1", "uniform_consensus"), (SID, "periodic:2")}
    assert set(COMM_POLICIES) <= set(bm.POLICY_NAMES)
