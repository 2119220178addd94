"""Faults in the environment (issue 9 item 4): each ``[[faults]]`` kind has its documented
effect, and the freshness policy in the environment equals the library's faulty runs
(:func:`netsense.observers.faults.run_with_faults`,
:class:`netsense.observers.faults.LyingFreshnessObserver`)
on the same graphs and initial state."""

from __future__ import annotations

import numpy as np
import pytest

from netsense.engine.core import BatchedCore
from netsense.env.policies import make_policy
from netsense.env.registry import build_model, load, make, with_overrides
from netsense.observers.faults import (
    CrashedAgents,
    LyingAgent,
    StuckSensor,
    captured_fraction,
    run_with_faults,
)

NOISELESS = {"noise": {"process": {"kind": "none"}, "measurement": {"kind": "none"}}}


def rollout(env, policy="freshness", seed=0):
    """Run to the horizon; returns per-step records (k = 0..K)."""
    pol = make_policy(policy, env)
    obs, infos = env.reset(seed=seed)
    c = env.core
    rec = {"tau": [c.tau[0].copy()], "Z": [c.Z[0].copy()], "x": [c.x[0].copy()],
           "y": [c.y[0].copy()], "adj": [], "tx": [c.transmit[0].copy()], "rew": [],
           "obs": [obs]}
    while env.agents:
        rec["adj"].append(c.adjacency[0].copy())
        obs, rew, _, _, infos = env.step(pol.act_dict(env, obs, infos))
        for key, v in (("tau", c.tau[0]), ("Z", c.Z[0]), ("x", c.x[0]), ("y", c.y[0]),
                       ("tx", c.transmit[0])):
            rec[key].append(v.copy())
        rec["rew"].append([rew[a] for a in env.possible_agents])
        rec["obs"].append(obs)
    out = {k: np.array(v) for k, v in rec.items() if k != "obs"}
    out["obs"] = rec["obs"]
    return out


def sub_errors(env, rec):
    """``(K + 1, N agents, N substates)`` error norms per substate (Lemma 1 coordinates)."""
    c = env.core
    ez = rec["Z"] - (rec["x"] @ c.T)[:, None, :]
    onehot = (c.block_of[:, None] == np.arange(c.N)[None, :]).astype(float)
    return np.sqrt((ez ** 2) @ onehot)


@pytest.mark.parametrize("sid, fault", [
    ("fault_crash-v0", CrashedAgents(4, at=20)),
    ("fault_stuck_sensor-v0", StuckSensor(4, at=20, mode="stuck")),
    ("fault_stuck_sensor-v0", StuckSensor(4, at=20, mode="stale", delay=5)),
    ("fault_liar-v0", LyingAgent(0, claim=0, at=10)),
])
def test_env_freshness_policy_equals_library_faulty_run(sid, fault):
    """Noiseless plant: the library run on the environment's own graphs and x[0] gives the
    same indices at every step and the same estimates."""
    over = dict(NOISELESS)
    if isinstance(fault, StuckSensor):
        over["faults"] = [fault.to_dict()]
    env = make(sid, **over)
    assert env.model.faults == (fault,)
    rec = rollout(env)
    c = env.core
    graphs = rec["adj"][None]  # (1, K, N, N)
    tr, obs = run_with_faults(c.model.plant, c.model.design, graphs, rec["x"][:1], [fault])
    np.testing.assert_array_equal(rec["tau"], tr.tau[:, 0])
    np.testing.assert_allclose(rec["Z"][-1], obs.z_estimates[0], rtol=1e-9,
                               atol=1e-9 * (1 + np.abs(rec["Z"][-1]).max()))
    assert (c.alive == tr.alive).all()


def test_crashed_source_leaves_its_substate_open_loop_with_growing_indices():
    env = make("fault_crash-v0")
    N, at = env.core.N, 20
    rec = rollout(env)
    healthy_env = make("fault_crash-v0", faults=[])
    healthy = rollout(healthy_env)
    others = [i for i in range(N) if i != 4]
    # agent 4 never transmits from its crash step on (its action asked to, every step)
    assert not rec["tx"][at:, 4].any() and rec["tx"][:at, 4].all()
    # nobody can adopt substate 4 any more: once the last pre-crash information has
    # spread ((N - 1) T = 14 steps, Lemma 3), every other index grows by one per step
    t4 = rec["tau"][:, others, 4]
    assert np.all(t4[at + 14:] >= 0)
    np.testing.assert_array_equal(np.diff(t4[at + 14:], axis=0), 1)
    assert np.all(rec["tau"][:, 4, 4] == 0)
    np.testing.assert_array_equal(rec["tau"][:at + 1], healthy["tau"][:at + 1])
    assert healthy["tau"][at + 14:, others, 4].max() <= 2 * 2 * (N - 1)  # Lemma 5 bound
    # open loop on a noisy plant (eq. (12)): over 32 seeds the other agents' substate-4
    # error ends far above the healthy run's and above the crashed source's own (still
    # closed-loop) error; same seeds: same plant, noise and graphs
    e_crash, e_ok = _final_substate_error("fault_crash-v0", 4), _final_substate_error(
        "fault_crash-v0", 4, faults=[])
    assert e_crash[:, others].mean() > 3 * e_ok[:, others].mean()
    assert e_crash[:, others].mean() > 3 * e_crash[:, 4].mean()


def _final_substate_error(sid, j, B=32, **over):
    """``(B, N)`` error on substate ``j`` at the horizon, freshness policy, seeds 0..B-1."""
    core = BatchedCore(build_model(with_overrides(load(sid), **over)), B)
    o, m = core.reset(0)
    pol = make_policy("freshness", core)
    for _ in range(core.horizon):
        out = core.step(pol.act(o, m))
        o, m = out.obs, out.action_mask
    ez = core.Z - (core.x @ core.T)[:, None, :]
    return np.sqrt((ez[:, :, core.block_of == j] ** 2).sum(-1))


def test_crashed_agent_is_excluded_from_team_error_and_rewards():
    env = make("fault_crash-v0", horizon=25, reward={"team_weight": 0.5, "message_cost": 0.1})
    rec = rollout(env)
    c = env.core
    assert c.alive.tolist() == [True] * 4 + [False] + [True] * 3
    e = c.errors[0]
    mean_alive = e[c.alive].mean()
    want = -(0.5 * e + 0.5 * mean_alive) - 0.1 * rec["tx"][-1]
    want[4] = 0.0  # crashed: no error reward, and it no longer transmits (no cost)
    np.testing.assert_allclose(rec["rew"][-1], want, rtol=1e-12)


@pytest.mark.parametrize("mode", ["stuck", "stale"])
def test_stuck_or_stale_sensor_replaces_the_reading_and_spreads_a_wrong_substate(mode):
    fault = {"kind": "stuck_sensor", "agents": [4], "at": 20, "mode": mode, "delay": 5}
    env = make("fault_stuck_sensor-v0", faults=[fault])
    rec = rollout(env)
    healthy_env = make("fault_stuck_sensor-v0", faults=[])
    healthy = rollout(healthy_env)
    K = env.core.horizon
    # oracle: the true readings of the same seed (the plant does not depend on faults)
    true = healthy["y"][:, 4]
    for k in range(K + 1):
        want = true[k] if k < 20 else (true[20] if mode == "stuck" else true[k - 5])
        np.testing.assert_array_equal(rec["y"][k, 4], want, err_msg=f"k={k}")
        np.testing.assert_array_equal(rec["y"][k, :4], healthy["y"][k, :4])
    # the source still claims tau = 0: indices are exactly the healthy ones
    np.testing.assert_array_equal(rec["tau"], healthy["tau"])
    e, e_ok = sub_errors(env, rec), sub_errors(healthy_env, healthy)
    # its own substate's error grows; substates 0..3 (upstream, Lemma 1) are unaffected
    assert e[-1, 4, 4] > 10 * e_ok[-1, 4, 4] and e[-1, 4, 4] > e[30, 4, 4]
    np.testing.assert_allclose(e[:, :, :4], e_ok[:, :, :4], rtol=1e-9, atol=1e-12)


def test_liar_claiming_fresh_indices_is_adopted_by_its_neighbours():
    env = make("fault_liar-v0")
    rec = rollout(env)
    c, L = env.core, env.layout
    N, H, at = c.N, c.horizon, 10
    # what the liar's neighbours see: every slot holding agent 0's message after step 10
    # shows age 0 (not omega) for every substate
    seen = 0
    for k in range(at, H):
        obs = rec["obs"][k]
        for a in env.possible_agents:
            o = obs[a]["observation"]
            ids = np.rint(o[L.slot_id] * N).astype(int) - 1
            for d in np.flatnonzero((ids == 0) & (o[L.slot_arrived] > 0.5)):
                seen += 1
                assert np.all(o[L.slot_age].reshape(c.D, N)[d] == 0)
                assert not o[L.slot_omega].reshape(c.D, N)[d].any()
        # the liar itself observes its claimed row (so the freshness rule never adopts)
        o0 = obs["sensor_0"]["observation"]
        assert np.all(o0[L.own_age] == 0) and not o0[L.own_omega].any()
    assert seen > 0
    # adopted through advance_indices: in this very episode honest agents hold
    # information that originates at the liar (the library's provenance bookkeeping on
    # the same graphs; its indices equal the environment's, see the equivalence test)
    tau = rec["tau"]
    honest = np.arange(1, N)
    _, lib = run_with_faults(c.model.plant, c.model.design, np.array(rec["adj"])[None],
                             rec["x"][:1], [LyingAgent(0, claim=0, at=at)])
    assert captured_fraction(lib)[0] > 0.2
    np.testing.assert_array_equal(lib.indices[0], tau[-1])
    # and honest agents' errors are worse than in the healthy run
    healthy_env = make("fault_liar-v0", faults=[])
    healthy = rollout(healthy_env)
    e, e_ok = sub_errors(env, rec), sub_errors(healthy_env, healthy)
    assert e[-1, honest].sum() > 10 * e_ok[-1, honest].sum()
    assert c.alive.tolist() == [False] + [True] * (N - 1)
    np.testing.assert_array_equal(tau[:at + 1], healthy["tau"][:at + 1])  # honest before


@pytest.mark.parametrize("sid, over", [
    ("fault_crash-v0", {}),
    ("fault_stuck_sensor-v0", {"faults": [{"kind": "stuck_sensor", "agents": [4], "at": 20,
                                           "mode": "stale", "delay": 5}]}),
    ("fault_stuck_sensor-v0", {}),
    ("fault_liar-v0", {}),
])
def test_faults_are_per_member_across_partial_resets(sid, over):
    """Fault state is per member (crash and lie onsets use each member's own k, the stuck
    or stale memory restarts with the member): after member 1 alone is reset at k = 25,
    every member still equals a single environment with its seed, bit for bit."""
    B = 3
    core = BatchedCore(build_model(with_overrides(load(sid), **over)), B)
    obs, mask = core.reset([10, 20, 30])
    pol = make_policy("freshness", core)
    ref = [make(sid, **over) for _ in range(B)]
    ref_obs = [r.reset(seed=s)[0] for r, s in zip(ref, [10, 20, 30], strict=True)]
    for k in range(50):
        if k == 25:
            obs, mask = core.reset([0, 99, 0], members=np.array([False, True, False]))
            ref_obs[1] = ref[1].reset(seed=99)[0]
        act = pol.act(obs, mask)
        out = core.step(act)
        obs, mask = out.obs, out.action_mask
        for b in range(B):
            ref_obs[b], rew, *_ = ref[b].step({a: act[b, i]
                                               for i, a in enumerate(ref[b].possible_agents)})
            np.testing.assert_array_equal(obs[b], np.stack(
                [ref_obs[b][a]["observation"] for a in ref[b].possible_agents]))
            np.testing.assert_array_equal(out.reward[b], list(rew.values()))
            np.testing.assert_array_equal(core.Z[b], ref[b].core.Z[0])
