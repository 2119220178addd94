"""The environment driven by the scripted policies reproduces the core observers exactly.

The observers (:class:`netsense.FreshnessObserver`, :class:`netsense.ConsensusObserver`)
are fed the environment's own measurements, arrivals and graphs step by step; the
environment only sees the policies' actions, built from observations and masks.
"""

import numpy as np
import pytest

import netsense as ns
from netsense.env.policies import make_policy
from netsense.env.registry import make


def _rollout_against(env, observer, policy_name, steps, exact=True):
    policy = make_policy(policy_name, env)
    obs, infos = env.reset(seed=7)
    core = env.core
    env.dropped = 0
    for k in range(steps):
        y, adj, arrived = core.y[0].copy(), core.adjacency[0].copy(), core.y_arrived[0].copy()
        observer.step(y, adj, arrived=arrived)
        env.dropped += int((~arrived & core.model.plant.output_mask.any(1)).sum())
        obs, rew, term, trunc, infos = env.step(policy.act_dict(env, obs, infos))
        if exact:
            np.testing.assert_array_equal(core.Z[0], observer.z_estimates, err_msg=f"k={k}")
        else:
            np.testing.assert_allclose(core.Z[0], observer.z_estimates, rtol=1e-12,
                                       atol=1e-12 * (1 + np.abs(observer.z_estimates).max()),
                                       err_msg=f"k={k}")
        np.testing.assert_array_equal(core.tau[0], observer.indices, err_msg=f"k={k}")
        np.testing.assert_allclose(core.estimates[0], observer.estimates, rtol=1e-12,
                                   atol=1e-9 * (1 + np.abs(observer.estimates).max()))
        if not env.agents:
            break
    return k + 1


@pytest.mark.parametrize("sid", ["fig1_scalar-v0", "random_structured_n20_N10-v0",
                                 "message_cost-v0"])
def test_freshness_policy_reproduces_freshness_observer(sid):
    env = make(sid)
    observer = ns.FreshnessObserver(env.core.model.design)
    steps = _rollout_against(env, observer, "freshness", env.core.horizon)
    assert steps == env.core.horizon
    # the indices really moved: every index is finite by the end (Lemma 3)
    assert (env.core.tau[0] >= 0).all()


def test_freshness_policy_with_measurement_drops_and_link_failures():
    env = make("link_failures-v0", arrivals={"message": {"kind": "always"}})
    observer = ns.FreshnessObserver(env.core.model.design)
    _rollout_against(env, observer, "freshness", env.core.horizon)
    assert env.dropped > 0  # the sources really ran open loop at some steps


def test_uniform_policy_reproduces_uniform_consensus():
    env = make("random_structured_n20_N10-v0", horizon=40)
    observer = ns.ConsensusObserver(env.core.model.design, weights="uniform")
    _rollout_against(env, observer, "uniform", 40, exact=False)


def test_tree_policy_reproduces_tree_consensus_on_fig1():
    env = make("fig1_scalar-v0")
    observer = ns.ConsensusObserver(env.core.model.design, weights="tree")
    _rollout_against(env, observer, "tree", env.core.horizon)


def test_fig1_outcome_freshness_converges_consensus_diverges():
    """Fig. 2 of the paper: with a = 2 the freshness policy's error vanishes (deadbeat,
    Corollary 1) while uniform and tree consensus errors blow up."""
    final = {}
    for name in ("freshness", "uniform", "tree"):
        env = make("fig1_scalar-v0", horizon=20)
        pol = make_policy(name, env)
        obs, infos = env.reset(seed=0)
        while env.agents:
            obs, rew, term, trunc, infos = env.step(pol.act_dict(env, obs, infos))
        x = env.core.x[0]
        final[name] = np.abs(env.core.estimates[0, :, 0] - x[0]).max()
    assert final["freshness"] <= 1e-9 * (1 + abs(x[0]))
    assert final["uniform"] > 1e2 and final["tree"] > 1e2
