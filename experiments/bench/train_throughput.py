"""End-to-end training throughput (collection + learning), batched TorchRL path vs SB3.

Agent-steps of experience per second of training wall time, for

==================  ==========================================================================
path                what runs
==================  ==========================================================================
``torchrl-tx``      MAPPO (state critic, MLP actor) in the communication-only control mode
                    ``"transmit"`` (freshness fusion adopts, the agent decides the transmit
                    bit; :mod:`netsense.engine.control`)
``torchrl-full``    MAPPO (state critic, MLP actor) in full control
``torchrl-set``     the same with the set network (:class:`netsense.rl.set_network.SetPolicyNet`)
``sb3-batched``     MaskablePPO on :func:`netsense.env.vector.make_sb3_vec_env` (full control)
``sb3-supersuit``   MaskablePPO through SuperSuit (:func:`netsense.rl.sb3.train`, full control,
                    the default ``netsense train`` path)
``sb3-supersuit-tx``  the same on the communication-only scenario
==================  ==========================================================================

The ``-tx`` paths run ``--comm-scenario`` (default ``comm_process_noise-v0``: N = 10,
transmit bit only), the others ``--scenario`` (default ``message_cost-v1``: N = 10, full
control). Every path is measured in ``--rounds`` interleaved rounds
(every path once per round, in turn, so that load from other processes on a shared machine
falls on all paths alike); each path is warmed up once (numba compilation, torch
initialisation) before the first round. The wall time is that of the learning loop
(collection and updates; building the environment and the networks is outside it); the
TorchRL rows also split it into collection (env + policy inference) and learning. Learner
threads: one torch thread and one numba thread for every path (``PPOConfig`` defaults; the
SB3 trainer sets one torch thread too). Writes ``bench_train_throughput.csv`` (one row per
round and path), ``bench_train_throughput.txt`` (median, min and max per path) and
``bench_train_throughput.png`` into ``--out``::

    python experiments/bench/train_throughput.py                   # about 6 minutes
    python experiments/bench/train_throughput.py --rounds 1 --iters 1 --sb3-steps 2000 \\
        --num-envs 8 --rollout 8 --out /tmp/x --tag smoke          # smoke size
"""

# %%
from __future__ import annotations

import argparse
import csv
import os
import platform
import statistics
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parents[1] / "results" / "bench" / "train_throughput"
PATHS = ("torchrl-tx", "sb3-supersuit-tx", "torchrl-full", "torchrl-set", "sb3-batched",
         "sb3-supersuit")


def _torchrl(scenario: str, path: str, B: int, T: int, iters: int, N: int, minibatch: int,
             epochs: int) -> dict:
    from netsense.rl.config import PPOConfig
    from netsense.rl.ppo import train_ppo

    cfg = PPOConfig(scenario, algo="mappo", network="set" if path == "torchrl-set" else "mlp",
                    steps=B * T * N * iters, num_envs=B, rollout=T, epochs=epochs,
                    minibatch=minibatch, critic_hidden=(64, 64), device="auto")
    res = train_ppo(cfg, None, evaluate_every=False)
    last = res.rows[-1]
    return {"agent_steps": res.agent_steps, "wall_s": res.wall_s,
            "collect_s": last["collect_s"], "learn_s": last["learn_s"],
            "mask_violations": res.mask_violations}


def _sb3_batched(scenario: str, steps: int, B: int) -> dict:
    import torch
    from sb3_contrib import MaskablePPO

    from netsense.env.vector import make_sb3_vec_env

    torch.set_num_threads(1)
    venv = make_sb3_vec_env(scenario, B, seed=0)
    model = MaskablePPO("MlpPolicy", venv, n_steps=128, batch_size=256, n_epochs=5,
                        gamma=0.95, seed=0, device="cpu", policy_kwargs={"net_arch": [64, 64]})
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps)
    wall = time.perf_counter() - t0
    return {"agent_steps": int(model.num_timesteps), "wall_s": wall}


def _sb3_supersuit(scenario: str, steps: int, out: Path) -> dict:
    from netsense.rl.sb3 import TrainConfig, train

    res = train(TrainConfig(scenario=scenario, steps=steps, seed=0), out, progress=False)
    return {"agent_steps": int(res.curve[-1]["timesteps"]) if res.curve else steps,
            "wall_s": res.wall_s}


def run_path(path: str, args, scratch: Path, *, warm: bool = False) -> dict:
    """One measurement of ``path`` (a tiny one with ``warm``)."""
    from netsense.rl.envs import make_core

    scenario = _scenario(path, args)
    N = make_core(scenario, 1).N
    if path.startswith("torchrl"):
        B = 4 if warm else args.num_envs
        T = 4 if warm else args.rollout
        mb = args.set_minibatch if path == "torchrl-set" else args.minibatch
        iters = 1 if warm else (args.set_iters if path == "torchrl-set" else args.iters)
        return _torchrl(scenario, path, B, T, iters, N, min(mb, B * T), args.epochs)
    if path == "sb3-batched":
        B = max(1, args.sb3_envs // N)
        return _sb3_batched(scenario, 256 * B * N if warm else args.sb3_steps, B)
    return _sb3_supersuit(scenario, 512 if warm else args.sb3_steps, scratch)


def _scenario(path: str, args) -> str:
    return args.comm_scenario if path.endswith("-tx") else args.scenario


# %%
def main(argv: list[str] | None = None) -> Path:
    """Measure; returns the CSV path."""
    from tqdm.auto import tqdm

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="message_cost-v1",
                   help="scenario of the full-control paths")
    p.add_argument("--comm-scenario", default="comm_process_noise-v0",
                   help="scenario of the communication-only (-tx) paths")
    p.add_argument("--paths", nargs="+", default=list(PATHS), choices=PATHS)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--num-envs", type=int, default=256, help="B of the TorchRL paths")
    p.add_argument("--rollout", type=int, default=32, help="T of the TorchRL paths")
    p.add_argument("--iters", type=int, default=3, help="PPO iterations per measurement")
    p.add_argument("--epochs", type=int, default=2, help="PPO epochs (TorchRL paths)")
    p.add_argument("--minibatch", type=int, default=2048, help="env-steps per minibatch")
    p.add_argument("--set-minibatch", type=int, default=512,
                   help="env-steps per minibatch of the set network")
    p.add_argument("--set-iters", type=int, default=1,
                   help="PPO iterations per measurement of the set network")
    p.add_argument("--sb3-steps", type=int, default=30_000,
                   help="agent-steps per SB3 measurement")
    p.add_argument("--sb3-envs", type=int, default=40,
                   help="agent slots of sb3-batched (B = this / N)")
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--tag", default="bench_train_throughput", help="output file stem")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scratch = out / f".{args.tag}_scratch"
    rows: list[dict] = []
    for path in tqdm(args.paths, desc="warm-up", leave=False):
        run_path(path, args, scratch, warm=True)
    bar = tqdm(total=args.rounds * len(args.paths), desc="measure")
    for r in range(args.rounds):
        for path in args.paths:
            m = run_path(path, args, scratch)
            rows.append({"round": r, "path": path, "scenario": _scenario(path, args),
                         "agent_steps": m["agent_steps"], "wall_s": round(m["wall_s"], 3),
                         "agent_steps_per_s": round(m["agent_steps"] / m["wall_s"], 1),
                         "collect_s": round(m.get("collect_s", float("nan")), 3),
                         "learn_s": round(m.get("learn_s", float("nan")), 3),
                         "mask_violations": m.get("mask_violations", "")})
            bar.update(1)
            bar.set_postfix(path=path, aps=rows[-1]["agent_steps_per_s"])
    bar.close()
    csv_path = out / f"{args.tag}.csv"
    with csv_path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    _report(rows, args, out / f"{args.tag}.txt")
    _plot(rows, args, out / f"{args.tag}.png")
    if scratch.exists():
        import shutil

        shutil.rmtree(scratch)
    return csv_path


def _summary(rows: list[dict]) -> dict[str, tuple[float, float, float, float]]:
    """path -> (median, min, max agent-steps/s, median learn share)."""
    out = {}
    for path in dict.fromkeys(r["path"] for r in rows):
        v = [r["agent_steps_per_s"] for r in rows if r["path"] == path]
        share = [r["learn_s"] / r["wall_s"] for r in rows
                 if r["path"] == path and np.isfinite(r["learn_s"])]
        out[path] = (statistics.median(v), min(v), max(v),
                     statistics.median(share) if share else float("nan"))
    return out


def _report(rows: list[dict], args, path: Path) -> None:
    import torch

    lines = [f"# {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, {platform.node()}, "
             f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the end, "
             f"torch {torch.__version__}, learner device "
             f"{'cuda' if torch.cuda.is_available() else 'cpu'}",
             f"# scenarios {args.comm_scenario} (-tx paths, communication only) and "
             f"{args.scenario} (full control); TorchRL: B = {args.num_envs}, T = {args.rollout}, "
             f"{args.iters} iterations, {args.epochs} epochs, minibatch {args.minibatch} "
             f"env-steps (set network: {args.set_minibatch}, {args.set_iters} iterations); "
             f"SB3: {args.sb3_steps} "
             f"agent-steps; {args.rounds} interleaved rounds",
             "path                median agent-steps/s   (min - max)      learn share"]
    for p_, (med, lo, hi, share) in _summary(rows).items():
        lines.append(f"{p_:<18}  {med:>12,.0f}        ({lo:,.0f} - {hi:,.0f})   "
                     f"{'' if not np.isfinite(share) else f'{share:.0%}'}")
    path.write_text("\n".join(lines) + "\n")


def _plot(rows: list[dict], args, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = _summary(rows)
    names = list(s)
    med = np.array([s[n][0] for n in names])
    err = np.array([[s[n][0] - s[n][1] for n in names], [s[n][2] - s[n][0] for n in names]])
    fig, ax = plt.subplots(figsize=(6.4, 3.4))
    ax.bar(names, med, yerr=err, capsize=4, color=["C0" if n.startswith("torchrl") else "C1"
                                                   for n in names])
    ax.axhline(50_000, ls="--", color="k", lw=0.8, label="50k target (communication-only)")
    ax.set_yscale("log")
    ax.set_ylabel("agent-steps / s (collection + learning)")
    ax.set_title(f"training throughput (-tx: {args.comm_scenario}, others: {args.scenario}), "
                 f"median of {args.rounds} (bars: min-max)", fontsize=8)
    ax.legend(fontsize=8)
    ax.tick_params(axis="x", labelsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    print(main())
