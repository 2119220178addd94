"""The GPU check of docs/scale.md in one short script: the learner's CUDA path tested, then
one large run's iterations with the learner on the GPU against the same on the CPU.

On a machine with a CUDA device and the package installed with the ``torchrl`` and
``test`` extras (about 5 minutes on one GPU and 16 cores)::

    python experiments/bench/gpu_check.py

1. ``pytest tests/test_rl_cuda.py``: a run trains with the learner on the GPU and the core
   on the CPU, its policy loads and acts in a CPU-only process, the networks agree on both
   devices (the script stops if a test fails);
2. ``comm_channel_kofn_n1000-v0`` with the set actor and IPPO (the command of
   docs/scale.md, "One large run on a GPU"), ``--iterations`` PPO iterations of
   ``--num-envs`` environments x 32 steps x 1,000 agents, once with ``device="cuda"`` and
   once with ``device="cpu"``, one after the other in this process: agent-steps/s of
   the iterations after the first and the ratio GPU / CPU, measured in this run.

Writes ``gpu_check.csv`` and ``gpu_check.md`` into ``--out`` (default
``experiments/results/bench/gpu_check``; whole or not at all). Without
a CUDA device it says so and exits 2, unless ``--smoke``: the same steps on the CPU only
(both "devices" the CPU, a few thousand agent-steps), which is how the script is tested
here (``tests/test_gpu_check.py``).
"""

# %%
from __future__ import annotations

import argparse
import csv
import importlib.util
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments" / "results" / "bench" / "gpu_check"
TASK = "comm_channel_kofn_n1000-v0"


def measure(device: str, num_envs: int, iterations: int, smoke: bool) -> dict:
    """Agent-steps/s of the iterations after the first of one IPPO set-actor run."""
    from netsense.rl.config import PPOConfig
    from netsense.rl.ppo import train_ppo

    task, rollout, over = (("comm_channel_kofn_n50-v0", 4, {"horizon": 8}) if smoke
                           else (TASK, 32, {}))
    n = 50 if smoke else 1000
    cfg = PPOConfig(task, algo="ippo", network="set", num_envs=num_envs, rollout=rollout,
                    steps=num_envs * rollout * n * iterations, device=device,
                    eval_interval=10**6, eval_envs=2, minibatch=min(2048, num_envs * rollout),
                    overrides=over)
    res = train_ppo(cfg, None, evaluate_every=False)
    return {"device": device, "task": task, "num_envs": num_envs,
            "iterations": len(res.rows), "agent_steps": int(res.agent_steps),
            "agent_steps_per_s": _scale().steady_rate(res.rows)}


def _scale():
    """``experiments/bench/scale.py``, whose :func:`steady_rate` times training the same
    way."""
    spec = importlib.util.spec_from_file_location("_gpu_check_scale",
                                                  ROOT / "experiments" / "bench" / "scale.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--num-envs", type=int, default=16)
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--smoke", action="store_true",
                    help="CPU only, tiny: checks the script itself where no GPU is lent")
    ap.add_argument("--skip-tests", action="store_true")
    args = ap.parse_args(argv)
    import torch

    from netsense.rl.atomic import atomic_path, write_atomic

    if args.iterations < 2:
        ap.error(f"--iterations must be at least 2 (the first is not timed), got "
                 f"{args.iterations}")
    cuda = torch.cuda.is_available()
    if not cuda and not args.smoke:
        print("no CUDA device: nothing to check (--smoke checks the script on the CPU)")
        return 2
    if not args.skip_tests:
        rc = subprocess.call([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                              str(ROOT / "tests" / "test_rl_cuda.py")], cwd=ROOT)
        if rc not in (0, 5) or (rc == 5 and cuda):
            print(f"tests/test_rl_cuda.py failed (exit {rc})")
            return 1
    gpu = "cuda" if cuda and not args.smoke else "cpu"
    rows = [measure(gpu, args.num_envs, args.iterations, args.smoke),
            measure("cpu", args.num_envs, args.iterations, args.smoke)]
    ratio = rows[0]["agent_steps_per_s"] / rows[1]["agent_steps_per_s"]
    for r in rows:
        r["vs_cpu"] = r["agent_steps_per_s"] / rows[1]["agent_steps_per_s"]
    args.out.mkdir(parents=True, exist_ok=True)
    with atomic_path(args.out / "gpu_check.csv") as tmp, tmp.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    name = torch.cuda.get_device_name(0) if gpu == "cuda" else "none (smoke: the CPU twice)"
    lines = [f"# GPU check: {rows[0]['task']}, IPPO, set actor", "",
             f"GPU: {name}; command: `python experiments/bench/gpu_check.py"
             + (" --smoke" if args.smoke else "") + "`", "",
             "| learner on | environments | iterations | agent-steps/s | vs CPU |",
             "|---|---|---|---|---|"]
    lines += [f"| {r['device']} | {r['num_envs']} | {r['iterations']} | "
              f"{r['agent_steps_per_s']:,.0f} | {r['vs_cpu']:.2f}x |" for r in rows]
    write_atomic(args.out / "gpu_check.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"learner on {gpu}: {ratio:.2f}x the CPU's agent-steps/s in this run")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
