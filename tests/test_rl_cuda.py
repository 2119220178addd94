"""The learner on CUDA (skipped without a GPU): a run trains with the learner on the GPU
and the core on the CPU, its policy file loads and acts on a CPU-only process, and the
networks give the same outputs on both devices."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")
pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")

SCEN = "comm_process_noise-v0"


@pytest.mark.parametrize("memory", [0, 16])
def test_training_on_cuda_and_acting_on_cpu(tmp_path, memory):
    from netsense.rl.checkpoint import load_policy
    from netsense.rl.config import PPOConfig
    from netsense.rl.envs import make_core
    from netsense.rl.ppo import train_ppo

    cfg = PPOConfig(SCEN, num_envs=8, rollout=8, steps=8 * 8 * 10 * 3, epochs=2, minibatch=16,
                    memory=memory, device="cuda", eval_interval=2, eval_envs=4,
                    overrides={"horizon": 16})
    res = train_ppo(cfg, tmp_path)
    assert res.mask_violations == 0
    assert all(np.isfinite(r["loss_critic"]) for r in res.rows)
    assert (tmp_path / "summary.json").read_text().count('"cuda') == 1
    pol = load_policy(tmp_path / "policy.pt")  # maps the CUDA weights to the CPU
    core = make_core(SCEN, 2, horizon=16)
    obs, mask = core.reset(5)
    a = pol.act(obs, mask)
    assert a.shape == (2, core.N, len(core.nvec))


def test_networks_agree_on_both_devices():
    from netsense.rl.config import PPOConfig
    from netsense.rl.envs import NetSenseBatchedEnv, make_core
    from netsense.rl.policy import actor_net, critic_module

    core = make_core(SCEN, 4)
    env = NetSenseBatchedEnv(core, seed=0)
    obs, _ = env.restart()
    torch.manual_seed(0)
    cfg = PPOConfig(SCEN)
    net = actor_net(cfg, core, torch.device("cpu"))
    critic = critic_module(cfg, env, torch.device("cpu"))
    from netsense.rl.envs import global_state

    o = torch.as_tensor(obs)
    s = torch.as_tensor(global_state(core))
    with torch.no_grad():
        cpu = (net(o), critic.module(s))
        net.cuda()
        critic.cuda()
        gpu = (net(o.cuda()).cpu(), critic.module(s.cuda()).cpu())
    for a, b in zip(cpu, gpu, strict=True):
        torch.testing.assert_close(a, b, atol=1e-4, rtol=1e-4)
