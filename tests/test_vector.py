"""Vector interfaces over the batched core (issue 8, items 2 and 6): the array API with
same-step auto-reset, the Gymnasium VectorEnv with B x N agent slots, the SB3 VecEnv."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from netsense.env.policies import make_policy
from netsense.env.registry import make
from netsense.env.vector import AgentVectorEnv, BatchedEnv, load_model


def single_arrays(env, obs):
    a = env.possible_agents
    return (np.stack([obs[x]["observation"] for x in a]),
            np.stack([obs[x]["action_mask"] for x in a]))


def as_dict(env, act):
    return {a: act[i] for i, a in enumerate(env.possible_agents)}


def test_b1_equals_the_pettingzoo_env_step_by_step():
    """B = 1 through the array API is the single environment, across a chunk boundary
    (64 steps) and an auto-reset."""
    sid, H = "link_failures-v0", 70
    be = BatchedEnv(sid, 1, horizon=H)
    env = make(sid, horizon=H)
    obs, info = be.reset(seed=7)
    so = env.reset(seed=7)[0]
    pol = make_policy("random", be.core, seed=3, p_transmit=0.6)
    for k in range(H):
        o, m = single_arrays(env, so)
        np.testing.assert_array_equal(obs[0], o)
        np.testing.assert_array_equal(info["action_mask"][0], m)
        act = pol.act(obs, info["action_mask"])
        obs, rew, term, trunc, info = be.step(act)
        so, srew, sterm, strunc, sinfo = env.step(as_dict(env, act[0]))
        np.testing.assert_array_equal(rew[0], [srew[a] for a in env.possible_agents])
        np.testing.assert_array_equal(info["error"][0],
                                      [sinfo[a]["error"] for a in env.possible_agents])
        assert bool(trunc[0]) == strunc["sensor_0"] == (k == H - 1)
        assert not term[0]
    # the last step returned the new episode's first observation; the final one is kept
    o, m = single_arrays(env, so)
    assert info["_final_obs"].tolist() == [True]
    np.testing.assert_array_equal(info["final_obs"][0], o)
    np.testing.assert_array_equal(info["final_action_mask"][0], m)
    fresh = make(sid, horizon=H)
    o2, m2 = single_arrays(fresh, fresh.reset(seed=int(be.episode_seeds[0]))[0])
    np.testing.assert_array_equal(obs[0], o2)
    np.testing.assert_array_equal(info["action_mask"][0], m2)


def test_auto_reset_is_per_member_and_members_stay_independent():
    """Members whose episodes are out of phase: each finishes at its own step, only it is
    restarted, and every member equals an independent single env all along."""
    sid, H, B = "fig1_scalar-v0", 6, 3
    be = BatchedEnv(sid, B, horizon=H)
    obs, info = be.reset(seed=100)
    refs = [make(sid, horizon=H) for _ in range(B)]
    ref_obs = [r.reset(seed=100 + b)[0] for b, r in enumerate(refs)]
    pol = make_policy("random", be.core, seed=0)
    finished = {b: [] for b in range(B)}
    for k in range(20):
        if k == 2:  # put member 1 out of phase
            obs, info = be.reset_at([1], seed=50)
            assert be.episode_seeds[1] == 51
            ref_obs[1] = refs[1].reset(seed=51)[0]
        act = pol.act(obs, info["action_mask"])
        obs, rew, term, trunc, info = be.step(act)
        for b, r in enumerate(refs):
            ref_obs[b], srew, _, strunc, _ = r.step(as_dict(r, act[b]))
            np.testing.assert_array_equal(rew[b], [srew[a] for a in r.possible_agents])
            assert bool(trunc[b]) == strunc["sensor_0"]
            if trunc[b]:
                finished[b].append(k)
                assert info["_final_obs"][b]
                np.testing.assert_array_equal(info["final_obs"][b],
                                              single_arrays(r, ref_obs[b])[0])
                ref_obs[b] = r.reset(seed=int(be.episode_seeds[b]))[0]
            elif "_final_obs" in info:
                assert not info["_final_obs"][b]
            o, m = single_arrays(r, ref_obs[b])
            np.testing.assert_array_equal(obs[b], o)
            np.testing.assert_array_equal(info["action_mask"][b], m)
    assert finished == {0: [5, 11, 17], 1: [7, 13, 19], 2: [5, 11, 17]}
    assert be.core.k.tolist() == [2, 0, 2]


def test_auto_reset_seeds_are_reproducible_and_distinct():
    def episode_seeds(seed):
        be = BatchedEnv("fig1_scalar-v0", 4, horizon=3)
        be.reset(seed=seed)
        out = [be.episode_seeds.copy()]
        act = np.zeros((4, 3, 4), dtype=np.int64)
        for _ in range(6):
            be.step(act)
        out.append(be.episode_seeds.copy())
        return np.concatenate(out)

    a, b = episode_seeds(5), episode_seeds(5)
    np.testing.assert_array_equal(a, b)
    assert a[:4].tolist() == [5, 6, 7, 8]
    assert len(set(a.tolist())) == a.size
    assert not np.array_equal(a, episode_seeds(6))


def test_without_auto_reset_members_run_past_the_horizon():
    be = BatchedEnv("fig1_scalar-v0", 2, horizon=2, auto_reset=False)
    obs, info = be.reset(seed=0)
    act = np.zeros((2, 3, 4), dtype=np.int64)
    for _ in range(3):
        obs, rew, term, trunc, info = be.step(act)
        assert "final_obs" not in info
    assert be.core.k.tolist() == [3, 3] and trunc.all()
    obs, info = be.reset_at(np.array([True, False]))
    assert be.core.k.tolist() == [0, 3]


def test_array_api_rejects_bad_input():
    with pytest.raises(ValueError, match="num_envs"):
        BatchedEnv("fig1_scalar-v0", 0)
    with pytest.raises(ValueError, match="PettingZoo env"):
        BatchedEnv("fig1_scalar-v0", 2, render_mode="ansi")
    with pytest.raises(ValueError, match="unknown scenario"):
        BatchedEnv("nope-v0", 2)
    with pytest.raises(ValueError, match="overrides need a scenario id"):
        load_model(make("fig1_scalar-v0").model, horizon=3)
    be = BatchedEnv("fig1_scalar-v0", 2)
    with pytest.raises(ValueError, match="reset"):
        be.step(np.zeros((2, 3, 4), dtype=np.int64))
    be.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        be.step(np.zeros((2, 3, 3), dtype=np.int64))
    with pytest.raises(ValueError, match="member indices"):
        be.reset_at([2])
    with pytest.raises(ValueError, match="seed"):
        be.reset(seed=-1)
    with pytest.raises(ValueError, match="seed"):
        be.reset(seed=[1, 2])


# ----------------------------------------------------------------------------- Gymnasium
def test_agent_vector_env_slots_spaces_and_autoreset():
    B, H = 3, 4
    env = AgentVectorEnv("link_failures-v0", B, horizon=H)
    N = env.num_agents
    assert env.num_envs == B * N and env.metadata["autoreset_mode"].value == "SameStep"
    obs, infos = env.reset(seed=2)
    assert obs.shape == (B * N, env.single_observation_space.shape[0])
    assert env.observation_space.contains(obs)
    be = BatchedEnv("link_failures-v0", B, horizon=H)
    ref_obs, ref_info = be.reset(seed=2)
    np.testing.assert_array_equal(obs, ref_obs.reshape(B * N, -1))
    pol = make_policy("freshness", be.core)
    for k in range(H):
        masks = env.action_masks()
        assert masks.dtype == bool and masks.shape == (B * N, env.batched.mask_size)
        np.testing.assert_array_equal(masks, infos["action_mask"].astype(bool))
        act = pol.act(ref_obs, ref_info["action_mask"])
        flat = act.reshape(B * N, -1)
        assert env.action_space.contains(flat)
        for s in range(0, B * N, 7):  # every chosen action is allowed by the slot's mask
            assert env.single_action_space.sample(masks[s].astype(np.int8)) in \
                env.single_action_space
        obs, rew, term, trunc, infos = env.step(flat)
        ref_obs, ref_rew, _, ref_trunc, ref_info = be.step(act)
        np.testing.assert_array_equal(obs, ref_obs.reshape(B * N, -1))
        np.testing.assert_array_equal(rew, ref_rew.reshape(-1))
        assert trunc.shape == term.shape == (B * N,)
        assert trunc.all() == (k == H - 1)
    assert infos["_final_obs"].all()
    np.testing.assert_array_equal(infos["final_obs"],
                                  ref_info["final_obs"].reshape(B * N, -1))
    # partial reset of copy 1 through options (whole copies only)
    m = np.zeros(B * N, bool)
    m[N:2 * N] = True
    obs, _ = env.reset(seed=9, options={"reset_mask": m})
    assert env.batched.core.k.tolist() == [0, 0, 0]
    m[N] = False
    with pytest.raises(ValueError, match="all agent slots of a copy"):
        env.reset(options={"reset_mask": m})
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(options={"foo": 1})
    with pytest.raises(ValueError, match="actions must have shape"):
        env.step(np.zeros((B, N, N + 1), dtype=np.int64))


# ----------------------------------------------------------------------------- SB3
def test_sb3_vec_env_trains_maskable_ppo_and_serves_masks():
    pytest.importorskip("stable_baselines3")
    sb3c = pytest.importorskip("sb3_contrib")
    from sb3_contrib.common.maskable.utils import get_action_masks, is_masking_supported
    from stable_baselines3.common.vec_env import VecEnv, VecMonitor

    from netsense.env.vector import make_sb3_vec_env

    venv = make_sb3_vec_env("fig1_scalar-v0", 2, seed=4, horizon=5)
    assert isinstance(venv, VecEnv) and venv.num_envs == 6
    assert is_masking_supported(venv)
    obs = venv.reset()
    ref = BatchedEnv("fig1_scalar-v0", 2, horizon=5)
    np.testing.assert_array_equal(obs, ref.reset(seed=4)[0].reshape(6, -1))
    masks = get_action_masks(venv)
    assert masks.shape == (6, venv.venv.batched.mask_size) and masks.dtype == bool
    act = np.zeros((6, 4), dtype=np.int64)
    for _ in range(5):
        obs, rew, dones, infos = venv.step(act)
        assert rew.dtype == np.float32 and len(infos) == 6
    assert dones.all()
    assert all(i["TimeLimit.truncated"] for i in infos)
    assert infos[0]["terminal_observation"].shape == obs[0].shape
    model = sb3c.MaskablePPO("MlpPolicy", VecMonitor(venv), n_steps=8, batch_size=24,
                             n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=48)
    assert model.num_timesteps >= 48


def test_agent_vector_env_works_with_gymnasium_vector_wrappers():
    from gymnasium.wrappers.vector import RecordEpisodeStatistics

    # Gymnasium's wrapper honours AutoresetMode.SAME_STEP only in newer releases (1.2.x
    # counts lengths as if the reset came a step later); Ray pins gymnasium 1.2.2, so the
    # lengths are checked only where the wrapper knows the mode we declare.
    knows_same_step = "SAME_STEP" in inspect.getsource(RecordEpisodeStatistics.step)
    env = RecordEpisodeStatistics(AgentVectorEnv("fig1_scalar-v0", 2, horizon=3))
    env.reset(seed=0)
    ends = []
    for k in range(7):
        _, rew, _, trunc, info = env.step(np.zeros((6, 4), dtype=np.int64))
        if "episode" in info:
            ends.append(k)
            assert info["_episode"].all()
            if knows_same_step:
                assert (info["episode"]["l"] == 3).all()
    assert ends == [2, 5]


@pytest.mark.parametrize("sid,policy", [("link_failures-v0", "freshness"),
                                        ("fig1_scalar-v0", "tree_consensus"),
                                        ("message_cost-v0", "uniform_consensus"),
                                        ("message_cost-v0", "random")])
def test_rollout_seeds_equals_the_benchmark_rollout_per_seed(sid, policy):
    from netsense.benchmark import rollout
    from netsense.benchmark.batched import rollout_seeds

    seeds, over = [3, 8, 21], {"horizon": 12}
    recs = rollout_seeds(sid, policy, seeds, over)
    for s, rec in zip(seeds, recs, strict=True):
        ref = rollout(sid, policy, s, over)
        np.testing.assert_allclose(rec.errors, ref.errors, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(rec.x_norm, ref.x_norm, rtol=1e-12)
        np.testing.assert_array_equal(rec.aoi, ref.aoi)
        np.testing.assert_array_equal(rec.messages, ref.messages)
        np.testing.assert_array_equal(rec.rewards, ref.rewards)
        assert rec.floor == ref.floor
    assert not np.array_equal(recs[0].errors, recs[1].errors)


def test_rollout_seeds_cuts_members_at_their_own_end():
    from netsense.benchmark.batched import rollout_seeds

    # open loop on an unstable plant diverges; a low limit ends members at different steps
    recs = rollout_seeds("random_structured_n20_N10-v0", "open_loop", [0, 1, 2, 3],
                         {"horizon": 40, "divergence_limit": 3.0})
    lengths = [r.rewards.shape[0] for r in recs]
    assert all(r.errors.shape[0] == n + 1 == r.aoi.shape[0] for r, n in zip(recs, lengths,
                                                                           strict=True))
    assert len(set(lengths)) > 1 and max(lengths) == 40
    from netsense.benchmark import rollout

    short = int(np.argmin(lengths))
    ref = rollout("random_structured_n20_N10-v0", "open_loop", short,
                  {"horizon": 40, "divergence_limit": 3.0})
    np.testing.assert_array_equal(recs[short].rewards, ref.rewards)
    with pytest.raises(ValueError, match="cannot run batched"):
        rollout_seeds("fig1_scalar-v0", "learned:policy.zip", [0])


def test_pickle_round_trip_continues_identically():
    import pickle

    env = BatchedEnv("link_failures-v0", 3, horizon=5)
    obs, info = env.reset(seed=1)
    pol = make_policy("freshness", env.core)
    for _ in range(3):
        obs, *_, info = env.step(pol.act(obs, info["action_mask"]))
    twin = pickle.loads(pickle.dumps(env))
    for _ in range(6):  # crosses the horizon: both auto-reset with the same seeds
        act = pol.act(obs, info["action_mask"])
        obs, rew, term, trunc, info = env.step(act)
        obs2, rew2, _, trunc2, _ = twin.step(act)
        np.testing.assert_array_equal(obs, obs2)
        np.testing.assert_array_equal(rew, rew2)
        np.testing.assert_array_equal(trunc, trunc2)
    np.testing.assert_array_equal(env.episode_seeds, twin.episode_seeds)
    vec = AgentVectorEnv("fig1_scalar-v0", 2)
    vec.reset(seed=0)
    assert pickle.loads(pickle.dumps(vec)).num_envs == 6
