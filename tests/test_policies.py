"""Scripted policies: they act only through observations and masks, and show the
paper's outcomes when run to the horizon."""

from __future__ import annotations

import numpy as np
import pytest

from netsense.engine.core import BatchedCore
from netsense.env.policies import POLICIES, make_policy
from netsense.env.registry import build_model, list_scenarios, load, make, with_overrides


def run(sid, name, seed=0, **over):
    env = make(sid, **over)
    pol = make_policy(name, env, **({"seed": seed} if name == "random" else {}))
    obs, infos = env.reset(seed=seed)
    total, sent = 0.0, 0
    while env.agents:
        acts = pol.act_dict(env, obs, infos)
        obs, rew, term, trunc, infos = env.step(acts)
        total += sum(rew.values())
        sent += sum(i["transmitted"] for i in infos.values())
    return env, total, sent


@pytest.mark.parametrize("sid", list_scenarios())
def test_random_policy_respects_masks_everywhere(sid):
    over = {"horizon": 3 if sid.startswith("large") else 25}
    run(sid, "random", seed=1, **over)  # default invalid_actions="raise" would fail


def test_freshness_converges_on_the_structured_scenario():
    """Theorem 1: with joint strong connectivity every agent's error decays."""
    env, _, _ = run("random_structured_n20_N10-v0", "freshness")
    assert env.core.errors[0].max() < 1e-6
    assert (env.core.tau[0] >= 0).all()  # Lemma 3: every index finite


def test_freshness_beats_consensus_and_open_loop():
    ret = {p: run("random_structured_n20_N10-v0", p)[1] for p in
           ("freshness", "uniform", "open_loop")}
    assert ret["freshness"] > ret["uniform"] > ret["open_loop"]


def test_open_loop_never_transmits_and_keeps_initial_error():
    env, total, sent = run("fig1_scalar-v0", "open_loop")
    assert sent == 0
    # nodes 1 and 2 never hear anything: estimates stay 0, normalised error 1
    np.testing.assert_allclose(env.core.errors[0, 1:], 1.0)


def test_message_cost_is_charged_per_transmission():
    env, total, sent = run("message_cost-v0", "freshness", horizon=10)
    env2, total2, sent2 = run("message_cost-v0", "freshness", horizon=10,
                              reward={"message_cost": 0.0})
    assert sent == sent2 == 10 * env.core.N
    assert total == pytest.approx(total2 - 0.05 * sent)


def test_tree_policy_needs_periodic_graphs():
    with pytest.raises(ValueError, match="PeriodicGraphs"):
        make_policy("tree", make("message_cost-v0"))
    with pytest.raises(ValueError, match="unknown policy"):
        make_policy("greedy", make("fig1_scalar-v0"))


def test_policies_work_on_batched_arrays():
    model = build_model(with_overrides(load("fig1_scalar-v0"), horizon=12))
    core = BatchedCore(model, 5)
    for name in POLICIES:
        obs, mask = core.reset(3)
        pol = make_policy(name, core)
        for _ in range(12):
            out = core.step(pol.act(obs, mask))
            obs, mask = out.obs, out.action_mask
        assert out.truncated.all()
        if name == "freshness":
            assert out.reward.max() == 0.0  # deadbeat: every estimate exact by k = 12


def test_freshness_policy_uses_only_observations():
    """The action is a function of the observation alone: same observation, same action;
    an observation claiming that nobody has any information gives 'keep' everywhere."""
    env = make("random_structured_n20_N10-v0")
    pol = make_policy("freshness", env)
    core = env.core
    env.reset(seed=0)
    obs, mask = core.observe()
    a1, a2 = pol.act(obs, mask), pol.act(obs.copy(), mask.copy())
    np.testing.assert_array_equal(a1, a2)
    L = env.layout
    o = obs.copy()
    o[..., L.own_omega] = 1.0  # pretend nobody knows anything
    o[..., L.slot_omega] = 1.0
    a = pol.act(o, mask)
    assert (a[..., : core.N] == 0).all()  # nothing fresher to adopt: keep


@pytest.mark.parametrize("seed, what", [(2.7, "2.7"), ([3, 4.5], "4.5"), (-1, "-1"),
                                        (True, "True"), ([1, "2"], "'2'")])
def test_random_policy_rejects_seeds_it_would_have_to_truncate(seed, what):
    core = BatchedCore(build_model(load("fig1_scalar-v0")), 2)
    with pytest.raises(ValueError, match=f"seeds must be non-negative integers, got {what}"):
        make_policy("random", core, seed=seed)


@pytest.mark.parametrize("p", [-0.1, 1.5, float("nan")])
def test_random_policy_rejects_a_transmit_probability_outside_0_1(p):
    core = BatchedCore(build_model(load("fig1_scalar-v0")), 1)
    with pytest.raises(ValueError, match="p_transmit must be a probability"):
        make_policy("random", core, p_transmit=p)


def test_random_policy_takes_numpy_integer_seeds_as_their_int():
    core = BatchedCore(build_model(load("fig1_scalar-v0")), 2)
    obs, mask = core.reset(0)
    a = make_policy("random", core, seed=[np.int64(5), np.uint8(6)]).act(obs, mask)
    b = make_policy("random", core, seed=[5, 6]).act(obs, mask)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("seed", range(3))
def test_freshness_policy_equals_the_rule_on_the_indices(seed):
    """Read from the observation, the policy chooses what ``kernels.freshness_choice``
    chooses on the indices and messages behind that observation (mid-run, with link
    failures: slots without messages, omega indices and ties)."""
    from netsense.kernels import update as kernels

    model = build_model(with_overrides(load("link_failures-v0"), horizon=40))
    core = BatchedCore(model, 4)
    pol = make_policy("freshness", core)
    obs, mask = core.reset(seed)
    adopted = 0
    for _ in range(12):
        act = pol.act(obs, mask)
        _, ref = kernels.freshness_choice(core.tau, core.nbr, core.msg)  # slots with a message
        np.testing.assert_array_equal(act[..., :core.M], ref + 1)
        assert (act[..., core.M] == 1).all()
        adopted += int((ref >= 0).sum())
        out = core.step(act)
        obs, mask = out.obs, out.action_mask
    assert adopted > 0


@pytest.mark.parametrize("shape, dtype", [((4, 7), np.float32), ("last+1", np.float32),
                                          ("ok", np.int64)])
def test_freshness_policy_rejects_observations_of_another_shape(shape, dtype):
    core = BatchedCore(build_model(load("fig1_scalar-v0")), 1)
    pol = make_policy("freshness", core)
    size = core.layout.size
    shape = {"last+1": (1, core.N, size + 1), "ok": (1, core.N, size)}.get(shape, shape)
    with pytest.raises(ValueError, match="obs must be a float array of shape"):
        pol.act(np.zeros(shape, dtype), None)
