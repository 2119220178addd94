"""Training pipeline, stage *training loop*: MAPPO and IPPO on the batched core (torch; on
demand).

One iteration::

    Collector.collect()                     T steps of B environments, lean: core arrays ->
      (netsense.rl.rollout)                 torch, one actor pass per step, masked sampling
    critic_values + estimate                one critic pass over all T + 1 states; TorchRL's
      (netsense.rl.advantage)               GAE; value targets standardised (value_norm)
    MAPPOLoss / IPPOLoss (TorchRL)          clipped surrogate, value and entropy terms on
                                            minibatches of env-steps (feed-forward actors) or
                                            of whole member sequences (recurrent actors)
    Adam, gradient clipping, schedules      learning rate and entropy coefficient per
                                            iteration (lr_decay, entropy_final)

Overlap (``PPOConfig.overlap``, the default): the collector runs in a second Python thread
with its own copy of the actor and collects the next rollout while the learner trains on
the current one, so an iteration takes about the longer of the two instead of their sum
(the core's compiled passes and torch's operations release the GIL). The rollout then
comes from the parameters before the last update (one update of lag), and the loss is the
decoupled objective for such data (Hilton et al. 2021, "Batch size-invariance for policy
optimization"; TorchRL's ``delay_actor``): the ratio is clipped around the parameters at
the start of the update (the proximal policy) and the surrogate is weighted by the
proximal over the behaviour probability of the action taken, through the batch
(:func:`netsense.rl.advantage.decouple`) and TorchRL's PPO loss. Between two collections
the collector takes the learner's parameters and the learner the collector's observation
statistics (:class:`netsense.rl.rollout.CollectAhead`). The collector draws from its own
generator, so a run is as reproducible as without the overlap.

No PPO arithmetic lives here: losses, advantages and value normalisers are TorchRL's.
Actor: :func:`netsense.rl.policy.actor_net` (MLP, recurrent MLP, set network) behind
TorchRL's ``ProbabilisticActor`` with
:class:`netsense.rl.distributions.MaskedMultiCategorical`; parameters shared by all agents.
Critic: ``mappo`` uses the global ``state`` (:func:`netsense.rl.envs.global_state`) with
each agent's observation (``critic="state"``) or TorchRL's
``MultiAgentMLP(centralised=True)`` over all observations (``critic="joint"``); ``ippo`` a
local critic ``V_i(o_i)``.

Optional behaviour-cloning warm start (:func:`netsense.rl.cloning.behaviour_clone`);
:meth:`PPOConfig.conservative` gives the small clip range and learning rate and the critic
warm-up (actor frozen) used after it.

Outputs per run (:func:`train_ppo`): ``log.csv`` (one row per iteration: agent-steps,
wall time and throughput, collection and learning seconds, the mean reward per agent-step
of the rollout and the returns of the episodes that ended in it, error and messages, the
three loss terms, entropy, approximate KL, clip fraction, gradient norm, the critic's
explained variance, the spread of values, targets and raw advantages, learning rate and
entropy coefficient; ``eval_*`` columns (most likely actions) and ``eval_sampled_*``
(sampled) at every evaluation; no row repeats an earlier iteration's figure),
``training_curve.png`` (returns vs agent-steps), TensorBoard events under ``tb/`` when
``tensorboard`` or ``tensorboardX`` is installed, ``checkpoint_<iter>.pt`` at every
evaluation and ``policy.pt`` at the end (:func:`netsense.rl.checkpoint.load_policy` reads
them), ``resume.pt`` at every checkpoint until the run finishes (what ``resume=True``
continues from, :mod:`netsense.rl.resume`), ``config.json``, ``summary.json`` and
``run.json`` (``running``, then ``finished`` as the last write;
:mod:`netsense.rl.run_folder`). Every file is written whole or not at all
(:mod:`netsense.rl.atomic`). The learner runs on CUDA when
``torch.cuda.is_available()`` (``device="auto"``); the core always runs on the CPU. The
loss runs in bfloat16 mixed precision on CPUs with native bfloat16 products
(``precision="auto"``, :func:`netsense.rl.config.learner_precision`).
"""

from __future__ import annotations

import copy
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from netsense.rl.advantage import critic_values, decouple, estimate, explained_variance, loss_batch
from netsense.rl.atomic import atomic_path, write_json
from netsense.rl.checkpoint import save_checkpoint
from netsense.rl.cloning import behaviour_clone
from netsense.rl.config import PPOConfig, device_of, learner_precision, loss_arithmetic
from netsense.rl.envs import NetSenseBatchedEnv, make_core
from netsense.rl.evaluation import evaluate, mask_violations
from netsense.rl.memory import is_recurrent
from netsense.rl.policy import actor_net, build_actor, critic_module
from netsense.rl.resume import (
    RESUME_FILE,
    numpy_rng_state,
    read_resume,
    set_numpy_rng_state,
)
from netsense.rl.rollout import CollectAhead, Collector
from netsense.rl.run_folder import FINISHED, RUNNING, mark, run_status
from netsense.rl.runlog import RunLog, plot_curve

__all__ = ["PPOResult", "ReturnScaler", "keep_freed_memory", "ppo_loss", "train_ppo"]


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


def _schedule(start: float, end: float | None, frac: float) -> float:
    return start if end is None else start + (end - start) * frac


def train_ppo(config: PPOConfig, out: str | Path | None = None, *, progress: bool = False,
              evaluate_every: bool = True, resume: bool = False) -> PPOResult:
    """Train one seed; see the module docstring for what is written into ``out``.

    ``out=None`` writes nothing (benchmarks). ``evaluate_every=False`` skips the periodic
    evaluations and checkpoints (benchmarks). ``resume=True`` continues the run in ``out``
    from its last checkpoint (:mod:`netsense.rl.resume`; the same ``config`` is required,
    else ``ValueError`` naming the fields that differ, before anything is written); a
    folder without a checkpoint yet is trained from the start. ``out`` is marked as a
    running, then a finished, run (:mod:`netsense.rl.run_folder`); every file is written
    whole (:mod:`netsense.rl.atomic`). Sets, for the process,
    ``torch.set_flush_denormal(True)`` (a forward and backward pass of a warm-started actor
    took 0.031 s instead of 0.040 s with it) and glibc's allocator to keep the blocks a
    training iteration frees (:func:`keep_freed_memory`).
    """
    from torchrl.modules import RunningValueNorm
    from tqdm.auto import tqdm

    device = device_of(config.device)
    precision = learner_precision(config.precision, device)
    torch.manual_seed(config.seed)
    # subnormal floats take a slow path on x86 CPUs; flushing them to zero changes
    # nothing above 1e-38
    torch.set_flush_denormal(True)
    keep_freed_memory()
    if config.torch_threads:
        torch.set_num_threads(int(config.torch_threads))
    if config.numba_threads:
        _numba_threads(config.numba_threads)
    out = None if out is None else Path(out)
    saved = _resume_state(config, out) if resume and out is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        mark(out, RUNNING, backend="torchrl", seed=config.seed)
        if saved is None:  # a fresh start: an older run's resume state is not this run's
            (out / RESUME_FILE).unlink(missing_ok=True)
        write_json(out / "config.json", asdict(config), default=list)
    core = make_core(config.scenario, config.num_envs, control=config.control,
                     **config.overrides)
    env = NetSenseBatchedEnv(core, reward=config.reward, seed=config.seed * config.num_envs)
    N, B, T = core.N, core.B, config.rollout
    net = actor_net(config, core, device)
    bc = (behaviour_clone(net, config, config.bc, device=device, progress=progress)
          if config.bc and saved is None else None)
    actor = build_actor(net, core.nvec).to(device)
    critic = critic_module(config, env, device).to(device)
    value_norm = RunningValueNorm(shape=1, device=device) if config.value_norm else None
    scaler = ReturnScaler(config.gamma) if config.reward_scale else None
    loss = ppo_loss(config, actor, critic)
    opt = torch.optim.Adam(loss.parameters(), lr=config.lr)
    # overlap: the collector acts with its own copy of the actor (parameters one update
    # behind the learner's), in a second thread while the learner trains
    collector = Collector(env, copy.deepcopy(net) if config.overlap else net, T,
                          device=device, with_state="state" in critic.in_keys,
                          update_obs_norm=config.obs_norm, stagger=config.stagger,
                          seed=config.seed)
    ahead = (CollectAhead(collector, net, initializer=_numba_threads,
                          initargs=(config.numba_threads,)) if config.overlap else None)
    sequences = is_recurrent(net)
    iters = max(1, -(-int(config.steps) // (B * T * N)))
    violations = agent_steps = start = 0
    collect_s = learn_s = before_s = 0.0
    if saved is not None:  # the learner, the collection and the generators as saved
        start = int(saved["iteration"])
        c = saved["counters"]
        violations, agent_steps = int(c["mask_violations"]), int(c["agent_steps"])
        collect_s, learn_s, before_s = c["collect_s"], c["learn_s"], c["wall_s"]
        bc = c.get("bc")
        _restore(saved, out / RESUME_FILE, net=net, critic=critic, opt=opt,
                 value_norm=value_norm, scaler=scaler, collector=collector)
    log = RunLog(out, resume_at=start if saved is not None else None) \
        if out is not None else None
    rows: list[dict] = list(log.kept) if log is not None else []
    t0 = time.perf_counter() - before_s
    bar = tqdm(total=iters * B * T * N, initial=start * B * T * N,
               desc=f"{config.algo} seed {config.seed}", unit="agent-step", unit_scale=True,
               disable=not progress)
    try:
        for it in range(start, iters):
            frac = it / iters
            lr = config.lr * (1.0 - frac) if config.lr_decay else config.lr
            for g in opt.param_groups:
                g["lr"] = lr
            ent = _schedule(config.entropy_coef, config.entropy_final, frac)
            loss.entropy_coeff.fill_(ent)
            last = it == iters - 1
            keep = out is not None and evaluate_every and (
                last or (config.eval_interval and (it + 1) % config.eval_interval == 0))
            # a checkpoint keeps the collection's state where the next rollout starts
            # (overlapped: now, before the collection ahead begins)
            ro, took = (ahead.next(more=it + 1 < iters, snapshot=keep and not last)
                        if ahead is not None else collector.timed_collect())
            t_collected = time.perf_counter()
            violations += mask_violations(ro.mask, ro.action, core.nvec)
            reward = scaler(ro.reward, ro.done) if scaler is not None else ro.reward
            adv = estimate(critic_values(critic, ro, value_norm), reward, ro.done,
                           config.gamma, config.lmbda)
            if value_norm is not None:
                value_norm.update(adv.target.reshape(-1, 1))
            data = loss_batch(ro, adv, value_norm, sequences=sequences)
            if config.overlap:  # the rollout is one update old: the decoupled objective
                data = decouple(data, actor, precision=precision)
            stats = _update(loss, opt, data, config, warm=it < config.critic_warmup,
                            sequences=sequences, T=T, precision=precision)
            t_learned = time.perf_counter()
            collect_s += took
            learn_s += t_learned - t_collected
            agent_steps += B * T * N
            bar.update(B * T * N)
            wall = time.perf_counter() - t0
            row = {"iteration": it, "agent_steps": agent_steps, "wall_s": round(wall, 3),
                   "agent_steps_per_s": round(agent_steps / wall, 1),
                   "collect_s": round(collect_s, 3), "learn_s": round(learn_s, 3),
                   "step_reward": float(ro.reward.mean()),
                   "train_error": float(ro.error.mean()), "train_messages": float(ro.sent.mean()),
                   **stats, "explained_variance": explained_variance(adv.value, adv.target),
                   "value_sd": float(adv.value.std()), "target_sd": float(adv.target.std()),
                   "advantage_mean": float(adv.advantage.mean()),
                   "advantage_sd": float(adv.advantage.std()),
                   "action_gap": action_gap(adv.advantage, ro.action, core.nvec),
                   "lr": lr, "entropy_coef": ent}
            if ro.returns:
                row["train_return"] = float(np.mean(ro.returns))
                row["train_episodes"] = len(ro.returns)
            if keep:
                # greedy and sampled: a learned randomised schedule (transmit with some
                # probability) collapses to all-or-nothing under the greedy action
                row.update({f"eval_{k}": v for k, v in evaluate(net, config).items()})
                row.update({f"eval_sampled_{k}": v for k, v in evaluate(
                    net, config, deterministic=False).items()})
            rows.append(row)
            if log is not None:
                log.add(row)
            if keep:  # after the log's row: a resumed run finds every row up to here
                save_checkpoint(out / f"checkpoint_{it + 1:05d}.pt", config, net, critic, it + 1,
                                agent_steps, core)
                if not last:
                    snap = ahead.snapshot if ahead is not None else (collector.state(), None)
                    _save_resume(out / RESUME_FILE, config, it + 1, snap, net=net,
                                 critic=critic, opt=opt, value_norm=value_norm, scaler=scaler,
                                 counters={"agent_steps": agent_steps,
                                           "mask_violations": violations,
                                           "collect_s": collect_s, "learn_s": learn_s,
                                           "wall_s": time.perf_counter() - t0,
                                           "bc": json.loads(json.dumps(bc, default=float))})
            bar.set_postfix(r=f"{row['step_reward']:.3g}", ev=f"{row['explained_variance']:.2f}")
    finally:  # an error in the learner leaves no collection running
        if ahead is not None:
            ahead.close()
    wall = time.perf_counter() - t0
    bar.close()
    if out is not None:
        save_checkpoint(out / "policy.pt", config, net, critic, iters, agent_steps, core)
        log.close()
        plot_curve(rows, out / "training_curve.png", f"{config.algo} on {config.scenario} "
                   f"(seed {config.seed})")
        meta = {"wall_s": round(wall, 2), "agent_steps": agent_steps,
                "agent_steps_per_s": round(agent_steps / wall, 1),
                "collect_s": round(collect_s, 2), "learn_s": round(learn_s, 2),
                "mask_violations": violations, "device": str(device),
                "precision": precision, "torch_threads": torch.get_num_threads(), "bc": bc}
        write_json(out / "summary.json", meta)
        mark(out, FINISHED, backend="torchrl", seed=config.seed)  # the last write
        (out / RESUME_FILE).unlink(missing_ok=True)  # a finished run is not resumed
    return PPOResult(out, rows, wall, agent_steps, violations, bc)


def _as_json(config: PPOConfig) -> dict:
    """``config`` as ``config.json`` holds it (tuples as lists)."""
    return json.loads(json.dumps(asdict(config), default=list))


def _resume_state(config: PPOConfig, out: Path) -> dict | None:
    """The resume state of the run in ``out`` (``None``: no checkpoint yet, train from
    the start), checked against ``config`` before anything is written."""
    if run_status(out) == FINISHED:
        raise ValueError(f"{out}: the run there has finished; there is nothing to resume "
                         "(--overwrite trains it again)")
    path = out / RESUME_FILE
    if not path.is_file():
        return None
    state = read_resume(path)
    now, then = _as_json(config), state["config"]
    if now != then:
        diff = sorted(k for k in set(now) | set(then) if now.get(k) != then.get(k))
        parts = [f"{k}: {then.get(k)!r} in the run, {now.get(k)!r} now" for k in diff[:5]]
        raise ValueError(f"{out}: --resume needs the configuration the run was started "
                         f"with; it differs in {'; '.join(parts)}")
    return state


def _save_resume(path: Path, config: PPOConfig, iteration: int, snapshot, *, net, critic,
                 opt, value_norm, scaler, counters: dict) -> None:
    """``resume.pt`` (:mod:`netsense.rl.resume`): the state a run continues from after
    ``iteration`` iterations. ``snapshot``: the collector's state and, overlapped, its
    actor's weights (``None``: the learner's)."""
    collector_state, collector_actor = snapshot
    cpu = {k: v.detach().cpu() for k, v in net.state_dict().items()}
    learner = {"actor": cpu, "critic": {k: v.detach().cpu()
                                        for k, v in critic.state_dict().items()},
               "optimizer": opt.state_dict(),
               "collector_actor": collector_actor if collector_actor is not None else cpu}
    if value_norm is not None:
        learner["value_norm"] = value_norm.state_dict()
    if scaler is not None:
        learner["scaler"] = {"stats": scaler.stats.state_dict(), "ret": scaler.ret}
    rng = {"torch": torch.get_rng_state(), "numpy": numpy_rng_state()}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        rng["cuda"] = torch.cuda.get_rng_state_all()
    state = {"format": "netsense-resume", "iteration": int(iteration),
             "config": _as_json(config), "learner": learner,
             "collector": torch.frombuffer(bytearray(collector_state), dtype=torch.uint8),
             "counters": counters, "rng": rng}
    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def _restore(state: dict, path: Path, *, net, critic, opt, value_norm, scaler,
             collector) -> None:
    """Load :func:`_save_resume`'s state into a freshly built run."""
    learner = state["learner"]
    try:
        net.load_state_dict(learner["actor"])
        critic.load_state_dict(learner["critic"])
        opt.load_state_dict(learner["optimizer"])
        if value_norm is not None:
            value_norm.load_state_dict(learner["value_norm"])
        if scaler is not None:
            scaler.stats.load_state_dict(learner["scaler"]["stats"])
            scaler.ret = learner["scaler"]["ret"]
        if collector.net is not net:
            collector.net.load_state_dict(learner["collector_actor"])
    except (KeyError, RuntimeError, ValueError) as exc:
        raise ValueError(f"{path}: the saved learner does not fit this run's networks "
                         f"({type(exc).__name__}: {exc})") from None
    collector.load_state(state["collector"].numpy().tobytes(), str(path))
    torch.set_rng_state(state["rng"]["torch"])
    set_numpy_rng_state(state["rng"]["numpy"])
    if "cuda" in state["rng"] and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["rng"]["cuda"])


def ppo_loss(config: PPOConfig, actor: torch.nn.Module, critic: torch.nn.Module,
             **kwargs: Any) -> torch.nn.Module:
    """TorchRL's PPO loss as the trainer uses it: ``MAPPOLoss`` (``IPPOLoss`` for
    ``algo="ippo"``) over the batch keys of :func:`netsense.rl.advantage.loss_batch`,
    without TorchRL's own advantage standardisation (the batch's advantages are
    standardised over the whole rollout).

    The loss is built with ``functional=False``: it calls ``actor`` and ``critic`` with
    their own parameters, where TorchRL's default copies them into a parameter
    TensorDict and swaps them into the modules on every forward pass (for meta-learning
    and ``delay_actor``, which the trainer does not use: its decoupled objective is
    :func:`netsense.rl.advantage.decouple`). The values and gradients are the same
    (``tests/test_rl_training.py``); a gradient step costs 0.24-0.38 ms less at small
    minibatches on the 2-core development machine (``experiments/bench/update_cost.py``).
    ``kwargs`` go to the loss (tests)."""
    from torchrl.objectives.multiagent import IPPOLoss, MAPPOLoss

    Loss = IPPOLoss if config.algo == "ippo" else MAPPOLoss  # noqa: N806
    kw = dict(clip_epsilon=config.clip, entropy_coeff=config.entropy_coef,
              critic_coeff=config.critic_coef, normalize_advantage=False,
              loss_critic_type="l2", functional=False)
    loss = Loss(actor, critic, **{**kw, **kwargs})
    loss.set_keys(action=("agents", "action"), sample_log_prob=("agents", "action_log_prob"),
                  value=("agents", "state_value"), advantage=("agents", "advantage"),
                  value_target=("agents", "value_target"))
    return loss


def _numba_threads(k: int | None) -> None:
    """numba's thread count for the calling Python thread (``None``: numba's default)."""
    if k:
        import numba

        numba.set_num_threads(min(int(k), numba.config.NUMBA_NUM_THREADS))


def keep_freed_memory() -> bool:
    """Make glibc's ``malloc`` keep the memory a training iteration frees, for the process.

    Every minibatch allocates and frees tensors of a few megabytes. glibc serves blocks
    above its mmap threshold (128 KiB at first, raised only after such a block is freed)
    with fresh ``mmap`` pages and gives them back on ``free``, so each allocation pays
    its page faults again, and the heap's top is trimmed back to the system. Setting
    ``M_MMAP_THRESHOLD`` to its largest value (32 MiB on 64-bit systems) and
    ``M_TRIM_THRESHOLD`` to 1 GiB with ``mallopt`` keeps them; before, a run trained faster
    in a process whose earlier runs had raised the threshold than in a fresh one
    (docs/performance.md). The process keeps up to its peak heap afterwards. Returns
    whether the settings were applied (False where the C library has no ``mallopt``: not
    Linux, or not glibc)."""
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    ok = mallopt(m_mmap_threshold, 32 * 2**20) == 1
    return mallopt(m_trim_threshold, 2**30) == 1 and ok


def action_gap(advantage: torch.Tensor, action: torch.Tensor, nvec) -> float:
    """Signal of the binary decisions in a rollout: the mean advantage of choice 1 minus
    that of choice 0, over the advantages' standard deviation, averaged over the action
    entries with two choices (the transmit and send bits). Near 0 with a large spread of
    advantages: the gradient of those bits is mostly noise."""
    sd = float(advantage.std())
    gaps = []
    for e, k in enumerate(nvec):
        if int(k) != 2:
            continue
        one = action[..., e] == 1
        if one.any() and (~one).any():
            gaps.append(float(advantage[one].mean() - advantage[~one].mean()) / max(sd, 1e-12))
    return float(np.mean(gaps)) if gaps else 0.0


_STATS = ("loss_objective", "loss_critic", "loss_entropy", "entropy", "kl_approx",
          "clip_fraction")


def _update(loss, opt, data, config: PPOConfig, *, warm: bool, sequences: bool,
            T: int, precision: str = "fp32") -> dict:
    """``config.epochs`` passes of minibatch updates over ``data``; mean loss statistics.

    ``precision="bf16"``: the loss's forward pass under ``torch.autocast`` with bfloat16
    (torch's mixed precision: the layers' matrix products in bfloat16; the masked
    distribution, which casts the logits up, and the loss terms in float32; the backward
    pass follows the forward's types), the optimiser on the float32 parameters
    (:attr:`PPOConfig.precision`)."""
    rows = data.shape[0]
    # minibatch in env-steps; recurrent: whole sequences of T steps per member
    mb = max(1, min(rows, config.minibatch // T if sequences else config.minibatch))
    sums = dict.fromkeys((*_STATS, "grad_norm"), 0.0)
    n = 0
    params = list(loss.parameters())
    # the batch's tensors' device (a TensorDict built without one has device None)
    device = data["agents", "action"].device
    for _ in range(config.epochs):
        perm = torch.randperm(rows, device=device)
        for s in range(0, rows - mb + 1, mb):
            with loss_arithmetic(device, precision):
                lv = loss(_gather(data, perm[s:s + mb]))
            total = lv["loss_critic"] if warm else (
                lv["loss_objective"] + lv["loss_critic"] + lv["loss_entropy"])
            opt.zero_grad(set_to_none=True)
            total.backward()
            sums["grad_norm"] += float(torch.nn.utils.clip_grad_norm_(params,
                                                                      config.max_grad_norm))
            opt.step()
            for k in _STATS:
                if k in lv.keys():
                    sums[k] += float(lv[k].detach())
            n += 1
    out = {k: v / max(n, 1) for k, v in sums.items()}
    out["gradient_steps"] = n
    if not all(np.isfinite(list(out.values()))):
        raise FloatingPointError(f"non-finite PPO statistics: {out}")
    return out


def _gather(data, idx: torch.Tensor):
    """The minibatch ``data[idx]``: the rows ``idx`` of every entry, nested batch sizes
    kept, the same values as TensorDict's indexing.

    Each entry is gathered as a 2-D ``index_select`` of its rows: TensorDict's ``data[idx]``
    runs torch's general advanced indexing on every entry, which copied the rows of the
    (rows, N, O) observations several times slower on the 2-core development machine.
    """
    from tensordict import TensorDict, is_tensor_collection

    k = int(idx.shape[0])

    def rows(x: torch.Tensor) -> torch.Tensor:
        return x.reshape(x.shape[0], -1).index_select(0, idx).reshape(k, *x.shape[1:])

    def nested(td):
        return TensorDict({key: nested(v) if is_tensor_collection(v) else rows(v)
                           for key, v in td.items()},
                          batch_size=(k, *td.batch_size[1:]), device=td.device)

    return nested(data)


class ReturnScaler:
    """``reward_scale``: rewards divided by the running standard deviation of the
    discounted return ``R <- gamma R + r`` (per member and agent, reset at episode ends;
    TorchRL's ``RunningValueNorm`` keeps the statistics), as in the PPO implementation
    studied by Engstrom et al. (ICLR 2020)."""

    def __init__(self, gamma: float) -> None:
        from torchrl.modules import RunningValueNorm

        self.gamma = float(gamma)
        self.stats = RunningValueNorm(shape=1)
        self.ret: torch.Tensor | None = None

    def __call__(self, reward: torch.Tensor, done: torch.Tensor) -> torch.Tensor:
        """``reward (T, B, N)``, ``done (T, B)`` -> scaled rewards (same shape)."""
        if self.ret is None:
            self.ret = torch.zeros_like(reward[0])
        for t in range(reward.shape[0]):
            self.ret = self.gamma * self.ret + reward[t]
            self.stats.update(self.ret.reshape(-1, 1).cpu())
            self.ret[done[t]] = 0.0
        return reward / float(self.stats.scale())
