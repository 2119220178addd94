"""The batched TorchRL path: env specs, masks, MAPPO / IPPO smoke runs, the set network's
size freedom, behaviour cloning and the credit-assignment rewards."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from netsense.rl import credit

SCEN = "message_cost-v1"
SHORT = {"horizon": 12}


# ------------------------------------------------------------------ rewards (numpy only)
def test_team_and_agent_rewards_by_hand():
    # two agents, w_e = 2, w_t = 0.25, c = 0.1; agent 1 transmitted
    e = np.array([[0.4, 0.8]])
    t = np.array([[0.0, 1.0]])
    we, wt, c = 2.0, 0.25, 0.1
    ebar = 0.6
    core_r = -we * ((1 - wt) * e + wt * ebar) - c * t  # the core's reward
    agent = credit.agent_reward(core_r, e, np.array([True, True]), we, wt)
    np.testing.assert_allclose(agent, -we * e - c * t, atol=1e-15)
    np.testing.assert_allclose(credit.team_reward(core_r), np.full((1, 2), core_r.mean()))
    # an agent that does not count keeps only its cost, and leaves the team mean
    alive = np.array([True, False])
    core_r2 = np.array([[-we * ((1 - wt) * 0.4 + wt * 0.4), -c]])
    np.testing.assert_allclose(credit.agent_reward(core_r2, e, alive, we, wt),
                               [[-we * 0.4, -c]], atol=1e-15)


def test_own_cost_reward_by_hand():
    # three agents, w_e = 2, w_t = 0.25, c = 0.1; agents 1 and 2 transmitted, and agent 2
    # does not count (its error is left out of the team mean; it keeps its cost)
    e = np.array([[0.4, 0.8, 5.0]])
    t = np.array([[0.0, 1.0, 1.0]])
    we, wt, c = 2.0, 0.25, 0.1
    alive = np.array([True, True, False])
    ebar = 0.6
    err = -we * ((1 - wt) * e + wt * ebar) * alive
    core_r = err - c * t
    got = credit.own_cost_reward(core_r, e, alive, we, wt)
    want = err.mean() - c * t / 3  # the team's error, one's own cost at weight 1/N
    np.testing.assert_allclose(got, want, atol=1e-15)
    # the team reward plus the other agents' costs
    team = credit.team_reward(core_r)
    np.testing.assert_allclose(got - team, c * (t.sum() - t) / 3, atol=1e-15)
    assert credit.shaped_reward("own_cost", core_r, e, alive, we, wt).tolist() == \
        got.tolist()


def test_own_cost_reward_through_the_env():
    """On ``comm_fading-v0`` (team weight 1) the env's ``own_cost`` reward equals the team
    reward where nobody sends, and otherwise the team reward plus ``c / N`` for every
    other agent that sent at that step."""
    from netsense.rl.envs import NetSenseBatchedEnv, make_core

    envs = {r: NetSenseBatchedEnv(make_core("comm_fading-v0", 4, control="transmit"),
                                  reward=r, seed=3) for r in ("team", "own_cost")}
    for env in envs.values():
        env.restart()
    core = envs["team"].core
    c, N = core.model.reward.message_cost, core.N
    rng = np.random.default_rng(0)
    for k in range(20):
        a = (rng.random((4, N, 1)) < (0.5 if k >= 5 else 0.0)).astype(np.int64)
        r = {name: env.advance(a)[2] for name, env in envs.items()}
        sent = a[..., 0]
        want = r["team"] + c * (sent.sum(1, keepdims=True) - sent) / N
        np.testing.assert_allclose(r["own_cost"], want, rtol=0, atol=1e-5)
        if k < 5:
            np.testing.assert_array_equal(r["own_cost"], r["team"])


def test_sender_credit_by_hand():
    # B = 1, N = 3, M = 2, D = 2. Agent 0 adopts substate 1 from slot 1 (= agent 2),
    # agent 1 adopts substate 0 from slot 0 (= agent 0) and substate 1 from slot 0
    # (= agent 2); agent 2 adopts nothing.
    eps = np.array([[[0.5, 0.9], [0.7, 0.6], [0.2, 0.1]]])
    nbr = np.array([[[1, 2], [2, 0], [0, 1]]])
    adopted = np.array([[[-1, 1], [1, 0], [-1, -1]]])
    got = credit.sender_credit(eps, adopted, nbr, np.ones(3, bool))
    want = np.zeros((1, 3))
    want[0, 2] += 0.9 - 0.1  # receiver 0, substate 1, from agent 2
    want[0, 0] += 0.7 - 0.5  # receiver 1, substate 0, from agent 0
    want[0, 2] += 0.6 - 0.1  # receiver 1, substate 1, from agent 2
    np.testing.assert_allclose(got, want, atol=1e-15)
    # receivers that do not count give no credit
    got = credit.sender_credit(eps, adopted, nbr, np.array([True, False, True]))
    np.testing.assert_allclose(got, [[0.0, 0.0, 0.8]], atol=1e-15)


def test_block_errors_by_hand():
    # n = 3 coordinates: 0, 1 in substate 0, 2 in substate 1; T = 2 I (z = x / 2)
    x = np.array([[2.0, 0.0, 4.0]])  # ||x|| = sqrt(20), z = (1, 0, 2)
    Z = np.array([[[1.0, 3.0, 2.0], [0.0, 0.0, 0.0]]])
    blocks = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    eps = credit.block_errors(Z, x, np.eye(3) / 2, blocks, 1e-3, 10.0)
    s = np.sqrt(20.0)
    np.testing.assert_allclose(eps, [[[3 / s, 0.0], [1 / s, 2 / s]]], atol=1e-15)


def test_adoptions_from_full_actions():
    from netsense.rl.envs import make_core

    core = make_core(SCEN, 1, **SHORT)
    a = np.zeros((1, core.N, core.M + 1), np.int64)
    a[0, 1, 0] = 3  # slot 2
    a[0, 2, 4] = core.D + 1  # average: no adoption
    got = credit.adopted_slots(core, a)
    assert got[0, 1, 0] == 2 and (got == -1).sum() == got.size - 1


def test_lifetime_credit_is_the_receivers_error_had_it_kept():
    """Two cores on the same seed and the same actions, but for one adoption: receiver l
    adopts substate j from sender s in one and keeps in the other, and nobody adopts
    from l afterwards. At every later step the lifetime credit of s is exactly l's error
    in the core that kept minus its error in the core that adopted, every other agent's
    credit is 0; a new adoption of j by l ends the chain."""
    from netsense.rl.envs import make_core

    scen = "comm_process_noise-v0"
    adopt, keep = (make_core(scen, 1, control="full", horizon=40) for _ in range(2))
    adopt.reset(3)
    keep.reset(3)
    lc = credit.LifetimeCredit(adopt, np.ones(adopt.N, bool))
    M, N = adopt.M, adopt.N
    quiet = np.zeros((1, N, M + 1), np.int64)
    quiet[..., M] = 1  # everyone transmits, nobody adopts
    receivers = np.flatnonzero(np.asarray(adopt.layout.own) < 0)  # own no substate
    for _ in range(3):
        lc.before(adopt, quiet)
        adopt.step(quiet)
        keep.step(quiet)
        lc.after(adopt)
    while not adopt.msg[0, receivers].any():
        adopt.step(quiet)
        keep.step(quiet)
    l = int(receivers[adopt.msg[0, receivers].any(-1)][0])
    d = int(np.flatnonzero(adopt.msg[0, l])[0])  # a slot with a message
    s, j = int(adopt.nbr[0, l, d]), 0
    act = quiet.copy()
    act[0, l, j] = d + 1
    lc.before(adopt, act)
    adopt.step(act)
    keep.step(quiet)
    seen = 0
    for step in range(8):
        got = lc.after(adopt)
        want = keep.errors[0, l] - adopt.errors[0, l]
        assert got[0, s] == pytest.approx(want, abs=1e-9), step
        assert np.count_nonzero(np.delete(got[0], s)) == 0
        seen += abs(want) > 1e-6
        lc.before(adopt, quiet)
        adopt.step(quiet)
        keep.step(quiet)
    assert seen > 0  # the adopted estimate did differ from the kept one
    while not adopt.msg[0, l].any():
        lc.before(adopt, quiet)
        adopt.step(quiet)
        lc.after(adopt)
    d2 = int(np.flatnonzero(adopt.msg[0, l])[0])
    s2 = int(adopt.nbr[0, l, d2])
    act[0, l, j] = d2 + 1
    lc.before(adopt, act)
    adopt.step(act)
    lc.after(adopt)
    assert lc.sender[0, l, j] == s2  # the chain of (l, j) is the newest adoption's
    assert np.count_nonzero(lc.sender >= 0) == 1
    lc.restart(np.array([True]))
    assert np.count_nonzero(lc.sender >= 0) == 0


def test_lifetime_reward_is_the_agent_reward_plus_the_senders_credit():
    """The env's ``lifetime`` reward is the ``agent`` reward plus the credit: equal where
    nobody sends, and where only the owners send, different only in the owners' columns
    (the senders; an owner whose channel stays bad earns nothing); a new episode ends every
    chain."""
    from netsense.rl.envs import NetSenseBatchedEnv, make_core

    envs = {r: NetSenseBatchedEnv(make_core("comm_fading-v0", 4, control="transmit"),
                                  reward=r, seed=7) for r in ("agent", "lifetime")}
    for env in envs.values():
        env.restart()
    core = envs["lifetime"].core
    owner = np.asarray(core.layout.own) >= 0
    credited = np.zeros(core.N, bool)
    for k in range(40):
        a = np.zeros((4, core.N, 1), np.int64)
        if k >= 10:
            a[:, owner, 0] = 1
        r = {name: env.advance(a)[2] for name, env in envs.items()}
        diff = r["lifetime"] - r["agent"]
        if k < 11:  # a message sent at k is adopted at k + 1
            np.testing.assert_array_equal(diff, 0.0)
        credited |= (np.abs(diff) > 0).any(0)
    assert credited[owner].any() and not credited[~owner].any()
    assert (envs["lifetime"].lifetime_credit.sender >= 0).any()
    envs["lifetime"].restart()
    assert not (envs["lifetime"].lifetime_credit.sender >= 0).any()


def test_netsense_rl_imports_no_torch():
    code = ("import sys, netsense, netsense.rl, netsense.rl.credit;"
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("mode", ["transmit", "substates"])
def test_adoptions_in_comm_modes_are_the_fusion_rules_choice(mode):
    # everyone transmitting (every substate), the communication-only core runs the
    # full-control freshness policy bit for bit; the slots credit reads from the fusion
    # rule must be the slots that policy adopts (on substates with a non-empty block of
    # Lemma 1: "adopting" an empty one moves nothing, and it is never sent per substate)
    from netsense.env.policies import FreshnessPolicy
    from netsense.rl.envs import make_core

    full = make_core(SCEN, 3, control="full", **SHORT)
    comm = make_core(SCEN, 3, control=mode, **SHORT)
    o, m = full.reset(5)
    comm.reset(5)
    pol = FreshnessPolicy(full.layout)
    real = ~comm.comm.empty
    adopted = 0
    for _ in range(12):
        a = pol.act(o, m)
        bits = comm.comm.allowed().astype(np.int64)  # every allowed bit
        want = credit.adopted_slots(full, a)[..., real]
        np.testing.assert_array_equal(credit.adopted_slots(comm, bits)[..., real], want)
        adopted += int((want >= 0).sum())
        out = full.step(a)
        o, m = out.obs, out.action_mask
        comm.step(bits)
    assert adopted > 0


def test_counterfactual_refuses_uniform_fusion():
    from netsense.rl.envs import make_core

    core = make_core(SCEN, 1, control="transmit", **SHORT)
    core.reset(0)
    assert credit.adopted_slots(core, np.ones((1, core.N, 1), np.int64)).shape == (
        1, core.N, core.M)
    core = make_core(SCEN, 1, control={"mode": "transmit", "fusion": "uniform"}, **SHORT)
    core.reset(0)
    with pytest.raises(ValueError, match="uniform"):
        credit.adopted_slots(core, np.ones((1, core.N, 1), np.int64))


# ------------------------------------------------------------------ TorchRL
torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")


@pytest.mark.parametrize("control", ["full", "transmit", "substates"])
def test_env_specs_and_masked_random_rollout(control):
    from torchrl.envs.utils import check_env_specs

    from netsense.rl.envs import NetSenseBatchedEnv, make_core, state_size

    core = make_core(SCEN, 3, control=control, **SHORT)
    env = NetSenseBatchedEnv(core, reward="counterfactual", seed=0)
    check_env_specs(env)  # rand_action draws from the masked spec: the core would raise
    td = env.rollout(30, break_when_any_done=False)  # through two auto-resets
    N, A = core.N, len(core.nvec)
    assert td["agents", "action"].shape == (3, 30, N, A)
    assert td["agents", "action_mask"].shape == (3, 30, N, int(np.sum(core.nvec)))
    assert td["state"].shape == (3, 30, state_size(N, core.M))
    assert td["next", "done"][:, 11].all() and td["next", "done"].sum() == 6
    assert torch.isfinite(td["next", "agents", "reward"]).all()


@pytest.mark.parametrize("scenario", ["comm_channel_kofn_n50-v0", "comm_spatial_n50-v0",
                                      "comm_process_noise-v0"])
def test_global_state_carries_the_adjacency_on_the_graphs_support(scenario):
    """Markov link failures fix a support (the base graph): the state carries the adjacency
    there only, losing nothing (every other entry stays False at every step); a process
    with no support (random jointly connected graphs) keeps all N^2 entries."""
    from netsense.rl.envs import NetSenseBatchedEnv, global_state, make_core, state_edges

    core = make_core(scenario, 3, control="transmit", horizon=40)
    env = NetSenseBatchedEnv(core, seed=4)
    N, M = core.N, core.M
    support = core.model.graphs.edge_support
    E = N * N if support is None else int(support.sum())
    assert state_edges(core) == (None if support is None else E)
    if support is not None:
        assert E < N * N / 5  # the point: it grows like N D, not N^2
    assert env.state_dim == 1 + 2 * N + E + 2 * N * M
    core.reset(seed=4)
    rng = np.random.default_rng(0)
    changed = False
    first = None
    for _ in range(25):
        s = global_state(core)
        adj = core.adjacency
        got = s[:, 1 + 2 * N:1 + 2 * N + E].astype(bool)
        if support is None:
            np.testing.assert_array_equal(got, adj.reshape(3, -1))
        else:
            assert not adj[:, ~support].any()
            np.testing.assert_array_equal(got, adj[:, support])
        first = got if first is None else first
        changed |= not np.array_equal(got, first)
        core.step(rng.integers(0, 2, (3, N, 1)))
    assert changed  # the links do switch, so the comparison saw more than one graph


def test_env_reset_seeds_members_like_the_core():
    from netsense.engine.core import BatchedCore
    from netsense.env.vector import load_model
    from netsense.rl.envs import NetSenseBatchedEnv

    model, _ = load_model(SCEN, **SHORT)
    env = NetSenseBatchedEnv(BatchedCore(model, 2), seed=7)
    td = env.reset()
    o, _ = BatchedCore(model, 2).reset(7)
    np.testing.assert_array_equal(td["agents", "observation"].numpy(), o)


def _small(algo, network, **kw):
    from netsense.rl.config import PPOConfig

    return PPOConfig(SCEN, algo=algo, network=network, steps=2 * 4 * 8 * 10, num_envs=4,
                     rollout=8, minibatch=16, epochs=2, eval_interval=1, eval_envs=3,
                     set_hidden=16, overrides=SHORT, **kw)


@pytest.mark.parametrize("algo,network,control,reward", [
    ("mappo", "mlp", "full", "team"),
    ("ippo", "set", "full", "counterfactual"),
    ("mappo", "set", "transmit", "agent"),
    ("mappo", "set", "substates", "counterfactual"),
    ("ippo", "mlp", "transmit", "scenario"),
])
def test_training_smoke(tmp_path, algo, network, control, reward):
    from netsense.rl.checkpoint import load_policy
    from netsense.rl.envs import make_core
    from netsense.rl.ppo import train_ppo

    cfg = _small(algo, network, control=control, reward=reward)
    res = train_ppo(cfg, tmp_path)
    assert res.mask_violations == 0 and len(res.rows) == 2
    for row in res.rows:
        for k in ("loss_objective", "loss_critic", "loss_entropy"):
            assert np.isfinite(row[k])
        assert np.isfinite(row["eval_return"])
    assert (tmp_path / "log.csv").exists() and (tmp_path / "policy.pt").exists()
    assert (tmp_path / "checkpoint_00002.pt").exists()
    # the saved policy acts within the masks: the core raises on a masked action
    core = make_core(SCEN, 2, control=control, **SHORT)
    pol = load_policy(tmp_path / "policy.pt", core, deterministic=False)
    o, m = core.reset(3)
    for _ in range(6):
        out = core.step(pol.act(o, m))
        o, m = out.obs, out.action_mask


def test_clock_features_are_the_step_phase_for_each_period():
    """The clock reads k from the time entry k / H and appends sin, cos of 2 pi k / p: equal
    at k and k + lcm of the periods, different between the p phases."""
    from netsense.rl.envs import make_core
    from netsense.rl.policy import ClockActor

    core = make_core("comm_channel_k2-v0", 1)
    H, t = core.horizon, core.layout.time.start
    clock = ClockActor(torch.nn.Identity(), t, H, (2, 5))
    obs = torch.zeros(H + 1, core.layout.size)
    obs[:, t] = torch.arange(H + 1, dtype=torch.float32) / H  # float32, as the core writes
    feat = clock(obs)[:, core.layout.size:]
    k = np.arange(H + 1)[:, None]
    want = np.concatenate([np.sin(2 * np.pi * k / [2, 5]), np.cos(2 * np.pi * k / [2, 5])], 1)
    np.testing.assert_allclose(feat.numpy(), want, atol=1e-5)
    np.testing.assert_allclose(feat[10:], feat[:-10], atol=1e-5)  # lcm(2, 5)
    phases = {tuple(np.round(f, 4)) for f in feat[:10, [1, 3]].numpy()}  # the p = 5 pair
    assert len(phases) == 5


def test_clock_only_actor_is_blind_to_the_state_and_not_to_the_step():
    """``clock_only``: the body sees the time entry and the clock, every other observation
    entry at 0: random observations with the same step give the same input, another step a
    different one; a clock-only config needs a clock."""
    from netsense.rl.config import PPOConfig
    from netsense.rl.envs import make_core
    from netsense.rl.policy import ClockActor

    core = make_core("comm_channel_k2-v0", 1)
    H, t, N, O = core.horizon, core.layout.time.start, core.N, core.layout.size
    blind = ClockActor(torch.nn.Identity(), t, H, (5,), shift=True, clock_only=True)
    seeing = ClockActor(torch.nn.Identity(), t, H, (5,), shift=True)
    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(N, O, generator=g), torch.rand(N, O, generator=g)
    a[:, t] = b[:, t] = 7 / H
    assert torch.equal(blind(a), blind(b))
    assert not torch.equal(seeing(a), seeing(b))
    c = b.clone()
    c[:, t] = 8 / H
    assert not torch.equal(blind(c)[:, O:], blind(b)[:, O:])
    np.testing.assert_array_equal(blind(c)[:, :O].count_nonzero(-1).numpy(), 1)
    with pytest.raises(ValueError, match="clock_only"):
        PPOConfig("comm_channel_k2-v0", clock_only=True)


def test_comm_fields_actor_reads_the_communication_fields_and_no_other():
    """``comm_fields_only``: changing the measurements and the estimator's slots leaves
    the logits unchanged, changing the acks or the silence does not; the kept entries are
    exactly the communication fields and the time entry."""
    from netsense.rl.config import PPOConfig
    from netsense.rl.envs import make_core
    from netsense.rl.policy import CommFieldsActor, actor_net

    core = make_core("comm_fading-v0", 2)
    L = core.layout
    net = actor_net(PPOConfig("comm_fading-v0", ages=(1, 4), comm_fields_only=True), core)
    assert isinstance(net, CommFieldsActor)
    kept = {i for f in CommFieldsActor.FIELDS if getattr(L, f) is not None
            for i in range(L.size)[getattr(L, f)]}
    assert set(torch.nonzero(net.keep).flatten().tolist()) == kept
    assert set(range(L.size)[L.acks]) <= kept and L.time.start in kept
    obs, _ = core.reset([1, 2])
    o = torch.as_tensor(obs)
    with torch.no_grad():
        base = net(o)
        other = o.clone()
        other[..., L.y] += 5.0
        other[..., L.slot_omega] += 3.0
        assert torch.equal(net(other), base)
        for field, value in ((L.acks, -1.0), (L.silence, 7 / core.horizon)):
            changed = o.clone()
            changed[..., field] = value
            assert not torch.equal(net(changed), base)
    with pytest.raises(ValueError, match="communication-only"):
        actor_net(PPOConfig("comm_substates-v0", comm_fields_only=True, control="substates"),
                  make_core("comm_substates-v0", 1, control="full"))


@pytest.mark.parametrize("inputs", [{"clock": (2, 5), "memory": 8},
                                    {"ages": (1, 4), "clock": (2,)}],
                         ids=["clock-memory", "ages-clock"])
def test_input_features_policy_trains_saves_and_loads(tmp_path, inputs):
    """A policy with a clock (and memory), or with the age features, round-trips through
    its file: loading rebuilds the features, whose inputs the weights expect."""
    from netsense.rl.checkpoint import load_policy
    from netsense.rl.envs import make_core
    from netsense.rl.ppo import train_ppo

    res = train_ppo(_small("mappo", "mlp", control="transmit", **inputs), tmp_path)
    assert res.mask_violations == 0 and np.isfinite(res.rows[-1]["eval_return"])
    core = make_core(SCEN, 2, control="transmit", **SHORT)
    pol = load_policy(tmp_path / "policy.pt", core)
    o, m = core.reset(3)
    for _ in range(6):
        out = core.step(pol.act(o, m))
        o, m = out.obs, out.action_mask


def test_clock_only_policy_loads_blind_to_the_state(tmp_path):
    """The policy file records ``clock_only``: the loaded feed-forward policy gives the same
    logits on two members whose observations differ but for the step."""
    from netsense.rl.checkpoint import load_policy
    from netsense.rl.envs import make_core
    from netsense.rl.ppo import train_ppo

    train_ppo(_small("mappo", "mlp", control="transmit", clock=(2, 5), clock_only=True),
              tmp_path)
    core = make_core(SCEN, 2, control="transmit", **SHORT)
    core.reset(3)
    for _ in range(3):
        o = core.step(np.ones((2, core.N, 1), dtype=np.int64)).obs
    assert not np.array_equal(o[0], o[1])
    with torch.no_grad():
        logits = load_policy(tmp_path / "policy.pt", core).net(torch.as_tensor(o))
    np.testing.assert_array_equal(logits[0].numpy(), logits[1].numpy())


def test_age_features_decay_with_the_steps_of_news_and_silence():
    """``ages``: each news and silence entry, read in steps from its units of the horizon,
    gives exp(-a / tau) per scale: 1 at age 0, e^-1 at a = tau, the first steps apart by
    order-1 differences where the raw entries differ by 1 / H; other entries add nothing."""
    from netsense.rl.envs import make_core
    from netsense.rl.policy import AgeActor

    core = make_core("comm_fading-v0", 1)
    L, H, M = core.layout, core.horizon, core.M
    ages = AgeActor(torch.nn.Identity(), L.news, L.silence, H, (1, 4))
    obs = torch.zeros(3, L.size)
    obs[:, L.news] = torch.tensor([0.0, 1.0, 4.0])[:, None] / H
    obs[:, L.silence.start] = torch.tensor([4.0, 0.0, float(H)]) / H
    obs[:, L.time.start] = 0.5  # not an age: no feature
    feat = ages(obs)[:, L.size:].reshape(3, M + 1, 2).numpy()
    steps = np.array([[0.0] * M + [4.0], [1.0] * M + [0.0], [4.0] * M + [H]])
    want = np.exp(-steps[..., None] / np.array([1.0, 4.0]))
    np.testing.assert_allclose(feat, want, rtol=1e-6, atol=1e-12)
    assert feat[0, M, 1] == pytest.approx(np.exp(-1.0))  # silence 4 at tau = 4
    np.testing.assert_array_equal(ages(obs)[:, :L.size].numpy(), obs.numpy())


def test_age_features_need_the_comm_fields_and_the_raw_observation():
    """A config asking for ages in full control, or with obs_norm, is refused naming it."""
    from netsense.rl.config import PPOConfig

    with pytest.raises(ValueError, match="PPOConfig.ages reads the news and silence"):
        PPOConfig(SCEN, ages=(2,), control="full")
    with pytest.raises(ValueError, match="PPOConfig.ages: the age features"):
        PPOConfig(SCEN, ages=(2,), obs_norm=True)


def test_set_network_runs_at_any_size_with_the_same_parameters():
    from netsense.rl.envs import make_core
    from netsense.rl.set_network import SetPolicyNet

    small, large = make_core("fig1_scalar-v0", 2), make_core(SCEN, 2)
    assert (small.N, small.D) != (large.N, large.D)
    torch.manual_seed(0)
    net = SetPolicyNet(small.layout, small.nvec, hidden=16)
    other = SetPolicyNet(large.layout, large.nvec, hidden=16)
    other.load_state_dict(net.state_dict())  # no size-dependent parameter
    for core, module in ((small, net), (large, other)):
        obs, mask = core.reset(0)
        logits = module(torch.as_tensor(obs))
        assert logits.shape == (2, core.N, int(np.sum(core.nvec)))
        assert torch.isfinite(logits).all()
    x = torch.as_tensor(large.observe()[0])
    np.testing.assert_array_equal(net.bind(large.layout)(x).detach(), other(x).detach())


def test_set_network_is_equivariant_to_slot_order():
    from netsense.rl.envs import make_core
    from netsense.rl.set_network import SetPolicyNet

    core = make_core(SCEN, 2)
    obs, _ = core.reset(1)
    L, D, M = core.layout, core.D, core.M
    perm = np.random.default_rng(0).permutation(D)
    po = obs.copy()
    for f in (L.slot_arrived, L.slot_id):
        po[..., f] = obs[..., f][..., perm]
    for f in (L.slot_omega, L.slot_age):
        po[..., f] = obs[..., f].reshape(2, core.N, D, M)[:, :, perm].reshape(2, core.N, -1)
    torch.manual_seed(0)
    net = SetPolicyNet(L, core.nvec, hidden=16)
    a = net(torch.as_tensor(obs)).detach().numpy()
    b = net(torch.as_tensor(po)).detach().numpy()
    blocks = lambda x: x[..., :M * (D + 2)].reshape(2, core.N, M, D + 2)  # noqa: E731
    np.testing.assert_allclose(blocks(b)[..., 1:D + 1], blocks(a)[..., 1:D + 1][..., perm],
                               atol=1e-5)
    np.testing.assert_allclose(b[..., -2:], a[..., -2:], atol=1e-5)  # transmit unchanged


def test_set_network_without_slots_reads_no_slot_and_keeps_the_parameters():
    """``slots=False``: the same parameters as the slot-pooling net; its substate
    embeddings are ``sub_mix`` on ``[u, 0, 0, agent]`` (checked against that formula), the
    logits do not move when only the pair tokens' fields change (the agent token keeps the
    share of arrived slots), the slot-pooling net's do, and
    full control, which scores adopt logits from slots, is refused by name."""
    from netsense.rl.config import PPOConfig
    from netsense.rl.envs import make_core
    from netsense.rl.set_network import SetPolicyNet

    core = make_core("comm_substates-v0", 2)
    obs, _ = core.reset(3)
    L = core.layout
    torch.manual_seed(0)
    full = SetPolicyNet(L, core.nvec, hidden=16)
    lite = SetPolicyNet(L, core.nvec, hidden=16, slots=False)
    lite.load_state_dict(full.state_dict())  # same parameters
    x = torch.as_tensor(obs)
    g, u, _, _ = full.tokens(x)
    ge, ue = full.agent_enc(g), full.sub_enc(u)
    zero = torch.zeros_like(ue)
    s = full.sub_mix(torch.cat([ue, zero, zero, ge.unsqueeze(-2).expand_as(ue)], -1))
    want = full.send_head(torch.cat([s, ge.unsqueeze(-2).expand_as(s)], -1)).flatten(-2)
    np.testing.assert_allclose(lite(x).detach(), want.detach(), atol=1e-5)
    moved = obs.copy()
    for f in (L.slot_omega, L.slot_age):
        moved[..., f] = np.random.default_rng(0).random(moved[..., f].shape)
    np.testing.assert_array_equal(lite(torch.as_tensor(moved)).detach(), lite(x).detach())
    assert not torch.equal(full(torch.as_tensor(moved)), full(x))
    news = obs.copy()
    news[..., L.news] = 1.0 - news[..., L.news]
    assert not torch.equal(lite(torch.as_tensor(news)), lite(x))
    with pytest.raises(ValueError, match="full control"):
        SetPolicyNet(make_core(SCEN, 1).layout, make_core(SCEN, 1).nvec, slots=False)
    with pytest.raises(ValueError, match="set_slots=False"):
        PPOConfig("comm_substates-v0", set_slots=False)  # the MLP has no slots to leave
    with pytest.raises(ValueError, match="set_slots=False"):
        PPOConfig(SCEN, network="set", control="full", set_slots=False)
    with pytest.raises(ValueError, match="set_slots=False"):  # the mode as a table too
        PPOConfig(SCEN, network="set", control={"mode": "full"}, set_slots=False)


def test_behaviour_cloning_learns_the_freshness_choices(capsys):
    from netsense.rl.cloning import behaviour_clone
    from netsense.rl.config import PPOConfig
    from netsense.rl.envs import make_core
    from netsense.rl.policy import actor_net

    torch.manual_seed(0)
    cfg = PPOConfig(SCEN, network="set", num_envs=8, bc_minibatch=32, set_hidden=16,
                    overrides=SHORT)
    net = actor_net(cfg, make_core(SCEN, 1, **SHORT))
    stats = behaviour_clone(net, cfg, "freshness", steps=192, epochs=8, lr=3e-3,
                            progress=True)
    assert stats["ce_after"] < 0.5 * stats["ce_before"]
    assert stats["accuracy"] > stats["chance"] + 0.2
    err = capsys.readouterr().err  # the phase shows progress: data, then gradient steps
    assert "scripted data (freshness)" in err and "cloning freshness" in err
    assert "48/48" in err  # 8 epochs x ceil(192 / 32) minibatches


def test_behaviour_cloning_copies_a_communication_baseline():
    # sources:0 (sources send every step, relays never) is a deterministic function of the
    # observation: the clone must match it on held-out members and act like it
    from netsense.benchmark import protocol as pr
    from netsense.rl.cloning import behaviour_clone
    from netsense.rl.config import PPOConfig
    from netsense.rl.distributions import MaskedMultiCategorical
    from netsense.rl.envs import make_core
    from netsense.rl.policy import actor_net

    torch.manual_seed(0)
    sc = "comm_process_noise-v0"
    cfg = PPOConfig(sc, num_envs=16, bc_steps=512, bc_epochs=30, bc_minibatch=128,
                    overrides=SHORT)
    net = actor_net(cfg, make_core(sc, 1, **SHORT))
    stats = behaviour_clone(net, cfg, "sources:0")
    assert stats["accuracy"] > 0.98, stats
    net.eval()

    def act(o, m):  # the clone's most likely allowed action
        with torch.no_grad():
            return MaskedMultiCategorical(net(torch.as_tensor(o)), torch.as_tensor(m != 0),
                                          (2,)).deterministic_sample.numpy()

    core = make_core(sc, 4, **SHORT)
    o, m = core.reset(pr.eval_seeds(4))
    sent = 0.0
    for _ in range(SHORT["horizon"]):
        out = core.step(act(o, m))
        o, m = out.obs, out.action_mask
        sent += core.transmit.mean()
    assert sent / SHORT["horizon"] == pytest.approx(0.5, abs=0.02)  # five sources of ten


def test_bench_train_throughput_smoke(tmp_path):
    pytest.importorskip("sb3_contrib")
    import csv

    import torch
    from experiment_loader import load_experiment

    from netsense.rl.config import PPOConfig

    mod = load_experiment("bench/train_throughput")
    before = torch.get_num_threads()
    path = mod.main(["--paths", "torchrl-defaults-tx", "torchrl-serial-tx", "torchrl-tuned-tx",
                     "torchrl-onethread-tx", "sb3-supersuit-tx", "sb3-supersuit-cores-tx",
                     "--rounds", "1", "--iters", "2", "--grid", "4:8,8:16",
                     "--defaults-envs", "4", "--defaults-minibatch", "8", "--sb3-steps", "512",
                     "--out", str(tmp_path), "--tag", "smoke"])
    assert torch.get_num_threads() == before  # the paths' thread settings do not leak
    rows = list(csv.DictReader(open(path)))
    # the tuned path measures every grid point
    assert [(r["path"], r["num_envs"]) for r in rows] == [
        ("torchrl-defaults-tx", "4"), ("torchrl-serial-tx", "4"), ("torchrl-tuned-tx", "4"),
        ("torchrl-tuned-tx", "8"),
        ("torchrl-onethread-tx", "4"), ("sb3-supersuit-tx", ""), ("sb3-supersuit-cores-tx", "")]
    assert all(float(r["agent_steps_per_s"]) > 0 for r in rows)
    text = (tmp_path / "smoke.txt").read_text()
    sb3 = {p: float(r["agent_steps_per_s"]) for r in rows for p in [r["path"]]
           if p.startswith("sb3")}
    faster = max(sb3, key=sb3.get)
    line = next(t for t in text.splitlines() if t.startswith("ratio defaults / SB3"))
    assert f"(against {faster})" in line  # the ratio divides by SB3's faster setting
    med: dict[str, float] = {}  # one round: a path's figure is its best grid point's
    for r in rows:
        med[r["path"]] = max(med.get(r["path"], 0.0), float(r["agent_steps_per_s"]))
    line = next(t for t in text.splitlines() if t.startswith("ratio defaults (collection"))
    want = med["torchrl-defaults-tx"] / med["torchrl-serial-tx"]
    assert f"communication only {want:.2f}x" in line  # overlapped over serial, this run's
    line = next(t for t in text.splitlines() if t.startswith("fastest (-tx)"))
    fastest = max(med, key=med.get)
    assert f"fastest (-tx): {fastest}" in line
    assert (tmp_path / "smoke.png").exists()
    T = PPOConfig("comm_process_noise-v0").rollout
    for r in rows:  # TorchRL: the rate after the first iteration, the whole loop's beside it
        assert float(r["whole_agent_steps_per_s"]) > 0
        if r["path"].startswith("torchrl"):  # one iteration of two: num_envs x T x N
            assert int(r["agent_steps"]) == int(r["num_envs"]) * T * 10
    with pytest.raises(SystemExit):  # no iteration after the first to time
        mod.main(["--iters", "1", "--out", str(tmp_path)])


def test_bench_train_throughput_comm_control(tmp_path, monkeypatch, capsys):
    """``--comm-control`` reaches the TorchRL -tx paths (the -full ones keep full control)
    and is named in the report; with it the SB3 -tx paths, which train the scenario's own
    control, are refused before anything runs."""
    from experiment_loader import load_experiment

    mod = load_experiment("bench/train_throughput")
    seen = []

    def fake(scenario, control, B, minibatch, iters, **fields):
        seen.append((scenario, control))
        return {"agent_steps": 100, "wall_s": 1.0, "whole_agent_steps_per_s": 100.0,
                "collect_s": 0.1, "learn_s": 0.9, "num_envs": B, "minibatch": minibatch}

    monkeypatch.setattr(mod, "_torchrl", fake)
    mod.main(["--comm-scenario", "message_cost-v0", "--comm-control", "transmit",
              "--paths", "torchrl-defaults-tx", "torchrl-defaults-full", "--rounds", "1",
              "--out", str(tmp_path), "--tag", "ctl"])
    assert set(seen) == {("message_cost-v0", "transmit"), ("message_cost-v1", "full")}
    assert "message_cost-v0 (-tx: communication only, control transmit)" in (
        tmp_path / "ctl.txt").read_text()
    seen.clear()
    with pytest.raises(SystemExit):
        mod.main(["--comm-control", "transmit", "--paths", "torchrl-defaults-tx",
                  "sb3-supersuit-tx", "--out", str(tmp_path / "no")])
    assert "leave the sb3-*-tx paths out" in capsys.readouterr().err
    assert not seen and not (tmp_path / "no").exists()


def test_bench_update_cost_smoke(tmp_path):
    """The update-cost benchmark measures every grid point, size, thread count and loss,
    restores torch's thread count, and its report's ratios are those of its own CSV."""
    import csv
    import statistics

    import torch
    from experiment_loader import load_experiment

    mod = load_experiment("bench/update_cost")
    before = torch.get_num_threads()
    path = mod.main(["--grid", "4:8,8:16", "--iters", "2", "--rounds", "1", "--envs", "4",
                     "--sizes", "2", "8", "--max-steps", "4", "--out", str(tmp_path)])
    assert torch.get_num_threads() == before
    rows = list(csv.DictReader(open(tmp_path / "update_cost.csv")))
    threads = sorted({1, before})
    e2e = [r for r in rows if r["measure"] == "end_to_end"]
    upd = [r for r in rows if r["measure"] == "update"]
    assert sorted((r["num_envs"], r["minibatch"], int(r["threads"])) for r in e2e) == sorted(
        (b, m, t) for b, m in (("4", "8"), ("8", "16")) for t in threads)
    assert sorted((r["minibatch"], int(r["threads"]), r["loss"]) for r in upd) == sorted(
        (m, t, loss) for m in ("2", "8") for t in threads
        for loss in ("trainer", "functional"))
    assert all(float(r["s_per_step"]) > 0 for r in upd)
    # at most --max-steps gradient steps on the rollout's 4 * 32 env-steps
    assert {int(r["gradient_steps"]) for r in upd} == {4}
    text = path.read_text()
    learn = {(r["num_envs"], int(r["threads"])): float(r["learn_s_per_m"]) for r in e2e}
    line = next(t for t in text.splitlines()
                if t.startswith("# learning per agent-step at threads 1,"))
    assert f"4:8 {learn['4', 1] / learn['8', 1]:.2f}x" in line
    small = statistics.median(float(r["s_per_step"]) for r in upd
                              if r["minibatch"] == "2" and r["threads"] == "1"
                              and r["loss"] == "trainer")
    line = next(t for t in text.splitlines() if t.startswith("# threads 1: a gradient step"))
    assert f"takes {small * 1e3:.2f} ms" in line and "2: 100%" in line
    assert (tmp_path / "update_cost.png").exists()
    with pytest.raises(SystemExit):  # no iteration after the first to time
        mod.main(["--iters", "1", "--out", str(tmp_path)])


def test_bench_train_profile_second_thread_changes_timing_only():
    """The profile's busy second thread (compiled, memory or Python work) runs beside the training
    and stops with it, and the run trains as it does alone (it draws nothing from the
    generator the run seeds)."""
    import threading

    from experiment_loader import load_experiment

    from netsense.rl.config import PPOConfig
    from netsense.rl.ppo import train_ppo

    mod = load_experiment("bench/train_profile")
    cfg = PPOConfig("comm_process_noise-v0", num_envs=4, minibatch=8, steps=4 * 32 * 10 * 2,
                    overlap=False, eval_interval=0)
    alone = train_ppo(cfg, None, evaluate_every=False)
    keys = ("loss_objective", "loss_critic", "entropy", "step_reward")
    for kind in mod._WORK:
        beside = mod._beside(cfg, kind)
        assert not [t for t in threading.enumerate()  # the busy thread has stopped
                    if t.name.startswith("train-profile")]
        assert [[r[k] for k in keys] for r in beside.rows] == [
            [r[k] for k in keys] for r in alone.rows]


# ------------------------------------------------------------------ policy files
@pytest.fixture(scope="module")
def tiny_policies(tmp_path_factory):
    """A set-network and an MLP policy trained for one iteration on the transmit task."""
    from netsense.rl.config import PPOConfig
    from netsense.rl.ppo import train_ppo

    out = {}
    for network in ("set", "mlp"):
        run = tmp_path_factory.mktemp(network)
        cfg = PPOConfig("comm_process_noise-v0", network=network, steps=4 * 8 * 10,
                        num_envs=4, rollout=8, minibatch=16, epochs=1, eval_interval=0,
                        eval_envs=2, set_hidden=8, hidden=(16,), overrides=SHORT, seed=3)
        train_ppo(cfg, run)
        out[network] = run / "policy.pt"
    return out


def test_protocol_evaluates_pt_policies_in_their_control_mode(tiny_policies):
    from netsense.benchmark import protocol as pr
    from netsense.rl.checkpoint import load_policy
    from netsense.rl.envs import make_core

    path = tiny_policies["set"]
    seeds = pr.eval_seeds(3)
    got = pr.evaluate("comm_process_noise-v0", f"learned:{path}", seeds, SHORT)
    # the same policy acting by hand on a core of the same seeds
    core = make_core("comm_process_noise-v0", 3, **SHORT)
    pol = load_policy(path, core)
    o, m = core.reset(seeds)
    sent = np.zeros(3)
    for _ in range(SHORT["horizon"]):
        out = core.step(pol.act(o, m))
        o, m = out.obs, out.action_mask
        sent += core.transmit.sum(1)
    np.testing.assert_allclose(got["msgs_per_agent_step"], sent / (core.N * SHORT["horizon"]))
    # on a full-control scenario the stored control puts it in its transmit mode; the set
    # network runs there although M differs (10 substates, trained on 5)
    rows = pr.frontier("message_cost-v1", episodes=2, families={}, learned=[str(path)],
                       overrides=SHORT, progress=False, settled_bases=())
    learned = [r for r in rows if r["family"] == "learned"]
    assert [r["evaluation"] for r in learned] == ["greedy", "sampled"]
    assert {r["control"] for r in learned} == {"transmit"}


def test_pt_policy_through_the_pettingzoo_benchmark_equals_the_batched_protocol(tiny_policies):
    from netsense import benchmark as bm
    from netsense.benchmark import protocol as pr

    path = tiny_policies["set"]
    seeds = pr.eval_seeds(2)
    batched = pr.evaluate("comm_process_noise-v0", f"learned:{path}", seeds, SHORT)
    jobs = bm.make_jobs(["comm_process_noise-v0"], [f"learned:{path}"], seeds,
                        overrides=SHORT)
    res = bm.execute(jobs, backend="serial", progress=False)
    np.testing.assert_allclose(batched["reward"], [r["metrics"]["reward"] for r in res],
                               rtol=1e-9)


def test_pt_policy_files_are_checked(tiny_policies, tmp_path):
    from netsense.benchmark import protocol as pr
    from netsense.rl.checkpoint import load_policy
    from netsense.rl.envs import make_core

    # an MLP is tied to the layout it was trained on (here N = 10, M = 5)
    small = make_core("fig1_scalar-v0", 1, control="transmit")
    with pytest.raises(ValueError, match="layout it was trained on"):
        load_policy(tiny_policies["mlp"], small)
    bad = tmp_path / "policy.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="not a readable policy file"):
        pr.evaluate("comm_process_noise-v0", f"learned:{bad}", pr.eval_seeds(1), SHORT)
    with pytest.raises(ValueError, match="no policy file"):
        load_policy(tmp_path / "missing.pt")
    # training seeds 3 * 4 + b = 12..15: evaluating on them is refused
    with pytest.raises(ValueError, match="used in training"):
        pr.evaluate("comm_process_noise-v0", f"learned:{tiny_policies['set']}", [13], SHORT)


@pytest.mark.parametrize("kw,match", [
    ({"control": "tx"}, "control must be one of"),
    ({"control": 3}, "control must be a mode name"),
    ({"control": {"mode": "broadcast"}}, "control.mode"),
])
def test_make_core_names_a_bad_control(kw, match):
    from netsense.rl.envs import make_core

    with pytest.raises(ValueError, match=match):
        make_core(SCEN, 1, **kw)


@pytest.mark.parametrize("kw,match", [
    ({"bc_lr": 0.0}, "bc_lr"), ({"lr": float("nan")}, "lr"), ({"bc_minibatch": 0}, "bc_minibatch"),
    ({"seed": -1}, "seed"), ({"seed": 4000, "num_envs": 256}, "below 900000"),
    ({"control": "tx"}, "control"),
])
def test_ppo_config_names_bad_fields(kw, match):
    from netsense.rl.config import PPOConfig

    with pytest.raises(ValueError, match=match):
        PPOConfig(SCEN, **kw)


@pytest.mark.parametrize(("scenario", "control"), [("comm_substates-v0", None),
                                                   ("comm_process_noise-v0", "transmit")])
def test_news_gate_that_always_sends_is_event_1(scenario, control):
    """Behind the news gate, a network that prefers every send is ``event:1`` (send what is
    news) action for action over an episode; a network without preference sends nothing
    without news and half of the news."""
    from netsense.rl.distributions import MaskedMultiCategorical
    from netsense.rl.envs import make_core
    from netsense.rl.policy import NewsGateActor
    from netsense.rl.scripted import scripted_actions

    class Prefers(torch.nn.Module):
        def __init__(self, send: float):
            super().__init__()
            self.send = send

        def forward(self, obs):
            n = len(core.nvec)
            return torch.tensor([0.0, self.send]).repeat(n).expand(*obs.shape[:-1], 2 * n)

    core = make_core(scenario, 4, control=control)
    event = scripted_actions("event:1", core)
    eager = NewsGateActor(Prefers(10.0), core.layout.news, core.control.mode)
    even = NewsGateActor(Prefers(0.0), core.layout.news, core.control.mode)
    obs, mask = core.reset(0)
    sent_any = withheld = 0
    for _ in range(core.horizon):
        o, m = torch.as_tensor(obs), torch.as_tensor(mask.view(np.bool_))
        a = MaskedMultiCategorical(eager(o), m, core.nvec).deterministic_sample.numpy()
        np.testing.assert_array_equal(a, event(obs, mask))
        p_send = MaskedMultiCategorical(even(o), m, core.nvec).base_dist.probs[..., 1]
        fresh = o[..., core.layout.news] > 0
        if core.control.mode == "transmit":
            fresh = fresh.any(-1, keepdim=True)
        assert torch.all(p_send[~fresh] == 0)
        allowed = fresh & m.unflatten(-1, (-1, 2))[..., 1]
        assert torch.allclose(p_send[allowed], torch.tensor(0.5))
        sent_any += int(a.sum())
        withheld += int((~fresh).sum())
        out = core.step(a)
        obs, mask = out.obs, out.action_mask
    assert sent_any > 0 and withheld > 0  # both branches were exercised


def test_news_gate_needs_a_communication_only_mode():
    from netsense.rl.config import PPOConfig
    from netsense.rl.envs import make_core
    from netsense.rl.policy import actor_net

    core = make_core(SCEN, 2, control="full")
    with pytest.raises(ValueError, match="news_gate.*communication-only"):
        actor_net(PPOConfig(scenario=SCEN, news_gate=True), core)


@pytest.mark.parametrize("network,memory", [("set", 8), ("mlp", 0)])
def test_news_gate_policy_trains_saves_and_loads(tmp_path, network, memory):
    """A gated policy (set network with memory, MLP) round-trips through its file, and the
    loaded policy, sampling, sends no substate without news."""
    from netsense.rl.checkpoint import load_policy
    from netsense.rl.envs import make_core
    from netsense.rl.ppo import train_ppo

    res = train_ppo(_small("mappo", network, control="substates", news_gate=True,
                           memory=memory), tmp_path)
    assert res.mask_violations == 0 and np.isfinite(res.rows[-1]["eval_return"])
    core = make_core(SCEN, 3, control="substates", **SHORT)
    pol = load_policy(tmp_path / "policy.pt", core, deterministic=False)
    o, m = core.reset(5)
    sent = 0
    for _ in range(core.horizon - 1):
        a = pol.act(o, m)
        assert not np.any(a.astype(bool) & (o[..., core.layout.news] <= 0))
        sent += int(a.sum())
        out = core.step(a)
        o, m = out.obs, out.action_mask
    assert sent > 0


def test_shifted_clock_is_each_agents_own_frame():
    """With ``shift``, agent i reads at step k the common clock's features of step k - i;
    on comm_channel_k2-v0 the rule "send at phase 0 or 1 of period 5", shared by every
    agent, lets exactly two of the five sources send at every step (no collision) and every
    source in turn."""
    from netsense.rl.envs import make_core
    from netsense.rl.policy import ClockActor

    core = make_core("comm_channel_k2-v0", 1)
    H, t, N, O = core.horizon, core.layout.time.start, core.N, core.layout.size
    common = ClockActor(torch.nn.Identity(), t, H, (5,))
    shifted = ClockActor(torch.nn.Identity(), t, H, (5,), shift=True)
    obs = torch.zeros(H, N, O)
    obs[..., t] = (torch.arange(H, dtype=torch.float32) / H)[:, None]
    mine, ref = shifted(obs)[..., O:], common(obs)[..., O:]
    for i in range(N):
        np.testing.assert_allclose(mine[N:, i], ref[N - i:H - i, 0], atol=1e-5)
    phase = torch.round(torch.atan2(mine[..., 0], mine[..., 1]) / (2 * np.pi) * 5) % 5
    send = (phase <= 1).numpy()
    sources = core.layout.own >= 0
    assert np.all(send[:, sources].sum(1) == 2)
    assert np.all(send[:, sources].any(0))
