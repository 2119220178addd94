"""Training pipeline, stage *training loop*: the PPO loop (MAPPO and IPPO on the batched
core, built from TorchRL components; torch, on demand).

Pipeline (no PPO arithmetic here: loss, advantages and collection are TorchRL's)::

    make_core(scenario, B, control)            BatchedCore (or another control mode)
      -> NetSenseBatchedEnv(core, reward)      TorchRL EnvBase, batch [B], group "agents"
      -> Collector(env, actor, B * T frames)   T steps of B environments per iteration
      -> GAE (torchrl.objectives.value)        per-agent advantages (done expanded to agents)
      -> ClipPPOLoss(actor, critic)            clipped surrogate + value + entropy terms
      -> Adam, minibatches of env-steps, gradient clipping

Actor: :func:`netsense.rl.networks.mlp_actor_net` or
:class:`netsense.rl.set_network.SetPolicyNet` behind TorchRL's ``ProbabilisticActor`` with
:class:`netsense.rl.distributions.MaskedMultiCategorical` reading
``("agents", "action_mask")``; parameters shared by all agents. Critic: ``mappo`` uses the
global ``state`` (:func:`netsense.rl.envs.global_state`) with each agent's observation
(``critic="state"``) or TorchRL's ``MultiAgentMLP(centralised=True)`` over all
observations (``critic="joint"``); ``ippo`` a local critic ``V_i(o_i)``.

Optional behaviour-cloning warm start (:func:`behaviour_clone`): cross-entropy of the
masked distribution on a scripted policy's actions collected through the batched core,
then PPO fine-tuning; :meth:`PPOConfig.conservative` gives the small clip range and
learning rate and the critic warm-up (actor frozen) used for that.

Outputs per run (:func:`train_ppo`): ``log.csv`` (one row per iteration: agent-steps,
wall time, throughput, training return, error, messages, losses, entropy, evaluation
columns when evaluated: ``eval_*`` with the most likely actions, ``eval_sampled_*`` with
sampled ones), TensorBoard events under ``tb/`` when ``tensorboard`` or
``tensorboardX`` is installed, ``checkpoint_<iter>.pt`` at every evaluation and
``policy.pt`` at the end (:func:`load_policy` reads them), ``config.json``. The learner
runs on CUDA when ``torch.cuda.is_available()`` (``device="auto"``); the core always
runs on the CPU.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from netsense.rl.checkpoint import save_checkpoint
from netsense.rl.cloning import behaviour_clone
from netsense.rl.config import PPOConfig, device_of
from netsense.rl.envs import NetSenseBatchedEnv, make_core
from netsense.rl.evaluation import evaluate, mask_violations
from netsense.rl.policy import actor_net, build_actor, critic_module
from netsense.rl.runlog import RunLog

__all__ = ["PPOResult", "train_ppo"]


@dataclass
class PPOResult:
    """What :func:`train_ppo` produced (paths and per-iteration rows)."""

    out: Path
    rows: list[dict]
    wall_s: float
    agent_steps: int
    mask_violations: int
    bc: dict | None = None

    @property
    def agent_steps_per_s(self) -> float:
        return self.agent_steps / max(self.wall_s, 1e-9)


def train_ppo(config: PPOConfig, out: str | Path | None = None, *, progress: bool = False,
              evaluate_every: bool = True) -> PPOResult:
    """Train one seed; see the module docstring for what is written into ``out``.

    ``out=None`` writes nothing (benchmarks). ``evaluate_every=False`` skips the periodic
    evaluations and checkpoints (benchmarks). Sets ``torch.set_flush_denormal(True)`` for
    the process (a forward and backward pass of a warm-started actor took 0.031 s instead
    of 0.040 s with it).
    """
    from torchrl.collectors import Collector
    from torchrl.objectives import ClipPPOLoss, ValueEstimators
    from tqdm.auto import tqdm

    device = device_of(config.device)
    torch.manual_seed(config.seed)
    # subnormal floats take a slow path on x86 CPUs; flushing them to zero changes
    # nothing above 1e-38
    torch.set_flush_denormal(True)
    if config.torch_threads:
        torch.set_num_threads(int(config.torch_threads))
    if config.numba_threads:
        import numba

        numba.set_num_threads(min(int(config.numba_threads), numba.config.NUMBA_NUM_THREADS))
    out = None if out is None else Path(out)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "config.json").write_text(json.dumps(asdict(config), indent=2, default=list)
                                         + "\n")
    core = make_core(config.scenario, config.num_envs, control=config.control,
                     **config.overrides)
    env = NetSenseBatchedEnv(core, reward=config.reward, seed=config.seed * config.num_envs)
    N, B, T = core.N, core.B, config.rollout
    net = actor_net(config, core, device)
    bc = None
    if config.bc:
        bc = behaviour_clone(net, config, config.bc, device=device, progress=progress)
    actor = build_actor(net, core.nvec).to(device)
    critic = critic_module(config, env, device).to(device)
    loss = ClipPPOLoss(actor, critic, clip_epsilon=config.clip,
                       entropy_coeff=config.entropy_coef, critic_coeff=config.critic_coef,
                       normalize_advantage=True, normalize_advantage_exclude_dims=(-2,),
                       loss_critic_type="smooth_l1")
    loss.set_keys(reward=("agents", "reward"), action=("agents", "action"),
                  sample_log_prob=("agents", "action_log_prob"),
                  value=("agents", "state_value"), done=("agents", "done"),
                  terminated=("agents", "terminated"))
    loss.make_value_estimator(ValueEstimators.GAE, gamma=config.gamma, lmbda=config.lmbda)
    opt = torch.optim.Adam(loss.parameters(), lr=config.lr)
    frames = B * T
    iters = max(1, -(-int(config.steps) // (frames * N)))
    collector = Collector(env, actor, frames_per_batch=frames, total_frames=frames * iters,
                          env_device="cpu", policy_device=device, storing_device=device,
                          auto_register_policy_transforms=False)
    log = RunLog(out) if out is not None else None
    acc = torch.zeros(B, N, device=device)
    returns: list[float] = []
    violations = 0
    agent_steps = 0
    t0 = time.perf_counter()
    bar = tqdm(total=frames * iters * N, desc=f"{config.algo} seed {config.seed}",
               unit="agent-step", disable=not progress)
    rows: list[dict] = []
    t_learned = t0
    collect_s = learn_s = 0.0
    for it, data in enumerate(collector):
        t_collected = time.perf_counter()
        collect_s += t_collected - t_learned
        violations += mask_violations(data, core.nvec)
        nxt = data["next"]
        for key in ("done", "terminated"):
            nxt.set(("agents", key), nxt[key].unsqueeze(-2).expand(B, T, N, 1))
        r = nxt["agents", "reward"][..., 0]
        done = nxt["done"][..., 0]
        for t in range(T):  # training episode returns (mean over agents)
            acc += r[:, t]
            d = done[:, t]
            if d.any():
                returns += acc[d].mean(-1).tolist()
                acc[d] = 0.0
        with torch.no_grad():
            loss.value_estimator(data, params=loss.critic_network_params,
                                 target_params=loss.target_critic_network_params)
        # only what the loss reads (observations, masks, state, actions, log-probs,
        # advantages, targets): gathering minibatches of the whole rollout costs more
        flat = data.exclude("next", ("agents", "logits")).reshape(-1)
        warm = it < config.critic_warmup
        sums = {"loss_objective": 0.0, "loss_critic": 0.0, "loss_entropy": 0.0, "entropy": 0.0}
        n_mb = 0
        mb = min(config.minibatch, flat.shape[0])
        for _ in range(config.epochs):
            perm = torch.randperm(flat.shape[0], device=device)
            for s in range(0, flat.shape[0] - mb + 1, mb):
                lv = loss(flat[perm[s:s + mb]])
                total = lv["loss_critic"] if warm else (
                    lv["loss_objective"] + lv["loss_critic"] + lv["loss_entropy"])
                opt.zero_grad()
                total.backward()
                torch.nn.utils.clip_grad_norm_(loss.parameters(), config.max_grad_norm)
                opt.step()
                for k in sums:
                    sums[k] += float(lv[k].detach())
                n_mb += 1
        collector.update_policy_weights_()
        t_learned = time.perf_counter()
        learn_s += t_learned - t_collected
        agent_steps += frames * N
        bar.update(frames * N)
        wall = time.perf_counter() - t0
        row = {"iteration": it, "agent_steps": agent_steps, "wall_s": round(wall, 3),
               "agent_steps_per_s": round(agent_steps / wall, 1),
               "collect_s": round(collect_s, 3), "learn_s": round(learn_s, 3),
               "train_return": float(np.mean(returns[-64:])) if returns else float("nan"),
               "train_error": float(nxt["agents", "error"].mean()),
               "train_messages": float(nxt["agents", "sent"].mean()),
               **{k: v / max(n_mb, 1) for k, v in sums.items()}}
        if not all(np.isfinite([row[k] for k in sums])):
            raise FloatingPointError(f"non-finite PPO loss at iteration {it}: {row}")
        last = it == iters - 1
        if out is not None and evaluate_every and (
                last or (config.eval_interval and (it + 1) % config.eval_interval == 0)):
            # greedy and sampled: a learned randomised schedule (transmit with some
            # probability) collapses to all-or-nothing under the greedy action
            ev = evaluate(actor, config)
            row.update({f"eval_{k}": v for k, v in ev.items()})
            ev = evaluate(actor, config, deterministic=False)
            row.update({f"eval_sampled_{k}": v for k, v in ev.items()})
            save_checkpoint(out / f"checkpoint_{it + 1:05d}.pt", config, net, critic, it + 1,
                        agent_steps, core)
        rows.append(row)
        if log is not None:
            log.add(row)
        bar.set_postfix(ret=f"{row['train_return']:.3g}")
    wall = time.perf_counter() - t0
    bar.close()
    collector.shutdown()
    if out is not None:
        save_checkpoint(out / "policy.pt", config, net, critic, iters, agent_steps, core)
        log.close()
        meta = {"wall_s": round(wall, 2), "agent_steps": agent_steps,
                "agent_steps_per_s": round(agent_steps / wall, 1),
                "mask_violations": violations, "device": str(device), "bc": bc}
        (out / "summary.json").write_text(json.dumps(meta, indent=2) + "\n")
    return PPOResult(out, rows, wall, agent_steps, violations, bc)
