"""PettingZoo conformance, determinism and pickling over every registered scenario."""

from __future__ import annotations

import hashlib
import json
import pickle
import subprocess
import sys
import warnings

import numpy as np
import pytest
from pettingzoo.test import (
    api_test,
    parallel_api_test,
    parallel_seed_test,
    render_test,
    state_test,
)
from pettingzoo.utils import parallel_to_aec

from netsense.env.policies import make_policy
from netsense.env.registry import list_scenarios, make

SCENARIOS = list_scenarios()


def short(sid: str) -> dict:
    """Horizon overrides that keep the suite fast (the large scenario is N = 100; the task at
    N = 1000, ``comm_channel_kofn_n1000-v0``, runs 2 steps: the AEC checks step its 1000
    agents one at a time, and its state check is marked slow, see :data:`STATE_CASES`)."""
    if "_n1000-" in sid:
        return {"horizon": 2}
    return {"horizon": 4 if sid.startswith("large") else 15}


#: The state check at N = 1000 reads the N^2 state at each of the N agents' AEC steps
#: (about 30 s whatever the horizon): marked slow.
STATE_CASES = [pytest.param(s, marks=pytest.mark.slow) if "_n1000-" in s else s
               for s in SCENARIOS]


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


@pytest.mark.parametrize("sid", SCENARIOS)
def test_parallel_api(sid):
    env = make(sid, **short(sid))
    parallel_api_test(env, num_cycles=1000)
    # parallel_api_test reads masks only from observations: tolerate masked samples here
    info_env = make(sid, action_mask_in="info", invalid_actions="keep", **short(sid))
    parallel_api_test(info_env, num_cycles=1000)


@pytest.mark.parametrize("sid", SCENARIOS)
def test_parallel_seed(sid):
    # the checker samples actions without masks, so masked choices must be tolerated
    parallel_seed_test(lambda: make(sid, invalid_actions="keep", **short(sid)), num_cycles=50)


@pytest.mark.parametrize("sid", SCENARIOS)
def test_aec_api(sid):
    api_test(parallel_to_aec(make(sid, **short(sid))), num_cycles=30)


@pytest.mark.parametrize("sid", STATE_CASES)
def test_state(sid):
    par = make(sid, invalid_actions="keep", **short(sid))
    state_test(parallel_to_aec(make(sid, invalid_actions="keep", **short(sid))), par,
               num_cycles=3)
    par.reset(seed=0)
    s = par.state()
    c = par.core
    assert s.shape == par.state_space.shape and par.state_space.contains(s)
    # layout: x, every estimate of x, G[k]
    np.testing.assert_array_equal(s[: c.n], c.x[0])
    np.testing.assert_array_equal(s[c.n + c.N * c.n:].reshape(c.N, c.N), c.adjacency[0])


@pytest.mark.parametrize("sid", ["fig1_scalar-v0", "large_n20_N100-v0"])
def test_render(sid):
    render_test(lambda render_mode=None: parallel_to_aec(
        make(sid, render_mode=render_mode, **short(sid))))


def test_every_space_is_shared_and_named():
    for sid in SCENARIOS:
        env = make(sid, **short(sid))
        assert env.possible_agents == [f"sensor_{i}" for i in range(env.core.N)]
        spaces = {id(env.observation_space(a)) for a in env.possible_agents}
        assert len(spaces) == 1
        assert len({id(env.action_space(a)) for a in env.possible_agents}) == 1


def _rollout_digest(sid: str, seed: int, steps: int | None = None) -> str:
    """Hash of observations, rewards, terminations and infos of a random-policy rollout."""
    env = make(sid, **short(sid))
    pol = make_policy("random", env, seed=seed)
    obs, infos = env.reset(seed=seed)
    h = hashlib.sha256()
    while env.agents:
        obs, rew, term, trunc, infos = env.step(pol.act_dict(env, obs, infos))
        for a in env.possible_agents:
            h.update(obs[a]["observation"].tobytes())
            h.update(obs[a]["action_mask"].tobytes())
        h.update(json.dumps([rew, term, trunc, infos], sort_keys=True).encode())
    h.update(env.core.Z.tobytes())
    return h.hexdigest()


def test_determinism_full_horizon_and_across_processes():
    here = {sid: _rollout_digest(sid, 3) for sid in SCENARIOS}
    assert here == {sid: _rollout_digest(sid, 3) for sid in SCENARIOS}
    assert _rollout_digest(SCENARIOS[0], 4) != here[SCENARIOS[0]]
    code = ("import json, sys; sys.path.insert(0, 'tests');"
            "from test_env_conformance import _rollout_digest, SCENARIOS;"
            "print(json.dumps({s: _rollout_digest(s, 3) for s in SCENARIOS}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=str(__import__("pathlib").Path(__file__).parents[1]),
                         env={**__import__("os").environ, "PYTHONHASHSEED": "123"})
    assert json.loads(out.stdout.strip().splitlines()[-1]) == here


@pytest.mark.parametrize("sid", SCENARIOS)
def test_pickle_round_trip_mid_episode(sid):
    env = make(sid, **short(sid))
    pol = make_policy("freshness", env)
    obs, infos = env.reset(seed=5)
    obs, *_, infos = env.step(pol.act_dict(env, obs, infos))
    clone = pickle.loads(pickle.dumps(env))
    obs_c = obs
    while env.agents:
        acts = pol.act_dict(env, obs, infos)
        obs, rew, term, trunc, infos = env.step(acts)
        obs_c, rew_c, term_c, trunc_c, _ = clone.step(acts)
        assert rew == rew_c and term == term_c and trunc == trunc_c
        for a in env.possible_agents:
            np.testing.assert_array_equal(obs[a]["observation"], obs_c[a]["observation"])
    np.testing.assert_array_equal(env.core.Z, clone.core.Z)
    assert not clone.agents
