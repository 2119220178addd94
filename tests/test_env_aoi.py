"""Age of information in the environment's infos (issue 9 item 2): ``infos[agent]["aoi"]``
equals :func:`netsense.graphs.aoi.aoi_stats` of the agent's freshness-index history."""

from __future__ import annotations

import json

import numpy as np
import pytest

from netsense.env.pettingzoo_env import RunningAoI
from netsense.env.policies import make_policy
from netsense.env.registry import make
from netsense.graphs.aoi import aoi_stats


@pytest.mark.parametrize("sid, policy", [("link_failures-v0", "freshness"),
                                         ("fault_liar-v0", "freshness"),
                                         ("random_structured_n20_N10-v0", "uniform"),
                                         ("message_cost-v0", "random")])
def test_aoi_info_equals_aoi_stats_of_the_index_history(sid, policy):
    env = make(sid, aoi_info=True, horizon=40, invalid_actions="keep")
    pol = make_policy(policy, env) if policy != "random" else make_policy(policy, env, seed=1)
    obs, infos = env.reset(seed=3)
    history = [env.core.tau[0].copy()]
    for k in range(41):
        ref = aoi_stats(np.array(history)[:, None])  # (k + 1 steps, B = 1, N, N)
        for i, a in enumerate(env.possible_agents):
            got = infos[a]["aoi"]
            np.testing.assert_array_equal(got["tau"], history[-1][i])
            for key in ("mean", "peak", "max", "omega_fraction"):
                np.testing.assert_allclose(got[key], ref[key][0, i], rtol=1e-12,
                                           equal_nan=True, err_msg=f"{key} k={k}")
        if not env.agents:
            break
        obs, _, _, _, infos = env.step(pol.act_dict(env, obs, infos))
        history.append(env.core.tau[0].copy())
    assert k == 40
    json.dumps({a: {key: np.asarray(v).tolist() for key, v in infos[a]["aoi"].items()}
                for a in infos})


def test_aoi_hand_computed_cases():
    # a source's own index is 0 at every step: mean 0, every step a refresh (peak 0);
    # with the open-loop policy nobody hears anything: omega throughout
    env = make("fig1_scalar-v0", aoi_info=True, horizon=6)
    pol = make_policy("open_loop", env)
    obs, infos = env.reset(seed=0)
    while env.agents:
        obs, _, _, _, infos = env.step(pol.act_dict(env, obs, infos))
    own = infos["sensor_0"]["aoi"]
    assert own["mean"][0] == 0 and own["peak"][0] == 0 and own["max"][0] == 0
    assert own["omega_fraction"][0] == 0
    other = infos["sensor_1"]["aoi"]
    assert np.isnan(other["mean"][0]) and np.isnan(other["peak"][0])
    assert other["max"][0] == -1 and other["omega_fraction"][0] == 1 and other["tau"][0] == -1
    # hand-made sequence 0 1 2 0 1 omega 3: mean (0+1+2+0+1+3)/6 = 7/6, peaks: 2 (before
    # the refresh 2 -> 0) and nothing at 1 -> omega or omega -> 3, max 3, omega 1/7
    run = RunningAoI(np.array([[0]]))
    for v in (1, 2, 0, 1, -1, 3):
        run.update(np.array([[v]]))
    st = run.stats()
    assert st["mean"][0, 0] == pytest.approx(7 / 6) and st["peak"][0, 0] == 2
    assert st["max"][0, 0] == 3 and st["omega_fraction"][0, 0] == pytest.approx(1 / 7)


def test_aoi_info_is_off_by_default_and_validated():
    env = make("fig1_scalar-v0")
    obs, infos = env.reset(seed=0)
    assert "aoi" not in infos["sensor_0"]
    with pytest.raises(ValueError, match="aoi_info"):
        make("fig1_scalar-v0", aoi_info="yes")


def test_faulty_flag_in_infos():
    env = make("fault_crash-v0", horizon=3)
    pol = make_policy("freshness", env)
    obs, infos = env.reset(seed=0)
    obs, _, _, _, infos = env.step(pol.act_dict(env, obs, infos))
    assert [infos[a]["faulty"] for a in env.possible_agents] == [False] * 4 + [True] + \
        [False] * 3
    obs, infos = make("fig1_scalar-v0").reset(seed=0)
    assert "faulty" not in infos["sensor_0"]


def test_env_with_aoi_info_passes_the_parallel_checker_and_pickles():
    import pickle
    import warnings

    from pettingzoo.test import parallel_api_test

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        parallel_api_test(make("fault_liar-v0", aoi_info=True, horizon=15), num_cycles=100)
    env = make("fault_liar-v0", aoi_info=True, horizon=15)
    pol = make_policy("freshness", env)
    obs, infos = env.reset(seed=1)
    obs, *_, infos = env.step(pol.act_dict(env, obs, infos))
    clone = pickle.loads(pickle.dumps(env))
    while env.agents:
        acts = pol.act_dict(env, obs, infos)
        obs, _, _, _, infos = env.step(acts)
        _, _, _, _, infos_c = clone.step(acts)
        for a in env.possible_agents:
            for key, v in infos[a]["aoi"].items():
                np.testing.assert_array_equal(v, infos_c[a]["aoi"][key])
