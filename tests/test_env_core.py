"""The batched core (issue 8, items 1 and 6): B = 1 is the env, members are independent
single runs, masks and partial resets behave per member, bad actions never corrupt state."""

from __future__ import annotations

import numpy as np
import pytest

import netsense as ns
from netsense.engine.core import BatchedCore, ObsLayout
from netsense.env.policies import make_policy
from netsense.env.registry import build_model, load, make, with_overrides


def model_of(sid, **over):
    return build_model(with_overrides(load(sid), **over))


def env_arrays(env, obs, infos=None):
    a = env.possible_agents
    return (np.stack([obs[x]["observation"] for x in a]),
            np.stack([obs[x]["action_mask"] for x in a]))


@pytest.mark.parametrize("sid", ["link_failures-v0", "random_structured_n20_N10-v0",
                                 "drops_kfio-v0"])  # (KFIO sources: products row by row)
def test_each_member_equals_an_independent_single_run(sid):
    B, seed = 3, 11
    model = model_of(sid, horizon=70)  # crosses a CHUNK boundary (64)
    core = BatchedCore(model, B)
    obs, mask = core.reset(seed)
    envs = [make(sid, horizon=70) for _ in range(B)]
    singles = [e.reset(seed=seed + b)[0] for b, e in enumerate(envs)]
    pol = make_policy("random", core, seed=0, p_transmit=0.7)
    for _ in range(70):
        for b, e in enumerate(envs):
            o, m = env_arrays(e, singles[b])
            np.testing.assert_array_equal(obs[b], o)
            np.testing.assert_array_equal(mask[b], m)
        act = pol.act(obs, mask)
        out = core.step(act)
        obs, mask = out.obs, out.action_mask
        for b, e in enumerate(envs):
            singles[b], rew, term, trunc, _ = e.step(
                {a: act[b, i] for i, a in enumerate(e.possible_agents)})
            np.testing.assert_array_equal(out.reward[b], [rew[a] for a in e.possible_agents])
            np.testing.assert_array_equal(core.Z[b], e.core.Z[0])
            np.testing.assert_array_equal(core.tau[b], e.core.tau[0])
            assert bool(out.truncated[b]) == trunc[e.possible_agents[0]]
    assert out.truncated.all()


def test_batched_freshness_policy_matches_batched_freshness_observer():
    """The batched core under the freshness policy equals FreshnessObserver(batch_size=B)
    fed each member's own graphs and measurements."""
    B = 4
    model = model_of("random_structured_n20_N10-v0", horizon=40)
    core = BatchedCore(model, B)
    obs, mask = core.reset(0)
    observer = ns.FreshnessObserver(model.design, batch_size=B)
    pol = make_policy("freshness", core)
    for _ in range(40):
        observer.step(core.y.copy(), core.adjacency.copy(), arrived=core.y_arrived.copy())
        out = core.step(pol.act(obs, mask))
        obs, mask = out.obs, out.action_mask
        np.testing.assert_array_equal(core.Z, observer.z_estimates)
        np.testing.assert_array_equal(core.tau, observer.indices)
    # members really differ (independent graph and noise realisations)
    assert not np.array_equal(core.Z[0], core.Z[1])


def test_masks_follow_graph_and_transmit_flags_per_member():
    """Oracle: slot d of agent i is its d-th smallest in-neighbour in G[k]; the slot is
    allowed iff that neighbour transmitted (no drops in this scenario)."""
    B = 3
    model = model_of("message_cost-v0")
    core = BatchedCore(model, B)
    obs, mask = core.reset(5)
    rng = np.random.default_rng(1)
    N, D = core.N, core.D
    for _ in range(12):
        act = np.zeros((B, N, N + 1), dtype=np.int64)
        act[..., N] = rng.random((B, N)) < 0.5
        out = core.step(act)
        for b in range(B):
            for i in range(N):
                nb = np.flatnonzero(core.adjacency[b, i])
                m = out.action_mask[b, i, : N * (D + 2)].reshape(N, D + 2)
                for d in range(D):
                    want = d < nb.size and bool(act[b, nb[d], N])
                    for j in range(N):
                        assert m[j, d + 1] == (want and j != i)
                assert m[:, 0].all() and m[i, 1:].sum() == 0
                assert (m[np.arange(N) != i, D + 1] == 1).all()
            np.testing.assert_array_equal(out.action_mask[b, :, -2:], 1)


def _step_both(core, pol, obs, mask, ref, ref_obs):
    """One step of the batch and of each member's own env under the same actions; the
    observations and masks must be equal. Returns the batch's next ``obs, mask``."""
    act = pol.act(obs, mask)
    out = core.step(act)
    for b in range(core.B):
        ref_obs[b], *_ = ref[b].step({a: act[b, i]
                                      for i, a in enumerate(ref[b].possible_agents)})
        o, m = env_arrays(ref[b], ref_obs[b])
        np.testing.assert_array_equal(out.obs[b], o)
        np.testing.assert_array_equal(out.action_mask[b], m)
    return out.obs, out.action_mask


def test_partial_reset_restarts_only_selected_members():
    B = 3
    model = model_of("link_failures-v0", horizon=30)
    core = BatchedCore(model, B)
    obs, mask = core.reset([10, 20, 30])
    pol = make_policy("freshness", core)
    ref = [make("link_failures-v0", horizon=30) for _ in range(B)]
    ref_obs = [r.reset(seed=s)[0] for r, s in zip(ref, [10, 20, 30], strict=True)]
    for k in range(25):
        if k == 9:  # restart member 1 with a new seed; the others keep going
            obs, mask = core.reset([0, 99, 0], members=np.array([False, True, False]))
            ref_obs[1] = ref[1].reset(seed=99)[0]
            assert core.k.tolist() == [9, 0, 9]
        obs, mask = _step_both(core, pol, obs, mask, ref, ref_obs)
    assert core.k.tolist() == [25, 16, 25]


def test_masked_and_out_of_range_actions_raise_before_any_state_change():
    model = model_of("fig1_scalar-v0")
    core = BatchedCore(model, 2)
    obs, mask = core.reset(0)
    N, D = core.N, core.D
    snap = (core.Z.copy(), core.tau.copy(), core.x.copy(), core.k.copy())
    bad = np.zeros((2, N, N + 1), dtype=np.int64)
    bad[1, 0, 0] = 1  # source 0 may not touch its own substate
    with pytest.raises(ValueError, match="own substate"):
        core.step(bad)
    bad[:] = 0
    bad[0, 2, 1] = D + 2  # out of range
    with pytest.raises(ValueError, match="outside"):
        core.step(bad)
    bad[:] = 0
    bad[0, 1, N] = 2  # transmit must be 0/1
    with pytest.raises(ValueError, match="transmit"):
        core.step(bad)
    with pytest.raises(ValueError, match="shape"):
        core.step(np.zeros((1, N, N + 1), dtype=np.int64))
    for before, after in zip(snap, (core.Z, core.tau, core.x, core.k), strict=True):
        np.testing.assert_array_equal(before, after)
    # a slot whose neighbour did not transmit: nobody transmits at k = 0 here
    silent = model_of("fig1_scalar-v0", initial_transmit=False)
    core = BatchedCore(silent, 2)
    core.reset(0)
    assert core.valid[0, 2].all() and not core.msg.any()
    bad[:] = 0
    bad[0, 2, 0] = 1
    with pytest.raises(ValueError, match="no message"):
        core.step(bad)
    keep = BatchedCore(silent, 2, invalid_actions="keep")
    keep.reset(0)
    ref = BatchedCore(silent, 2)
    ref.reset(0)
    keep.step(bad)
    ref.step(np.zeros_like(bad))  # the masked choice became 0 = keep
    np.testing.assert_array_equal(keep.Z, ref.Z)
    np.testing.assert_array_equal(keep.tau, ref.tau)
    assert keep.last_invalid.sum() == 1


def test_env_rejects_missing_agents_and_bad_names():
    env = make("fig1_scalar-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="missing"):
        env.step({"sensor_0": np.zeros(4, int)})
    with pytest.raises(ValueError, match="unknown agent"):
        env.observation_space("sensor_9")


def test_observation_layout_decodes_the_core_state():
    env = make("random_structured_n20_N10-v0", horizon=10)
    pol = make_policy("freshness", env)
    obs, infos = env.reset(seed=2)
    for _ in range(4):
        obs, *_, infos = env.step(pol.act_dict(env, obs, infos))
    c, L = env.core, env.layout
    assert isinstance(L, ObsLayout) and L.size == env.observation_space("sensor_0")[
        "observation"].shape[0]
    o = np.stack([obs[a]["observation"] for a in env.possible_agents])
    H = c.horizon
    np.testing.assert_allclose(o[:, L.time], 4 / H)
    tau = c.tau[0]
    np.testing.assert_array_equal(o[:, L.own_omega], tau < 0)
    np.testing.assert_allclose(o[:, L.own_age], np.where(tau < 0, 0, tau) / H, rtol=1e-6)
    z = c.Z[0]
    np.testing.assert_allclose(o[:, L.z_lognorm][:, 0], np.log1p(np.linalg.norm(z, axis=1)),
                               rtol=1e-5)
    nrm = np.linalg.norm(z, axis=1, keepdims=True)
    np.testing.assert_allclose(o[:, L.z_dir], z / np.where(nrm > 0, nrm, 1), atol=1e-6)
    for i in range(c.N):
        nb = np.flatnonzero(c.adjacency[0, i])
        for d in range(c.D):
            sid_ = o[i, L.slot_id][d]
            ages = o[i, L.slot_age].reshape(c.D, c.N)[d]
            if d < nb.size:
                assert sid_ == pytest.approx((nb[d] + 1) / c.N)
                t = tau[nb[d]]
                np.testing.assert_allclose(ages, np.where(t < 0, 0, t) / H, rtol=1e-6)
            else:
                assert sid_ == 0 and o[i, L.slot_arrived][d] == 0


def test_reward_is_negative_normalised_error_minus_message_cost():
    env = make("message_cost-v0", horizon=5)
    obs, infos = env.reset(seed=0)
    N = env.core.N
    rng = np.random.default_rng(0)
    for _ in range(5):
        tx = rng.random(N) < 0.5
        acts = {a: np.r_[np.zeros(N, int), int(tx[i])] for i, a in enumerate(env.agents)}
        obs, rew, term, trunc, infos = env.step(acts)
        c = env.core
        x = c.x[0]
        e = np.linalg.norm(c.estimates[0] - x, axis=1) / max(np.linalg.norm(x), 1e-3)
        e = np.minimum(e, 5.0)
        want = -(0.5 * e + 0.5 * e.mean()) - 0.05 * tx
        np.testing.assert_allclose([rew[a] for a in env.possible_agents], want, rtol=1e-9)
    assert all(trunc.values()) and not env.agents


def test_divergence_limit_terminates():
    env = make("fig1_scalar-v0", divergence_limit=0.5, horizon=30)
    obs, infos = env.reset(seed=0)
    N = env.core.N
    obs, rew, term, trunc, infos = env.step({a: np.r_[np.zeros(N, int), 0]
                                             for a in env.agents})
    # open loop from zero estimates: nodes 1 and 2 keep error ||x|| / ||x|| = 1 > 0.5
    assert all(term.values()) and not any(trunc.values()) and env.agents == []


@pytest.mark.parametrize("sid", __import__("netsense").list_scenarios())
def test_realisation_does_not_depend_on_chunk_length(sid):
    """Large batches draw shorter chunks (memory budget); every registered scenario's
    streams must give the same realisation for any chunk length."""
    steps = 8 if sid.startswith("large") else 20
    model = model_of(sid, horizon=steps)
    long_, short = BatchedCore(model, 2, chunk=64), BatchedCore(model, 2, chunk=3)
    o1, m1 = long_.reset(4)
    o2, m2 = short.reset(4)
    pol = make_policy("random", long_, seed=2)
    for _ in range(steps):
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(m1, m2)
        act = pol.act(o1, m1)
        r1, r2 = long_.step(act), short.step(act)
        o1, m1, o2, m2 = r1.obs, r1.action_mask, r2.obs, r2.action_mask
        np.testing.assert_array_equal(r1.reward, r2.reward)
        np.testing.assert_array_equal(long_.adjacency, short.adjacency)
    np.testing.assert_array_equal(long_.Z, short.Z)


def test_graphs_are_the_members_graph_stream():
    """G[k] of member b is the graph process sampled from that member's graph stream
    (child 1 of SeedSequence(seed + b)), independently of the batch."""
    model = model_of("link_failures-v0", horizon=30)
    core = BatchedCore(model, 3, chunk=7)
    core.reset(40)
    seen = [core.adjacency.copy()]
    for _ in range(29):
        core.step(np.r_[np.zeros(core.N, int), 1][None, None].repeat(core.N, 1).repeat(3, 0))
        seen.append(core.adjacency.copy())
    seen = np.stack(seen, 1)  # (B, K, N, N)
    for b in range(3):
        rng = np.random.default_rng(np.random.SeedSequence(40 + b).spawn(7)[1])
        seq, _ = model.graphs.sample(rng, 30, model.graphs.initial_state(rng))
        np.testing.assert_array_equal(seen[b], seq)


def test_chunk_buffers_respect_the_memory_budget():
    from netsense.engine.core import CHUNK_BUDGET

    model = model_of("random_structured_n20_N10-v0", plant={"num_agents": 30},
                     graph={"num_nodes": 30})
    core = BatchedCore(model, 1024)
    core.reset(0)
    bufs = [core.buf_nbr, core.buf_w, core.buf_v, core.buf_meas, core.buf_msg]
    assert sum(b.nbytes for b in bufs if b is not None) <= CHUNK_BUDGET
    assert 1 <= core.chunk < 64 and BatchedCore(model, 1).chunk == 64


def test_large_batch_path_equals_small_batch_path(monkeypatch):
    """Under a tiny memory budget the core draws 1-step chunks and derives the slot tables
    per step (the large-batch path); the trajectory is the same as the default path."""
    import netsense.engine.core as envcore

    model = model_of("link_failures-v0", horizon=15)
    ref = BatchedCore(model, 2)
    o_ref, m_ref = ref.reset(8)
    monkeypatch.setattr(envcore, "CHUNK_BUDGET", 1)
    lean = BatchedCore(model, 2)
    o, m = lean.reset(8)
    assert lean.chunk == 1 and ref.chunk > 1
    pol = make_policy("random", ref, seed=1)
    for _ in range(15):
        np.testing.assert_array_equal(o, o_ref)
        np.testing.assert_array_equal(m, m_ref)
        act = pol.act(o_ref, m_ref)
        r, r_ref = lean.step(act), ref.step(act)
        o, m, o_ref, m_ref = r.obs, r.action_mask, r_ref.obs, r_ref.action_mask
    np.testing.assert_array_equal(lean.Z, ref.Z)


@pytest.mark.parametrize("draws", ["all", "base"])
def test_markov_slot_sampler_equals_per_run_sampling(draws):
    """MarkovLinkFailures.sample_slots_many (the core's batched refill) gives, per run, the
    slot tables of sample() with that run's generator, and the same continuation state."""
    from netsense.graphs.processes import MarkovLinkFailures, in_neighbor_slots

    base = np.zeros((9, 9), bool)
    for o in (1, 2, 5):
        base[(np.arange(9) + o) % 9, np.arange(9)] = True
    g = MarkovLinkFailures(base, 0.3, 0.4, draws=draws)
    seeds = [3, 4, 5]
    states = [g.initial_state(np.random.default_rng(s)) for s in seeds]
    rngs = [np.random.default_rng(s + 10) for s in seeds]
    nbr, new = g.sample_slots_many(rngs, 6, states, g.max_in_degree)
    adj_many, new2 = g.sample_many([np.random.default_rng(s + 10) for s in seeds], 6, states)
    for m, s in enumerate(seeds):
        adj, st = g.sample(np.random.default_rng(s + 10), 6, states[m])
        np.testing.assert_array_equal(nbr[m], in_neighbor_slots(adj, g.max_in_degree)[0])
        np.testing.assert_array_equal(adj_many[m], adj)
        np.testing.assert_array_equal(new[m], st)
        np.testing.assert_array_equal(new2[m], st)
        assert not (adj & ~base).any()


def test_markov_base_draws_are_a_new_version_only():
    """large_n20_N100-v1 differs from -v0 only in the Markov draws (opt-in); v0 keeps the
    original one-uniform-per-node-pair stream."""
    v0, v1 = load("large_n20_N100-v0"), load("large_n20_N100-v1")
    assert v1.graph.get("draws") == "base" and "draws" not in v0.graph
    assert build_model(v0).graphs.draws == "all"
    assert with_overrides(v1, graph={"draws": "all"}).to_dict()["graph"] == \
        {**v0.to_dict()["graph"], "draws": "all"}


def test_step_without_observations_builds_them_on_demand():
    """step(observe=False) returns no obs/mask but leaves the same state; observe() then
    gives exactly what step(observe=True) returned."""
    model = model_of("link_failures-v0", horizon=12)
    a, b = BatchedCore(model, 3), BatchedCore(model, 3)
    oa, ma = a.reset(5)
    b.reset(5)
    pol = make_policy("freshness", a)
    for _ in range(12):
        act = pol.act(oa, ma)
        out = a.step(act)
        lean = b.step(act, observe=False)
        assert lean.obs is None and lean.action_mask is None
        np.testing.assert_array_equal(lean.reward, out.reward)
        ob, mb = b.observe()
        np.testing.assert_array_equal(ob, out.obs)
        np.testing.assert_array_equal(mb, out.action_mask)
        oa, ma = out.obs, out.action_mask


def test_partial_reset_of_scattered_members_with_short_chunks():
    # members 0 and 2 restart together (a non-contiguous group: their slot tables are drawn
    # into a scratch array, not a view of the chunk buffer), chunks of 3 steps put the
    # members' refills at different steps; every member must still equal its own env
    B, seeds = 4, [5, 6, 7, 8]
    model = model_of("link_failures-v0", horizon=40)
    core = BatchedCore(model, B, chunk=3)
    obs, mask = core.reset(seeds)
    pol = make_policy("freshness", core)
    ref = [make("link_failures-v0", horizon=40) for _ in range(B)]
    ref_obs = [r.reset(seed=s)[0] for r, s in zip(ref, seeds, strict=True)]
    for k in range(14):
        if k == 4:
            obs, mask = core.reset([41, 0, 43, 0], members=np.array([True, False, True, False]))
            ref_obs[0] = ref[0].reset(seed=41)[0]
            ref_obs[2] = ref[2].reset(seed=43)[0]
            assert core.ptr.tolist() == [0, 1, 0, 1]
        obs, mask = _step_both(core, pol, obs, mask, ref, ref_obs)


@pytest.mark.parametrize("change", [{"horizon": 2.5}, {"horizon": True}, {"horizon": 0},
                                    {"x0_std": float("nan")},
                                    {"divergence_limit": float("nan")},
                                    {"divergence_limit": 0.0}])
def test_core_model_rejects_bad_horizon_start_and_limit(change):
    import dataclasses

    name = next(iter(change))
    with pytest.raises(ValueError, match=name):
        dataclasses.replace(model_of("message_cost-v0"), **change)
