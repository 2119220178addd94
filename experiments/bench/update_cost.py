"""What a PPO gradient step costs against its minibatch size: why the command line's defaults
(minibatches of 2048 env-steps) learn slower per agent-step than the large minibatches of the
throughput benchmark's fastest grid point.

Two measurements, each in ``--rounds`` interleaved rounds (medians reported), at one torch
thread and at torch's own thread count (the TorchRL default), on the communication-only
scenario (``--scenario``, default ``comm_process_noise-v0``, N = 10):

1. **Per grid point, collection and learning apart.** For each ``num_envs:minibatch`` of
   ``--grid``, :func:`netsense.rl.ppo.train_ppo` with the :class:`netsense.rl.config.PPOConfig`
   defaults otherwise, for ``--iters`` iterations with collection and learning one after the
   other (``overlap=False``, so that neither slows the other), and reports the seconds of
   collection and of learning per million agent-steps (iterations after the first).
2. **One rollout, the update alone.** On one rollout of ``--envs`` members (the defaults'
   actor and critic at their initial parameters, the loss batch the trainer builds), the
   trainer's update (:func:`netsense.rl.ppo._update`, one epoch; at most ``--max-steps``
   gradient steps on the first rows of a fixed shuffle) at each minibatch size of
   ``--sizes``, with the trainer's loss (:func:`netsense.rl.ppo.ppo_loss`, TorchRL's
   ``MAPPOLoss`` with ``functional=False``) and with TorchRL's default functional loss. The
   step at the smallest size (next to no arithmetic) estimates the per-step overhead:
   Python, TensorDict, autograd and optimiser, which a step pays whatever its rows.

The loss runs at the defaults' precision (``precision="auto"``: bfloat16 mixed precision on
CPUs with native bfloat16 products). Writes ``update_cost.csv`` (one row per measurement),
``update_cost.txt`` and ``update_cost.png`` into ``--out``::

    python experiments/bench/update_cost.py             # about 3 minutes
    python experiments/bench/update_cost.py --grid 8:16 --iters 2 --rounds 1 --envs 8 \\
        --sizes 4 16 --out /tmp/x                         # smoke size
"""

# %%
from __future__ import annotations

import argparse
import copy
import csv
import statistics
import time
from dataclasses import replace
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1] / "results" / "bench" / "update_cost"


def _grid(text: str) -> list[tuple[int, int]]:
    try:
        pts = [tuple(int(v) for v in item.split(":")) for item in text.split(",") if item]
    except ValueError:
        pts = []
    if not pts or any(len(p) != 2 or min(p) < 1 for p in pts):
        raise argparse.ArgumentTypeError(
            f"--grid: comma-separated num_envs:minibatch pairs of positive integers, got "
            f"{text!r}")
    return pts


def main(argv: list[str] | None = None) -> Path:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="comm_process_noise-v0")
    p.add_argument("--grid", type=_grid, default=_grid("256:2048,512:4096,1024:16384"),
                   help="num_envs:minibatch points of the end-to-end measurement "
                        "(minibatch in env-steps)")
    p.add_argument("--iters", type=int, default=4,
                   help="training iterations per end-to-end measurement (the first is "
                        "not counted)")
    p.add_argument("--envs", type=int, default=2048,
                   help="members of the rollout the update alone is timed on")
    p.add_argument("--sizes", type=int, nargs="+", default=[16, 256, 2048, 16384],
                   help="minibatch sizes (env-steps) of the update alone")
    p.add_argument("--max-steps", type=int, default=64,
                   help="gradient steps per timing of the update alone, at most")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--out", default=str(RESULTS))
    args = p.parse_args(argv)
    if min(args.iters, args.rounds, args.envs, args.max_steps, *args.sizes) < 1 \
            or args.iters < 2:
        p.error("--iters must be at least 2, and --rounds, --envs, --max-steps and --sizes "
                "positive")
    import torch

    from netsense.rl.envs import make_core

    N = make_core(args.scenario, 1).N
    own = torch.get_num_threads()
    threads = sorted({1, own})
    rows: list[dict] = []
    try:
        rows += _end_to_end(args, threads, N)
        rows += _update_alone(args, threads)
    finally:
        torch.set_num_threads(own)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "update_cost.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
        w.writeheader()
        w.writerows(rows)
    lines = _report(rows, args, threads, own, N)
    (out / "update_cost.txt").write_text("\n".join(lines) + "\n")
    _plot(rows, threads, out / "update_cost.png", args.scenario)
    print("\n".join(lines))
    return out / "update_cost.txt"


def _end_to_end(args, threads: list[int], N: int) -> list[dict]:
    """Measurement 1: collection and learning seconds per million agent-steps per grid
    point and thread count, serial loop (``N`` agents)."""
    from netsense.rl.config import PPOConfig
    from netsense.rl.ppo import train_ppo

    base = PPOConfig(args.scenario, overlap=False)

    def cfg(B: int, mb: int, th: int, iters: int):
        return replace(base, num_envs=B, minibatch=mb, torch_threads=th,
                       steps=B * base.rollout * N * iters)

    for B, mb in args.grid:  # warm-up: compilation, allocation
        train_ppo(cfg(B, mb, threads[-1], 1), None, evaluate_every=False)
    rows = []
    for r in range(args.rounds):
        for B, mb in args.grid:
            for th in threads:  # each run sets its torch threads (torch_threads=th)
                res = train_ppo(cfg(B, mb, th, args.iters), None, evaluate_every=False)
                first, last = res.rows[0], res.rows[-1]
                steps = last["agent_steps"] - first["agent_steps"]
                rows.append({"measure": "end_to_end", "round": r, "threads": th,
                             "num_envs": B, "minibatch": mb, "agent_steps": steps,
                             "collect_s_per_m": (last["collect_s"] - first["collect_s"])
                             / steps * 1e6,
                             "learn_s_per_m": (last["learn_s"] - first["learn_s"])
                             / steps * 1e6,
                             "gradient_steps_per_m": last["gradient_steps"]
                             / (B * base.rollout * N) * 1e6})
                print(f"round {r} {B}:{mb} threads {th}: learning "
                      f"{rows[-1]['learn_s_per_m']:.2f} s per 1M agent-steps", flush=True)
    return rows


def _update_alone(args, threads: list[int]) -> list[dict]:
    """Measurement 2: seconds per gradient step of the update on one rollout, per minibatch
    size, thread count and loss (the trainer's, TorchRL's functional one)."""
    import torch

    from netsense.rl.advantage import critic_values, estimate, loss_batch
    from netsense.rl.config import PPOConfig, device_of, learner_precision
    from netsense.rl.envs import NetSenseBatchedEnv, make_core
    from netsense.rl.policy import actor_net, build_actor, critic_module
    from netsense.rl.ppo import _update, ppo_loss
    from netsense.rl.rollout import Collector

    torch.manual_seed(0)
    cfg = PPOConfig(args.scenario, num_envs=args.envs, epochs=1)
    device = device_of("cpu")
    precision = learner_precision(cfg.precision, device)
    core = make_core(args.scenario, args.envs)
    env = NetSenseBatchedEnv(core, reward=cfg.reward, seed=0)
    net = actor_net(cfg, core, device)
    actor = build_actor(net, core.nvec)
    critic = critic_module(cfg, env, device)
    ro = Collector(env, net, cfg.rollout, with_state="state" in critic.in_keys).collect()
    full = loss_batch(ro, estimate(critic_values(critic, ro), ro.reward, ro.done, cfg.gamma,
                                   cfg.lmbda))
    full = full[torch.randperm(full.shape[0])]  # one fixed shuffle: the first rows of it
    losses = {}
    for functional in (False, True):
        # each loss trains its own copy of the networks, so that both see the same start
        a, c = (build_actor(copy.deepcopy(net), core.nvec), copy.deepcopy(critic)) \
            if functional \
            else (actor, critic)
        loss = ppo_loss(cfg, a, c, functional=functional)
        losses[functional] = (loss, torch.optim.Adam(loss.parameters(), lr=cfg.lr))
    start = {f: [p.detach().clone() for p in loss.parameters()]
             for f, (loss, _) in losses.items()}
    rows = []
    for r in range(args.rounds):
        for mb in args.sizes:
            data = full[:min(full.shape[0], mb * args.max_steps)]
            one = replace(cfg, minibatch=mb)
            for th in threads:
                torch.set_num_threads(th)
                for functional, (loss, opt) in losses.items():
                    _update(loss, opt, data, one, warm=False, sequences=False, T=cfg.rollout,
                            precision=precision)  # warm: allocation at this size
                    t0 = time.perf_counter()
                    stats = _update(loss, opt, data, one, warm=False, sequences=False,
                                    T=cfg.rollout, precision=precision)
                    dt = time.perf_counter() - t0
                    with torch.no_grad():  # back to the start: every timing at one point
                        for p_, s in zip(loss.parameters(), start[functional], strict=True):
                            p_.copy_(s)
                    n = stats["gradient_steps"]
                    rows.append({"measure": "update", "round": r, "threads": th,
                                 "minibatch": mb, "loss": "functional" if functional
                                 else "trainer", "gradient_steps": n,
                                 "s_per_step": dt / n,
                                 "s_per_m_agent_steps": dt / (n * mb * core.N) * 1e6})
    return rows


def _median(rows: list[dict], key: str, **where) -> float:
    """Median of ``key`` over the rows whose fields equal ``where``'s values."""
    return statistics.median(r[key] for r in rows
                             if all(r[k] == v for k, v in where.items()))


def _report(rows: list[dict], args, threads: list[int], own: int, N: int) -> list[str]:
    import os
    import platform

    import torch

    e2e = [r for r in rows if r["measure"] == "end_to_end"]
    upd = [r for r in rows if r["measure"] == "update"]
    lines = [f"# {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {platform.node()}, "
             f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the end, "
             f"torch {torch.__version__} with {own} threads by default",
             f"# {args.scenario}, PPOConfig defaults otherwise; {args.rounds} interleaved "
             f"rounds, medians",
             f"# 1. serial loop (overlap=False), {args.iters} iterations per measurement "
             f"(the first not counted): seconds per million agent-steps",
             "num_envs:minibatch  threads  collection  learning  gradient steps per 1M"]
    med = {}
    for B, mb in args.grid:
        for th in threads:
            at = {"num_envs": B, "minibatch": mb, "threads": th}
            c = _median(e2e, "collect_s_per_m", **at)
            ln = med[B, mb, th] = _median(e2e, "learn_s_per_m", **at)
            steps = _median(e2e, "gradient_steps_per_m", **at)  # the same in every round
            lines.append(f"{f'{B}:{mb}':<19} {th:>7}  {c:>10.2f}  {ln:>8.2f}  "
                         f"{steps:>10.0f}")
    big = args.grid[-1]
    for th in threads:
        lines.append(f"# learning per agent-step at threads {th}, against {big[0]}:{big[1]}: "
                     + ", ".join(f"{B}:{mb} {med[B, mb, th] / med[(*big, th)]:.2f}x"
                                 for B, mb in args.grid))
    for B, mb in args.grid:
        if own > 1:
            lines.append(f"# {B}:{mb}: learning speed at torch's {own} threads over one "
                         f"thread: {med[B, mb, 1] / med[B, mb, own]:.2f}x")
    lines += [f"# 2. the update alone on one rollout of {args.envs} members (one epoch, at "
              f"most {args.max_steps} gradient steps): milliseconds per gradient step, and "
              f"the trainer's seconds per million agent-steps (one epoch)",
              "minibatch  threads  trainer's loss  TorchRL functional  "
              "trainer's s per 1M agent-steps"]
    sizes = sorted({r["minibatch"] for r in upd})
    for mb in sizes:
        for th in threads:
            m = {loss: _median(upd, "s_per_step", minibatch=mb, threads=th, loss=loss)
                 for loss in ("trainer", "functional")}
            per_m = _median(upd, "s_per_m_agent_steps", minibatch=mb, threads=th,
                            loss="trainer")
            lines.append(f"{mb:>9}  {th:>7}  {m['trainer'] * 1e3:>14.2f}  "
                         f"{m['functional'] * 1e3:>18.2f}  {per_m:>10.2f}")
    for th in threads:
        step = {mb: _median(upd, "s_per_step", minibatch=mb, threads=th, loss="trainer")
                for mb in sizes}
        fixed = step[sizes[0]]
        share = ", ".join(f"{mb}: {fixed / step[mb]:.0%}" for mb in sizes)
        lines.append(f"# threads {th}: a gradient step on {sizes[0]} env-steps "
                     f"({sizes[0] * N} agent rows, next to no arithmetic) takes "
                     f"{fixed * 1e3:.2f} ms, the per-step overhead (Python, TensorDict, "
                     f"autograd, optimiser); its share of a step by minibatch: {share}")
    return lines


def _plot(rows: list[dict], threads: list[int], path: Path, scenario: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    upd = [r for r in rows if r["measure"] == "update" and r["loss"] == "trainer"]
    sizes = sorted({r["minibatch"] for r in upd})
    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    for th in threads:
        ax.plot(sizes, [_median(upd, "s_per_m_agent_steps", minibatch=m, threads=th)
                        for m in sizes], "o-", label=f"{th} torch thread{'s' * (th > 1)}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("minibatch (env-steps)")
    ax.set_ylabel("update seconds per 1M agent-steps\n(one epoch)")
    ax.set_title(f"the PPO update's cost per agent-step, {scenario}", fontsize=9)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
