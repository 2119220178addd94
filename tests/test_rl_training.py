"""The training loop's parts against independent computations: GAE, explained variance,
the return scaler, recurrent unrolls, the lean collector (resets, hidden states, masks), a
recurrent policy file, and the log's contract (no NaN, no stale rows)."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

SCEN = "comm_process_noise-v0"


# ------------------------------------------------------------------ advantages
def _gae_by_hand(values, reward, done, gamma, lmbda):
    """The textbook recursion, one member-agent at a time (values (T + 1,))."""
    T = len(reward)
    adv = np.zeros(T)
    last = 0.0
    for t in reversed(range(T)):
        nonterminal = 0.0 if done[t] else 1.0
        delta = reward[t] + gamma * values[t + 1] * nonterminal - values[t]
        last = delta + gamma * lmbda * nonterminal * last
        adv[t] = last
    return adv, adv + values[:T]


def test_gae_equals_the_recursion_with_episode_ends():
    from netsense.rl.advantage import estimate

    rng = np.random.default_rng(0)
    T, B, N = 7, 3, 2
    values = rng.normal(size=(T + 1, B, N))
    reward = rng.normal(size=(T, B, N))
    done = rng.random((T, B)) < 0.3
    out = estimate(torch.tensor(values), torch.tensor(reward), torch.tensor(done), 0.9, 0.8)
    for b in range(B):
        for i in range(N):
            adv, target = _gae_by_hand(values[:, b, i], reward[:, b, i], done[:, b], 0.9, 0.8)
            # TorchRL's vectorised form (discounted sums as products) rounds at ~1e-8
            np.testing.assert_allclose(out.advantage[:, b, i].numpy(), adv, atol=1e-6)
            np.testing.assert_allclose(out.target[:, b, i].numpy(), target, atol=1e-6)


def test_explained_variance_closed_form():
    from netsense.rl.advantage import explained_variance

    target = torch.tensor([1.0, 2.0, 3.0, 4.0])
    assert explained_variance(target, target) == pytest.approx(1.0)
    assert explained_variance(torch.full((4,), 2.5), target) == pytest.approx(0.0)
    # residuals of mean 0 and a quarter of the target's variance (ratio free of ddof):
    # sum of squares 4 a^2 = 5 / 4 against the target's 5
    pred = target + torch.tensor([1.0, -1.0, 1.0, -1.0]) * math.sqrt(5 / 16)
    assert explained_variance(pred, target) == pytest.approx(0.75, abs=1e-6)


def test_return_scaler_divides_by_the_return_std():
    from netsense.rl.ppo import ReturnScaler

    rng = np.random.default_rng(1)
    T, B, N = 6, 4, 2
    reward = torch.tensor(rng.normal(size=(T, B, N)))
    done = torch.zeros(T, B, dtype=torch.bool)
    done[2, 1] = True
    sc = ReturnScaler(0.5)
    scaled = sc(reward, done)
    R = np.zeros((B, N))
    seen = []
    for t in range(T):
        R = 0.5 * R + reward[t].numpy()
        seen.append(R.copy())
        R[done[t].numpy()] = 0.0
    std = np.concatenate([s.ravel() for s in seen]).std()
    np.testing.assert_allclose(scaled.numpy(), reward.numpy() / std, rtol=1e-5)


# ------------------------------------------------------------------ recurrence
def test_unroll_equals_stepping_with_resets():
    from netsense.rl.memory import RecurrentActor, unroll

    torch.manual_seed(0)
    net = RecurrentActor(5, 3, (8,), memory=4)
    S, T, N = 2, 5, 3
    obs = torch.randn(S, T, N, 5)
    h0 = torch.randn(S, N, 4)
    first = torch.zeros(S, T, dtype=torch.bool)
    first[0, 2] = first[1, 0] = True
    got = unroll(net, obs, h0, first)
    for s in range(S):
        h = h0[s]
        for t in range(T):
            if first[s, t]:
                h = torch.zeros_like(h)
            logits, h = net(obs[s, t], h)
            torch.testing.assert_close(got[s, t], logits)


@pytest.fixture(scope="module")
def core_env():
    from netsense.rl.envs import NetSenseBatchedEnv, make_core

    core = make_core(SCEN, 3, horizon=6)
    return core, NetSenseBatchedEnv(core, reward="team", seed=5)


def test_collector_restarts_members_and_zeroes_their_hidden_state(core_env):
    from netsense.rl.evaluation import mask_violations
    from netsense.rl.memory import RecurrentActor
    from netsense.rl.rollout import Collector

    core, env = core_env
    torch.manual_seed(0)
    net = RecurrentActor(core.layout.size, int(sum(core.nvec)), (8,), memory=4)
    col = Collector(env, net, 9, with_state=True)
    ro = col.collect()
    # horizon 6: every member ends at t = 5 and starts again at t = 6
    assert ro.done[5].all() and not ro.done[:5].any() and not ro.done[6:].any()
    assert ro.first[0].all() and ro.first[6].all() and not ro.first[1:6].any()
    assert torch.all(ro.hidden[0] == 0) and torch.all(ro.hidden[6] == 0)
    assert torch.any(ro.hidden[3] != 0)
    # the time field k / H restarts with the episode (obs[9] follows the last step)
    time = ro.obs[..., core.layout.time][:, 0, 0, 0].numpy()
    np.testing.assert_allclose(time, np.array([0, 1, 2, 3, 4, 5, 0, 1, 2, 3]) / 6, atol=1e-6)
    assert ro.state.shape == (10, 3, env.state_dim)
    assert len(ro.returns) == 3
    assert mask_violations(ro.mask, ro.action, core.nvec) == 0


def test_minibatch_gather_equals_tensordict_indexing(core_env):
    """The loss batch's minibatches: the rows of every entry, nested batch sizes kept."""
    from netsense.rl.advantage import critic_values, estimate, loss_batch
    from netsense.rl.config import PPOConfig
    from netsense.rl.policy import actor_net, critic_module
    from netsense.rl.ppo import _gather
    from netsense.rl.rollout import Collector

    core, env = core_env
    torch.manual_seed(1)
    cfg = PPOConfig(SCEN, num_envs=3, critic="state", reward="agent")
    net = actor_net(cfg, core, "cpu")
    critic = critic_module(cfg, env, "cpu")
    ro = Collector(env, net, 7, with_state=True).collect()
    data = loss_batch(ro, estimate(critic_values(critic, ro, None), ro.reward, ro.done,
                                   0.99, 0.95))
    idx = torch.tensor([20, 3, 3, 0, 11])
    got, want = _gather(data, idx), data[idx]
    assert got.batch_size == want.batch_size == (5,)
    assert got["agents"].batch_size == want["agents"].batch_size == (5, core.N)
    keys = sorted(want.keys(True, True), key=str)
    assert sorted(got.keys(True, True), key=str) == keys and ("agents", "observation") in keys
    for k in keys:
        assert got[k].dtype == want[k].dtype and torch.equal(got[k], want[k]), k


@pytest.mark.parametrize("nvec", [(2,), (3, 3), (11,) * 10 + (2,), (2, 5, 1)])
def test_masked_distribution_equals_one_torchrl_categorical_per_entry(nvec):
    """Log-probabilities, entropies and their gradients against TorchRL's
    MaskedCategorical on every entry alone, summed; bfloat16 logits are computed in
    float32."""
    from torchrl.modules import MaskedCategorical

    from netsense.rl.distributions import MaskedMultiCategorical

    torch.manual_seed(0)
    x = (torch.randn(40, 3, sum(nvec)) * 3).requires_grad_()
    m = torch.rand(40, 3, sum(nvec)) < 0.5
    starts = np.cumsum((0,) + nvec[:-1])
    m[..., starts] = True  # every entry allows a choice
    w = torch.randn(40, 3)
    d = MaskedMultiCategorical(x, m, nvec)
    a = d.sample()
    assert bool(m.gather(-1, torch.as_tensor(starts)[None, None, :] + a).all())
    lp, ent = d.log_prob(a), d.entropy()
    grad = torch.autograd.grad((lp * w).sum() + ent.sum(), x)[0]
    ref_lp = ref_ent = 0.0
    for e, (s0, k) in enumerate(zip(starts, nvec, strict=True)):
        c = MaskedCategorical(logits=x[..., s0:s0 + k], mask=m[..., s0:s0 + k])
        ref_lp = ref_lp + c.log_prob(a[..., e])
        ref_ent = ref_ent + c.entropy()
    ref_grad = torch.autograd.grad((ref_lp * w).sum() + ref_ent.sum(), x)[0]
    torch.testing.assert_close(lp, ref_lp)
    torch.testing.assert_close(ent, ref_ent)
    torch.testing.assert_close(grad, ref_grad)
    half = MaskedMultiCategorical(x.detach().bfloat16(), m, nvec)
    assert half.base_dist.logits.dtype == torch.float32


def test_own_substate_features_give_the_mlp_the_same_input_under_autocast(core_env):
    """Under bfloat16 autocast the actor casts the observation before appending the
    one-hot: the logits equal those of the float32 concatenation cast by the first layer,
    bit for bit; outside autocast it stays float32."""
    from netsense.rl.config import PPOConfig
    from netsense.rl.policy import actor_net

    core, _ = core_env
    net = actor_net(PPOConfig(SCEN, num_envs=3), core, "cpu")
    obs = torch.randn(7, core.N, core.layout.size)
    feat = net.onehot.expand(7, core.N, net.onehot.shape[-1])
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = net(obs)
        want = net.body(torch.cat([obs, feat], -1))
    assert got.dtype == torch.bfloat16 and torch.equal(got, want)
    assert net(obs).dtype == torch.float32


def test_keep_freed_memory_sets_glibc_malloc():
    import platform
    import sys

    from netsense.rl.ppo import keep_freed_memory

    glibc = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"
    assert keep_freed_memory() is glibc


def test_precision_auto_is_bf16_only_on_cpus_with_native_bf16(monkeypatch):
    from netsense.rl.config import learner_precision

    cpu, gpu = torch.device("cpu"), torch.device("cuda")
    monkeypatch.setattr(torch.cpu, "_is_avx512_bf16_supported", lambda: True)
    assert learner_precision("auto", cpu) == "bf16"
    assert learner_precision("auto", gpu) == "fp32"  # not measured on a GPU
    assert learner_precision("fp32", cpu) == "fp32"
    monkeypatch.setattr(torch.cpu, "_is_avx512_bf16_supported", lambda: False)
    assert learner_precision("auto", cpu) == "fp32"  # emulated bfloat16 is slower
    assert learner_precision("bf16", cpu) == "bf16"  # asked for: given
    monkeypatch.delattr(torch.cpu, "_is_avx512_bf16_supported")
    assert learner_precision("auto", cpu) == "fp32"  # a torch without the probe


def test_bf16_precision_changes_the_loss_arithmetic_only(tmp_path):
    """The same run in bfloat16 mixed precision and in float32: the first rollout is the
    same (collection is float32 either way), its losses differ by bfloat16's rounding, not
    more; the run records the precision it used."""
    import json

    from netsense.rl.config import PPOConfig
    from netsense.rl.ppo import train_ppo

    rows = {}
    for prec in ("fp32", "bf16"):
        cfg = PPOConfig(SCEN, num_envs=8, rollout=8, steps=8 * 8 * 10, epochs=2,
                        minibatch=32, eval_interval=0, eval_envs=2, precision=prec,
                        overrides={"horizon": 16})
        rows[prec] = train_ppo(cfg, tmp_path / prec).rows[0]
        summary = json.loads((tmp_path / prec / "summary.json").read_text())
        assert summary["precision"] == prec
    a, b = rows["fp32"], rows["bf16"]
    assert a["step_reward"] == b["step_reward"]
    for k in ("loss_critic", "loss_entropy", "entropy"):
        assert a[k] != b[k], k  # the loss ran in another arithmetic
        assert b[k] == pytest.approx(a[k], rel=0.02), k


def test_torch_threads_are_set_only_when_given(tmp_path):
    """``PPOConfig.torch_threads`` goes to ``torch.set_num_threads``; ``None`` (the default)
    leaves the process's setting, and ``summary.json`` records the count the learner ran
    with."""
    import json

    from netsense.rl.config import PPOConfig
    from netsense.rl.ppo import train_ppo

    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        assert PPOConfig(SCEN).torch_threads is None
        for given, want in ((None, 2), (1, 1)):
            cfg = PPOConfig(SCEN, num_envs=4, rollout=4, steps=4 * 4 * 10, epochs=1,
                            minibatch=16, eval_interval=0, eval_envs=1,
                            torch_threads=given, overrides={"horizon": 8})
            train_ppo(cfg, tmp_path / str(given))
            assert torch.get_num_threads() == want
            summary = json.loads((tmp_path / str(given) / "summary.json").read_text())
            assert summary["torch_threads"] == want
    finally:
        torch.set_num_threads(before)


def _tiny(**kw):
    from netsense.rl.config import PPOConfig

    base = dict(num_envs=8, rollout=8, steps=8 * 8 * 10 * 4, epochs=2, minibatch=32,
                eval_interval=0, eval_envs=2, overrides={"horizon": 16})
    return PPOConfig(SCEN, **{**base, **kw})


def _second_rollout_of_the_initial_actor(cfg):
    """Replays the training loop's first steps by hand: the actor it builds from the seed,
    the collector it builds, two rollouts without any update."""
    from netsense.rl.envs import NetSenseBatchedEnv, make_core
    from netsense.rl.policy import actor_net
    from netsense.rl.rollout import Collector

    torch.manual_seed(cfg.seed)
    core = make_core(cfg.scenario, cfg.num_envs, **cfg.overrides)
    env = NetSenseBatchedEnv(core, reward=cfg.reward, seed=cfg.seed * cfg.num_envs)
    net = actor_net(cfg, core, torch.device("cpu"))
    col = Collector(env, net, cfg.rollout, stagger=cfg.stagger, seed=cfg.seed)
    col.collect()
    return col.collect()


@pytest.mark.parametrize("overlap", [True, False])
def test_overlap_collects_the_next_rollout_with_parameters_one_update_behind(overlap):
    """With ``overlap`` the second rollout comes from the initial parameters (collected
    while the learner made its first update); without it, from the updated ones."""
    from netsense.rl.ppo import train_ppo

    cfg = _tiny(overlap=overlap)
    rows = train_ppo(cfg).rows
    ro = _second_rollout_of_the_initial_actor(cfg)
    same = (rows[1]["step_reward"] == float(ro.reward.mean())
            and rows[1]["train_messages"] == float(ro.sent.mean()))
    assert same == overlap


def test_overlap_trains_every_iteration_on_the_decoupled_batch(monkeypatch):
    """The overlapped loop prepares every iteration's batch for the decoupled objective,
    with the learner's actor at the parameters it has when the update starts; the serial
    loop trains plain PPO on the batch as collected."""
    import netsense.rl.ppo as ppo

    calls = []

    def spy(data, actor, *, precision):
        calls.append([p.detach().clone() for p in actor.parameters()])
        return decouple(data, actor, precision=precision)

    decouple = ppo.decouple
    monkeypatch.setattr(ppo, "decouple", spy)
    res = ppo.train_ppo(_tiny())
    assert len(calls) == len(res.rows) == 4
    assert any(not torch.equal(a, b) for a, b in zip(calls[0], calls[1], strict=True))
    calls.clear()
    ppo.train_ppo(_tiny(overlap=False))
    assert calls == []


def test_decouple_of_on_policy_data_changes_nothing_with_an_observation_normaliser(core_env):
    """Data collected by the current actor (with its normaliser's statistics as they are):
    proximal = behaviour, so the weights are 1 and the advantages stay; the proximal pass
    reads the actor's current statistics (a stale copy of them would not)."""
    from netsense.rl.advantage import critic_values, decouple, estimate, loss_batch
    from netsense.rl.config import PPOConfig
    from netsense.rl.policy import actor_net, build_actor, critic_module
    from netsense.rl.rollout import Collector

    core, env = core_env
    torch.manual_seed(1)
    cfg = PPOConfig(SCEN, num_envs=3, obs_norm=True)
    net = actor_net(cfg, core, torch.device("cpu"))
    net.update(torch.randn(64, core.layout.size) * 3 + 2)  # statistics far from (0, 1)
    ro = Collector(env, net, 6, with_state=True).collect()
    adv = estimate(critic_values(critic_module(cfg, env, torch.device("cpu")), ro),
                   ro.reward, ro.done, 0.99, 0.95)
    data = loss_batch(ro, adv)
    before = data["agents", "advantage"].clone()
    decouple(data, build_actor(net, core.nvec))
    torch.testing.assert_close(data["agents", "action_log_prob"], ro.log_prob.reshape(
        data["agents", "action_log_prob"].shape), rtol=0, atol=1e-5)
    torch.testing.assert_close(data["agents", "advantage"], before, rtol=1e-5, atol=1e-6)


@pytest.mark.filterwarnings("ignore:No target network updater")
def test_decouple_gives_torchrl_delay_actor_loss(core_env):
    """PPO's loss on the decoupled batch equals TorchRL's own decoupled loss
    (``delay_actor``, proximal = the current parameters) on the batch as collected, for
    data whose behaviour policy differs from the proximal one."""
    from torchrl.objectives.multiagent import MAPPOLoss

    from netsense.rl.advantage import critic_values, decouple, estimate, loss_batch
    from netsense.rl.config import PPOConfig
    from netsense.rl.policy import actor_net, build_actor, critic_module
    from netsense.rl.rollout import Collector

    core, env = core_env
    torch.manual_seed(0)
    cfg = PPOConfig(SCEN, num_envs=3)
    net = actor_net(cfg, core, torch.device("cpu"))
    behaviour = actor_net(cfg, core, torch.device("cpu"))  # other weights collect
    actor = build_actor(net, core.nvec)
    critic = critic_module(cfg, env, torch.device("cpu"))
    ro = Collector(env, behaviour, 6, with_state=True).collect()
    adv = estimate(critic_values(critic, ro), ro.reward, ro.done, 0.99, 0.95)
    keys = dict(action=("agents", "action"), sample_log_prob=("agents", "action_log_prob"),
                value=("agents", "state_value"), advantage=("agents", "advantage"),
                value_target=("agents", "value_target"))
    losses = {}
    for delay in (True, False):
        losses[delay] = MAPPOLoss(actor, critic, clip_epsilon=0.2, entropy_coeff=0.0,
                                  normalize_advantage=False, loss_critic_type="l2",
                                  delay_actor=delay)  # (True: proximal = the weights now)
        losses[delay].set_keys(**keys)
    ready = decouple(loss_batch(ro, adv), actor)  # at the same (proximal) weights
    with torch.no_grad():  # an update moves the actor away from the proximal policy
        for p in net.parameters():
            p.add_(0.3 * torch.randn_like(p))
    out = {True: losses[True](loss_batch(ro, adv)), False: losses[False](ready),
           "plain": losses[False](loss_batch(ro, adv))}
    assert float(out[True]["clip_fraction"]) > 0.05  # the clipping acts
    gap = out["plain"]["loss_objective"] - out[True]["loss_objective"]
    assert abs(float(gap.detach())) > 1e-3  # and the weights w matter
    for k in ("loss_objective", "kl_approx", "clip_fraction", "entropy"):
        torch.testing.assert_close(out[False][k], out[True][k], rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("algo", ["mappo", "ippo"])
def test_trainer_loss_matches_torchrl_functional_loss(core_env, algo):
    """The trainer's PPO loss (TorchRL's, built with ``functional=False``) gives the same
    loss terms and the same gradients as TorchRL's default functional loss over the same
    modules, on a batch where the clipping acts."""
    from netsense.rl.advantage import critic_values, estimate, loss_batch
    from netsense.rl.config import PPOConfig
    from netsense.rl.policy import actor_net, build_actor, critic_module
    from netsense.rl.ppo import ppo_loss
    from netsense.rl.rollout import Collector

    core, env = core_env
    torch.manual_seed(1)
    cfg = PPOConfig(SCEN, algo=algo, num_envs=3)
    net = actor_net(cfg, core, torch.device("cpu"))
    actor = build_actor(net, core.nvec)
    critic = critic_module(cfg, env, torch.device("cpu"))
    ro = Collector(env, net, 6, with_state="state" in critic.in_keys).collect()
    data = loss_batch(ro, estimate(critic_values(critic, ro), ro.reward, ro.done, 0.99, 0.95))
    with torch.no_grad():  # move the actor away from the behaviour policy: ratios clip
        for p in net.parameters():
            p.add_(0.3 * torch.randn_like(p))
    params = list(net.parameters()) + list(critic.parameters())
    out, grads = {}, {}
    for functional in (False, True):
        loss = ppo_loss(cfg, actor, critic, functional=functional)
        for p in params:
            p.grad = None
        out[functional] = loss(data.clone())
        (out[functional]["loss_objective"] + out[functional]["loss_critic"]
         + out[functional]["loss_entropy"]).backward()
        grads[functional] = [p.grad.clone() for p in params]
    assert not ppo_loss(cfg, actor, critic).functional
    assert float(out[False]["clip_fraction"]) > 0.05
    for k in ("loss_objective", "loss_critic", "loss_entropy", "kl_approx", "clip_fraction"):
        torch.testing.assert_close(out[False][k], out[True][k], rtol=0, atol=0)
    for a, b in zip(grads[False], grads[True], strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_decoupled_objective_is_ppo_on_the_first_rollout():
    """The first rollout comes from the initial parameters with or without the overlap,
    so proximal = behaviour there and the decoupled loss is PPO's: the first iteration's
    statistics agree to float rounding (float32 loss: the proximal log-probabilities come
    from the loss's own pass, the behaviour ones from the collector's)."""
    from netsense.rl.ppo import train_ppo

    a = train_ppo(_tiny(precision="fp32")).rows[0]
    b = train_ppo(_tiny(precision="fp32", overlap=False)).rows[0]
    assert a["step_reward"] == b["step_reward"]
    for k in ("loss_objective", "loss_critic", "entropy", "grad_norm"):
        assert a[k] == pytest.approx(b[k], rel=1e-4, abs=1e-7), k


def test_overlapped_training_is_reproducible_and_leaves_no_thread(tmp_path):
    """Two overlapped runs of one seed give the same statistics and weights, whatever
    the process draws from torch's global generator in between (the collector has its own
    generator; evaluations in the loop draw from theirs); no collection thread outlives
    a run."""
    import threading

    from netsense.rl.ppo import train_ppo

    cfg = _tiny(eval_interval=2, obs_norm=True)
    skip = ("wall_s", "agent_steps_per_s", "collect_s", "learn_s")
    runs = []
    for k in range(2):
        torch.rand(k + 1)  # the global generator in another state
        res = train_ppo(cfg, tmp_path / str(k))
        runs.append(([{c: v for c, v in r.items() if c not in skip} for r in res.rows],
                     torch.load(tmp_path / str(k) / "policy.pt", weights_only=True)["actor"]))
    assert runs[0][0] == runs[1][0]
    assert all(torch.equal(runs[0][1][name], runs[1][1][name]) for name in runs[0][1])
    assert not [t for t in threading.enumerate() if t.name.startswith("netsense-collect")]


def test_sync_gives_the_collector_the_parameters_and_the_learner_the_normaliser():
    """Between overlapped collections parameters go from learner to collector, and the
    observation normaliser's statistics (only collection updates them) the other way."""
    import copy

    from netsense.rl.policy import ObsNormActor
    from netsense.rl.rollout import sync

    torch.manual_seed(0)
    learner = ObsNormActor(torch.nn.Linear(3, 2), 3)
    collector = copy.deepcopy(learner)
    with torch.no_grad():
        learner.body.weight.add_(1.0)  # an update
    collector.update(torch.randn(50, 3) * 4 + 2)  # observations collected
    stats = [b.clone() for b in collector.buffers()]
    assert any(not torch.equal(a, b) for a, b in zip(learner.buffers(), stats, strict=True))
    sync(learner, collector)
    for a, b in zip(collector.parameters(), learner.parameters(), strict=True):
        assert torch.equal(a, b)
    for a, b in zip(learner.buffers(), stats, strict=True):
        assert torch.equal(a, b)


def test_collector_actions_do_not_depend_on_the_global_generator(core_env):
    """Sampled actions come from the collector's own generator (seeded by ``seed``)."""
    from netsense.rl.envs import NetSenseBatchedEnv, make_core
    from netsense.rl.rollout import Collector

    torch.manual_seed(0)
    core, _ = core_env
    net = torch.nn.Linear(core.layout.size, int(sum(core.nvec)))
    acts = []
    for glob, seed in ((1, 7), (2, 7), (1, 8)):
        env = NetSenseBatchedEnv(make_core(SCEN, 3, horizon=6), reward="team", seed=5)
        torch.manual_seed(glob)
        acts.append(Collector(env, net, 6, seed=seed).collect().action)
    assert torch.equal(acts[0], acts[1])  # another global state: the same actions
    assert not torch.equal(acts[0], acts[2])  # another seed: others


def test_stagger_spreads_the_episode_phases():
    from netsense.rl.envs import NetSenseBatchedEnv, make_core
    from netsense.rl.memory import RecurrentActor
    from netsense.rl.rollout import Collector

    core = make_core(SCEN, 64, horizon=20)
    env = NetSenseBatchedEnv(core, seed=3)
    net = RecurrentActor(core.layout.size, int(sum(core.nvec)), (8,), memory=4)
    col = Collector(env, net, 20, stagger=True, seed=1)
    k = core.k.copy()
    assert k.min() >= 0 and k.max() < 20
    # restarts on the grid of STAGGER_STEP = 8 steps, after warm-up step s in {0, 8}: the
    # member has run the 19 - s steps since
    assert set(np.unique(k)) == {19, 11}
    ro = col.collect()  # every member ends exactly once in 20 steps, at its own step
    assert (ro.done.sum(0) == 1).all()
    ends = ro.done.int().argmax(0).numpy()
    np.testing.assert_array_equal(ends, 19 - k)


def test_policy_file_of_a_recurrent_actor_acts_like_training(tmp_path):
    from netsense.rl.checkpoint import load_policy
    from netsense.rl.config import PPOConfig
    from netsense.rl.envs import NetSenseBatchedEnv, make_core
    from netsense.rl.ppo import train_ppo
    from netsense.rl.rollout import Collector

    cfg = PPOConfig(SCEN, reward="team", num_envs=4, rollout=4, steps=4 * 4 * 10 * 2,
                    epochs=1, minibatch=8, memory=8, eval_interval=0, eval_envs=2,
                    overrides={"horizon": 8})
    train_ppo(cfg, tmp_path)
    pol = load_policy(tmp_path / "policy.pt")
    # the policy file's actions over two episodes (the hidden state restarts with time 0)
    # equal the collector's most likely actions with the trained network
    core = make_core(SCEN, 2, horizon=8)
    env = NetSenseBatchedEnv(core, reward="team", seed=123)
    ro = Collector(env, pol.net, 8).collect(deterministic=True)
    core2 = make_core(SCEN, 2, horizon=8)
    for _episode in range(2):  # the second time, the hidden state must restart at time 0
        obs, mask = core2.reset([123, 124])
        for t in range(8):
            a = pol.act(obs, mask)
            np.testing.assert_array_equal(a, ro.action[t].numpy())
            out = core2.step(a)
            obs, mask = out.obs, out.action_mask
    assert torch.any(pol.hidden != 0)


# ------------------------------------------------------------------ the log
def test_log_has_no_nan_and_no_stale_rows(tmp_path):
    from netsense.rl.config import PPOConfig
    from netsense.rl.ppo import train_ppo

    cfg = PPOConfig(SCEN, reward="team", num_envs=4, rollout=5, steps=4 * 5 * 10 * 4,
                    epochs=1, minibatch=10, eval_interval=2, eval_envs=2, stagger=False,
                    overrides={"horizon": 8})
    res = train_ppo(cfg, tmp_path)
    with (tmp_path / "log.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 4
    for r in rows:
        for k, v in r.items():
            assert v.lower() not in ("nan", "inf", "-inf"), (k, v)
    # returns only in the iterations where episodes ended (horizon 8, 5 steps each: the
    # ends fall in iterations 1 and 3), never carried over
    ended = [bool(r["train_return"]) for r in rows]
    assert ended == [False, True, False, True]
    assert len({r["train_return"] for r in rows if r["train_return"]}) == 2
    assert (tmp_path / "training_curve.png").stat().st_size > 0
    assert res.mask_violations == 0


def test_evaluation_scores_the_scenario_reward_whatever_the_training_reward():
    # The periodic evaluation must read on the scripted policies' scale: a run trained on a
    # shaped reward (here the counterfactual sender credit) is scored with the scenario's
    # reward, which is also what the team reward's mean over agents is.
    from netsense.rl.config import PPOConfig
    from netsense.rl.envs import make_core
    from netsense.rl.evaluation import evaluate, evaluate_scripted
    from netsense.rl.policy import actor_net

    scen = SCEN
    torch.manual_seed(0)
    base = PPOConfig(scen, eval_envs=3, overrides={"horizon": 30})
    net = actor_net(base, make_core(scen, 1, horizon=30))
    got = {r: evaluate(net, PPOConfig(scen, reward=r, eval_envs=3,
                                       overrides={"horizon": 30}), deterministic=False)
           for r in ("scenario", "team", "agent", "counterfactual")}
    for r in ("team", "agent", "counterfactual"):
        assert got[r]["return"] == pytest.approx(got["scenario"]["return"], rel=1e-5), r
    scripted = {r: evaluate_scripted("event:1", PPOConfig(scen, reward=r, eval_envs=3,
                                                          overrides={"horizon": 30}))
                for r in ("scenario", "counterfactual")}
    assert scripted["counterfactual"]["return"] == pytest.approx(
        scripted["scenario"]["return"], rel=1e-5)


@pytest.mark.parametrize("spec", ["gated(sources:0)", "acked(sources:0)", "phased(event:2)"])
def test_training_evaluates_the_informed_rules_as_the_benchmark_does(spec):
    """The periodic evaluation's scripted reference (and the learning curves' line) takes
    every decentralised rule of the frontier, the wrapping ones included, and scores it as
    the benchmark's rollout does on the same seeds."""
    from netsense.benchmark.protocol import evaluate as protocol_evaluate
    from netsense.rl.config import PPOConfig
    from netsense.rl.evaluation import EVAL_SEED, evaluate_scripted

    task = {"gated": "comm_announced-v0", "acked": "comm_fading-v0",
            "phased": "comm_schedule-v0"}[spec.split("(")[0]]
    got = evaluate_scripted(spec, PPOConfig(task, eval_envs=3))
    want = protocol_evaluate(task, spec, [EVAL_SEED + b for b in range(3)])
    assert got["return"] == pytest.approx(float(want["reward"].mean()), rel=1e-5)
