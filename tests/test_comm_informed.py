"""The informed rules (gated, acked, phased) and the privileged rules (oracle,
oracle_channel): spec syntax and errors, each gate against its rule on hand-made
observations or the core's own graph, decentralisation (own row only), per-member memory,
batches equal single episodes, and their place in the frontier (kinds, best decentralised,
Pareto) and the CLI."""

from __future__ import annotations

import numpy as np
import pytest

import netsense.benchmark as bm
from netsense.benchmark.headroom import best_scripted
from netsense.benchmark.kinds import family_kind
from netsense.benchmark.protocol import evaluate, frontier, frontier_overrides
from netsense.engine.core import BatchedCore
from netsense.env.comm_informed import Acked, Gated, Phased, applicable
from netsense.env.comm_policies import make_comm_policy, parse_spec, spec_family
from netsense.env.comm_privileged import Oracle
from netsense.env.vector import load_model

ANN, FAD, SCH = "comm_announced-v0", "comm_fading-v0", "comm_schedule-v0"
#: (scenario, spec) of every informed rule on a task that has its field
INFORMED = ((ANN, "gated(sources:0)"), (ANN, "gated(event:2)"), (FAD, "acked(always)"),
            (FAD, "acked:3(event:1)"), (SCH, "phased(event:2)"), (SCH, "phased:4(always)"),
            ("comm_schedule-v1", "phased(until:40)"))


def _core(sid, B=2, seed=0, **over):
    model, _ = load_model(sid, **frontier_overrides(sid, over))
    core = BatchedCore(model, B)
    obs, mask = core.reset(seed)
    return core, obs, mask


def test_specs_parse_wrapped_rules_and_bad_ones_fail():
    assert parse_spec("gated(sources:0)") == ("gated", (None, "sources:0"))
    assert parse_spec("acked(event:2)") == ("acked", (6, "event:2"))
    assert parse_spec("acked:3(event:2)") == ("acked", (3, "event:2"))
    assert parse_spec("phased(until:40)") == ("phased", (None, "until:40"))
    assert parse_spec("phased:12(aloha:1,1)") == ("phased", (12, "aloha:1,1"))
    assert parse_spec("oracle_channel(always)") == ("oracle_channel", (None, "always"))
    assert spec_family("acked:3(event:2)") == "acked" == spec_family("acked(always)")
    assert family_kind("gated") == "decentralised" and family_kind("oracle") == "privileged"
    for bad, why in (("gated", "wraps"), ("gated(", "wraps"), ("gated()", "needs a base"),
                     ("gated:3(sources:0)", "no knob"), ("acked:x(always)", "knob"),
                     ("gated(whittle:2)", "decentralised"), ("oracle(oldest:1)",
                                                              "decentralised"),
                     ("gated(acked(always))", "plain rule"), ("foo(always)", "only"),
                     ("gated(nope:1)", "unknown"), ("gated(periodic:x)", "knobs"),
                     ("periodic(always)", "only")):
        with pytest.raises(ValueError, match=why):
            parse_spec(bad)
    core, *_ = _core(FAD)
    for bad in ("acked:0(always)", "phased:0(always)"):
        with pytest.raises(ValueError, match="integer >= 1"):
            make_comm_policy(bad, core)


def test_a_rule_without_its_field_or_period_is_refused_by_name():
    core, *_ = _core("comm_process_noise-v0")
    with pytest.raises(ValueError, match=r"'next_out'.*\[control\] announce = true"):
        make_comm_policy("gated(sources:0)", core)
    for spec in ("acked(always)", "phased(event:2)", "phased:4(event:2)"):
        with pytest.raises(ValueError, match=r"'acks'.*\[control\] feedback = true"):
            make_comm_policy(spec, core)
    fading, *_ = _core(FAD)  # acks, but graphs that are not periodic
    with pytest.raises(ValueError, match="not periodic.*phased:P"):
        make_comm_policy("phased(event:2)", fading)
    assert isinstance(make_comm_policy("phased:5(event:2)", fading), Phased)
    announced, *_ = _core(ANN)
    with pytest.raises(ValueError, match="'acks'"):
        make_comm_policy("acked(always)", announced)
    # what the frontier runs where
    assert applicable(load_model(ANN)[0]) == ("gated",)
    assert applicable(load_model(FAD)[0]) == ("acked",)
    assert applicable(load_model(SCH)[0]) == ("acked", "phased")
    assert applicable(load_model("comm_process_noise-v0")[0]) == ()


def test_gated_always_sends_exactly_where_the_next_graph_has_an_out_link():
    """Against the core's own next graph (``nbr_next``: the in-neighbour slots of
    ``G[k+1]``), not the observation field the rule reads."""
    core, obs, mask = _core(ANN, B=3, seed=[1, 2, 3])
    pol = make_comm_policy("gated(always)", core)
    assert isinstance(pol, Gated)
    closed = 0
    for _ in range(40):
        bits = pol.act(obs, mask)[..., 0]
        for b in range(core.B):
            senders = set(core.nbr_next[b][core.nbr_next[b] >= 0].tolist())
            want = np.array([i in senders for i in range(core.N)])
            np.testing.assert_array_equal(bits[b].astype(bool), want)
            closed += int((~want).sum())
        out = core.step(bits[..., None])
        obs, mask = out.obs, out.action_mask
    assert closed > 0


def _agent0(core, obs, k, sent, acks):
    """``obs`` with agent 0's time ``k``, ``silence`` 0 iff it ``sent`` at ``k`` and its
    ``acks`` row."""
    o = obs.copy()
    L = core.layout
    o[..., L.time] = np.float32(k / core.horizon)
    o[:, 0, L.silence] = 0.0 if sent else np.float32(1 / core.horizon)
    o[:, 0, L.acks] = np.asarray(acks, np.float32)
    return o


def test_acked_by_hand():
    """Silent after a transmission lost on every out-link, a probe ``T`` steps later, open
    again after a delivered one; a transmission without out-links changes nothing."""
    core, obs, mask = _core(FAD, B=1)
    N = core.N
    lost, got, none = -np.eye(N)[3], np.eye(N)[3] - np.eye(N)[5], np.zeros(N)
    pol = make_comm_policy("acked:3(always)", core)
    assert isinstance(pol, Acked) and pol.probe == 3
    # (k, sent at k, acks) -> agent 0's gate for step k + 1
    script = [(0, False, none, 1), (1, True, lost, 0), (2, False, none, 0),
              (3, False, none, 0), (4, False, none, 1),  # 3 steps since: a probe
              (5, True, none, 1),  # a message without out-links: still probing
              (6, True, lost, 0), (7, True, got, 1), (8, False, none, 1),
              (9, True, lost, 0), (10, True, none, 0)]
    for k, sent, acks, want in script:
        bits = pol.act(_agent0(core, obs, k, sent, acks), mask)
        assert bits[0, 0, 0] == want, k


def test_phased_by_hand():
    """Per phase ``k mod P``: closed at the phases whose last transmission had no
    out-link, open at the phases never sent at or last heard."""
    core, obs, mask = _core(SCH, B=1)
    N = core.N
    heard, unheard = np.eye(N)[2] - np.eye(N)[4], np.zeros(N)
    pol = make_comm_policy("phased:3(always)", core)
    assert isinstance(pol, Phased) and pol.period == 3
    # (k, sent at k, acks) -> agent 0's gate for step k + 1 (phase (k + 1) mod 3)
    script = [(0, True, unheard, 1),  # phase 0 closed now; the gate is for phase 1
              (1, True, heard, 1), (2, False, unheard, 0),  # phase 0 is closed
              (3, True, heard, 1),  # phase 0 heard again
              (4, True, unheard, 1), (5, False, unheard, 1),
              (6, False, unheard, 0),  # phase 1: unheard at k = 4
              (7, False, unheard, 1), (8, False, unheard, 1)]
    for k, sent, acks, want in script:
        bits = pol.act(_agent0(core, obs, k, sent, acks), mask)
        assert bits[0, 0, 0] == want, k
    assert make_comm_policy("phased(always)", core).period == 12  # the schedule's period


@pytest.mark.parametrize("sid,spec", INFORMED)
def test_informed_rules_read_only_their_own_row(sid, spec):
    """Two members that share agent 0's observations step after step but differ in every
    other agent's row: agent 0 decides the same in both (memory included)."""
    core, obs, mask = _core(sid, B=2, seed=[5, 6])
    pol = make_comm_policy(spec, core, seed=[9, 9])
    rng = np.random.default_rng(0)
    for _ in range(60):
        o, m = obs.copy(), mask.copy()
        o[1, 0], m[1, 0] = o[0, 0], m[0, 0]  # agent 0 sees the same in both members
        bits = pol.act(o, m)
        assert (bits[0, 0] == bits[1, 0]).all()
        out = core.step((rng.random(bits.shape) < 0.4).astype(int))
        obs, mask = out.obs, out.action_mask


@pytest.mark.parametrize("sid,spec", [(FAD, "acked:3(event:1)"), (SCH, "phased(event:2)")])
def test_memory_restarts_with_the_member(sid, spec):
    """A member reset in the middle of the others' episodes acts like a fresh rule on a
    fresh single run with its seed."""
    model, _ = load_model(sid, **frontier_overrides(sid, {}))
    core = BatchedCore(model, 2)
    obs, mask = core.reset([1, 2])
    pol = make_comm_policy(spec, core)
    for _ in range(30):
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


@pytest.mark.parametrize("sid,spec", [(FAD, "acked(sources:0)"), (SCH, "phased(event:2)"),
                                      (ANN, "gated(sources:0)"), (FAD, "oracle(event:1)")])
def test_a_batch_of_seeds_equals_the_single_episodes(sid, spec):
    over = frontier_overrides(sid, {"horizon": 40})
    both = evaluate(sid, spec, [3, 4], over)
    for b, s in enumerate((3, 4)):
        one = evaluate(sid, spec, [s], over)
        for m in both:
            assert both[m][b] == one[m][0]


@pytest.mark.parametrize("sid,rule", [(ANN, "gated"), (SCH, "phased"),
                                      ("comm_schedule-v1", "phased")])
def test_a_gate_on_always_only_drops_messages_that_reach_no_one(sid, rule):
    """The announced next graph and a fixed link schedule without drops tell exactly which
    messages reach no one: gating ``always`` on them keeps the error of ``always`` (bit for
    bit, after the schedule's first period for ``phased``) with far fewer messages."""
    seeds = [11, 12, 13]
    over = frontier_overrides(sid, {"horizon": 60})
    gated = evaluate(sid, f"{rule}(always)", seeds, over)
    always = evaluate(sid, "always", seeds, over)
    np.testing.assert_allclose(gated["mean_rel_error"], always["mean_rel_error"], rtol=1e-12)
    assert (gated["msgs_per_agent_step"] < 0.6 * always["msgs_per_agent_step"]).all()
    assert (gated["reward"] > always["reward"]).all()


def test_acked_stays_silent_on_a_bad_channel():
    """On fading senders, ``acked(always)`` sends far fewer messages than ``always``, and
    fewer of its messages are lost (it stops while its channel is bad)."""
    sid, seeds = FAD, [21, 22, 23]
    over = frontier_overrides(sid, {"horizon": 120})
    lost = {}

    def on_step(tag):
        def record(core, live):
            L = core.layout
            acks = core.observe()[0][..., L.acks]
            lost.setdefault(tag, []).append(((acks < 0).any(-1) & ~(acks > 0).any(-1)).sum())
        return record

    acked = evaluate(sid, "acked(always)", seeds, over, on_step=on_step("acked"))
    always = evaluate(sid, "always", seeds, over, on_step=on_step("always"))
    assert (acked["msgs_per_agent_step"] < 0.7 * always["msgs_per_agent_step"]).all()
    rate = {t: sum(v) / (m["msgs_per_agent_step"].sum() * 120 * 10)
            for (t, v), m in zip(lost.items(), (acked, always), strict=True)}
    assert rate["acked"] < 0.7 * rate["always"], rate


def test_oracle_gates_on_exactly_the_messages_that_arrive():
    """``oracle(always)`` transmits iff the next message reaches an out-neighbour: every
    message it sends arrives somewhere, and its error equals ``always``'s (a message that
    reaches no one changes nothing); ``oracle_channel`` needs no out-link."""
    sid, seeds = FAD, [3, 4]
    over = frontier_overrides(sid, {"horizon": 70})
    sent = []

    def actor(core, s):
        rule = make_comm_policy("oracle(always)", core, seed=list(s))
        assert isinstance(rule, Oracle) and core.nbr_next is None  # no announce needed

        def act(obs, mask):
            if core.k[0] > 0:  # the messages of this step, sent on the oracle's bits
                sent.append((core.transmit.copy(), core.msg.copy(), core.nbr.copy()))
            return rule.act(obs, mask)
        return act

    gated = evaluate(sid, "oracle(always)", seeds, over, actor=actor)
    again = evaluate(sid, "oracle(always)", seeds, over)
    always = evaluate(sid, "always", seeds, over)
    channel = evaluate(sid, "oracle_channel(always)", seeds, over)
    np.testing.assert_array_equal(gated["reward"], again["reward"])
    np.testing.assert_allclose(gated["mean_rel_error"], always["mean_rel_error"])
    np.testing.assert_allclose(channel["mean_rel_error"], always["mean_rel_error"])
    assert (gated["msgs_per_agent_step"] < channel["msgs_per_agent_step"]).all()
    assert gated["msgs_per_agent_step"].mean() < 0.5 * always["msgs_per_agent_step"].mean()
    for transmit, msg, nbr in sent:
        for b, l in zip(*np.nonzero(transmit), strict=True):
            assert msg[b][nbr[b] == l].any()  # someone got it


def test_frontier_kinds_best_decentralised_and_pareto():
    """The frontier runs the informed rules over the bases where they apply and the
    privileged ones as their own kind, never a candidate for best decentralised or the
    Pareto front."""
    rows = frontier(FAD, episodes=3, families={"periodic": (2,)}, progress=False,
                    overrides={"horizon": 30}, informed_bases=("always", "event:2"),
                    settled_bases=("event:2",), settled_knobs=(0.3, 1))
    kinds = {r["policy"]: (r["kind"], r["family"], r["knob"]) for r in rows}
    assert kinds["acked(event:2)"] == ("decentralised", "acked", "event:2")
    assert kinds["settled:0.3(event:2)"] == ("decentralised", "settled", "event:2")
    assert kinds["settled:1.0(event:2)"] == ("decentralised", "settled", "event:2")
    assert kinds["oracle(always)"][0] == kinds["oracle_channel(event:2)"][0] == "privileged"
    assert not any(p.startswith(("gated", "phased")) for p in kinds)
    assert all(r["pareto"] == "" for r in rows if r["kind"] == "privileged")
    dec = [r for r in rows if r["kind"] == "decentralised"]
    best = best_scripted(rows, "decentralised")
    assert best["reward_mean"] == max(r["reward_mean"] for r in dec)
    assert best_scripted(rows)["kind"] != "privileged"
    none = frontier(FAD, episodes=2, families={}, progress=False, overrides={"horizon": 10},
                    informed_bases=(), privileged=False, settled_bases=())
    assert [r["policy"] for r in none] == ["always", "never"]
    with pytest.raises(ValueError, match="centralised"):
        frontier(FAD, episodes=2, families={}, progress=False, informed_bases=("whittle:1",))
    for bad in (0, -1.0, float("nan"), "0.3", True):
        with pytest.raises(ValueError, match="settled_knobs must be numbers > 0"):
            frontier(FAD, episodes=2, families={}, progress=False, settled_knobs=(bad,))
    with pytest.raises(ValueError, match="settled_bases must be a sequence"):
        frontier(FAD, episodes=2, families={}, progress=False, settled_bases="always")


def test_benchmark_command_runs_a_wrapped_rule(tmp_path, capsys):
    from netsense.cli import main

    assert main(["benchmark", ANN, "--policies", "gated(sources:0)", "sources:0",
                 "--seeds", "2", "--override", "horizon=15", "--out", str(tmp_path),
                 "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "| gated(sources:0) |" in printed
    jobs = bm.make_jobs([ANN], ["gated(sources:0)"], [3], overrides={"horizon": 15})
    serial = bm.execute(jobs, backend="serial", progress=False)
    batched = bm.execute(jobs, backend="batched", progress=False)
    for m in ("msgs_per_agent_step", "reward", "mean_rel_error"):
        assert serial[0]["metrics"][m] == pytest.approx(batched[0]["metrics"][m], rel=1e-12)
    with pytest.raises(ValueError, match="unknown"):
        bm.make_jobs([ANN], ["gossip(sources:0)"], [3])
