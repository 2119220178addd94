"""End-to-end training throughput (collection + learning): the batched TorchRL trainer at the
command line's defaults and at the best settings of a small grid, against SB3 + SuperSuit at
its defaults, in one run.

Agent-steps of experience per second of training wall time, for

================================  =============================================================
path                              what runs
================================  =============================================================
``torchrl-defaults-tx``           ``netsense train --backend torchrl`` without flags: MAPPO
                                  with the :class:`netsense.rl.config.PPOConfig` defaults
                                  (B = 256, T = 32, 4 epochs, minibatch 2048 env-steps, team
                                  critic, torch's own thread count) on the
                                  communication-only scenario (transmit bit; freshness
                                  fusion adopts)
``torchrl-serial-tx``             the defaults with collection and learning one after the
                                  other (``overlap=False``), where the defaults collect the
                                  next rollout in a second thread while the learner trains
``torchrl-tuned-tx``              the defaults with the fastest ``(num_envs, minibatch)`` of
                                  ``--grid`` (epochs, threads and everything else as the
                                  defaults)
``torchrl-tanh-tx``               the defaults with tanh hidden layers instead of ReLU (what
                                  the activation costs on this CPU)
``torchrl-fp32-tx``               the defaults with the loss in float32
                                  (``precision="fp32"``), where the defaults run it in
                                  bfloat16 mixed precision on a CPU with native bfloat16
                                  products (``precision="auto"``)
``torchrl-tunedone-tx``           the tuned grid again with one torch thread
                                  (``torch_threads = 1``)
``torchrl-onethread-tx``          the defaults with one torch thread: what the learner gains
                                  from torch's other threads at the default batch
``torchrl-threads-tx``            the defaults with every core for torch and numba
                                  (``torch_threads = numba_threads = os.cpu_count()``)
``sb3-supersuit-tx``              ``netsense train --backend sb3``: MaskablePPO
                                  through SuperSuit (:func:`netsense.rl.sb3.train`,
                                  ``TrainConfig`` defaults, one torch thread), same scenario
``sb3-supersuit-cores-tx``        the same with torch on every core
``torchrl-defaults-full``         the defaults in full control (``--scenario``, keep / adopt
``torchrl-tuned-full``            / average per substate plus transmit), the tuned grid point
``torchrl-fp32-full``             and the defaults with the loss in float32
``torchrl-onethread-full``        the defaults with one torch thread, full control
``torchrl-serial-full``           the defaults without the overlap, full control
``sb3-supersuit-full``            MaskablePPO through SuperSuit, full control, at one torch
``sb3-supersuit-cores-full``      thread (its default) and with torch on every core
================================  =============================================================

The ``-tx`` paths run ``--comm-scenario`` (default ``comm_process_noise-v0``, N = 10; its own
control mode, or ``--comm-control``'s), the ``-full`` ones ``--scenario`` (default
``message_cost-v1``, N = 10). Every measurement is
repeated in ``--rounds`` interleaved rounds (every path once per round, in turn, so that load
from other processes falls on all paths alike); each path is warmed up once first (numba
compilation, torch initialisation). The wall time is that of the training loop (building
the environment and the networks is outside it); the TorchRL rows split it into collection
and learning. A TorchRL path's rate is that of its iterations after the first (the whole
loop's rate is in the CSV's ``whole_agent_steps_per_s``): with the overlap, the first
rollout is collected with nothing to overlap, once per run, and a measurement of a few
iterations would weigh that once-per-run cost as if it came back every few iterations
(a run of 10M agent-steps at the defaults has 123 iterations); SB3's rate is that of its
whole ``learn`` call, which collects and learns one after the other throughout. The
TorchRL paths run torch's own thread count (``PPOConfig``'s default: one thread per core
unless ``OMP_NUM_THREADS`` says otherwise) and one numba thread, SB3 one torch thread (its
default), unless the path says otherwise; torch's setting is restored before every
measurement, so that a path that sets its threads does not leak into the next.
The summary gives medians and the ratios the project tracks: defaults / tuned (the fastest
grid point by agent-steps/s; ``time_to_return.py`` ranks the same grid by the return reached
in equal time, the ranking the target of >= 0.8 is held to) and defaults / SB3 + SuperSuit
per control mode, against the faster of SB3's two
thread settings (so that the thread default of neither backend can flatter the ratio). Writes
``bench_train_throughput.csv`` (one row per round and measurement),
``bench_train_throughput.txt`` and ``bench_train_throughput.png`` into ``--out``::

    python experiments/bench/train_throughput.py                   # about 12 minutes
    python experiments/bench/train_throughput.py --rounds 1 --iters 2 --sb3-steps 2000 \\
        --grid 8:16 --defaults-envs 8 --out /tmp/x --tag smoke       # smoke size
"""

# %%
from __future__ import annotations

import argparse
import csv
import os
import platform
import statistics
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parents[1] / "results" / "bench" / "train_throughput"
PATHS = ("torchrl-defaults-tx", "torchrl-serial-tx", "torchrl-tuned-tx", "torchrl-tanh-tx",
         "torchrl-fp32-tx", "torchrl-tunedone-tx", "torchrl-onethread-tx",
         "torchrl-threads-tx", "sb3-supersuit-tx", "sb3-supersuit-cores-tx",
         "torchrl-defaults-full", "torchrl-serial-full", "torchrl-tuned-full",
         "torchrl-fp32-full", "torchrl-onethread-full", "sb3-supersuit-full",
         "sb3-supersuit-cores-full")


def _torchrl(scenario: str, control: str | None, B: int, minibatch: int, iters: int,
             **fields) -> dict:
    """``iters`` iterations of the PPOConfig defaults with ``num_envs = B``, ``minibatch``
    and ``fields``."""
    from netsense.rl.config import PPOConfig
    from netsense.rl.envs import make_core
    from netsense.rl.ppo import train_ppo

    N = make_core(scenario, 1, control=control).N
    base = PPOConfig(scenario, control=control)
    cfg = PPOConfig(scenario, control=control, num_envs=B, minibatch=minibatch,
                    steps=B * base.rollout * N * iters, **fields)
    res = train_ppo(cfg, None, evaluate_every=False)
    first, last = res.rows[0], res.rows[-1]
    # the rate after the first iteration: the overlapped loop's first collection has no
    # learning to hide behind (once per run: a run of 10M agent-steps has 123 iterations)
    return {"agent_steps": res.agent_steps - first["agent_steps"],
            "wall_s": last["wall_s"] - first["wall_s"],
            "whole_agent_steps_per_s": res.agent_steps / res.wall_s,
            "collect_s": last["collect_s"] - first["collect_s"],
            "learn_s": last["learn_s"] - first["learn_s"], "num_envs": B,
            "minibatch": minibatch}


def _sb3_supersuit(scenario: str, steps: int, out: Path, **fields) -> dict:
    from netsense.rl.sb3 import TrainConfig, train

    res = train(TrainConfig(scenario=scenario, steps=steps, seed=0, **fields), out,
                progress=False)
    return {"agent_steps": int(res.agent_steps), "wall_s": res.wall_s,
            "whole_agent_steps_per_s": res.agent_steps / res.wall_s}


def _grid(text: str) -> list[tuple[int, int]]:
    """``"256:2048,1024:8192"`` -> [(256, 2048), (1024, 8192)] (num_envs:minibatch)."""
    out = []
    for item in text.split(","):
        b, _, m = item.partition(":")
        out.append((int(b), int(m)))
    return out


def measure(path: str, args, scratch: Path, *, warm: bool = False) -> list[dict]:
    """The measurements of ``path`` in one round (the tuned paths: one per grid point)."""
    import torch

    torch.set_num_threads(args.start_threads)  # what a path set does not leak into the next
    full = path.endswith("-full")
    scenario = args.scenario if full else args.comm_scenario
    control = "full" if full else args.comm_control
    cores = os.cpu_count() or 1
    if path.startswith("sb3"):
        every = {"torch_threads": cores} if "cores" in path else {}
        return [_sb3_supersuit(scenario, 512 if warm else args.sb3_steps, scratch, **every)]
    if warm:
        return [_torchrl(scenario, control, 4, 16, 2, device=args.device)]
    dev = {"device": args.device}
    one = {"torch_threads": 1}
    if "tuned" in path:
        return [_torchrl(scenario, control, b, m, args.iters,
                         **(one if path.startswith("torchrl-tunedone") else {}), **dev)
                for b, m in _grid(args.grid)]
    # the defaults and their one-field variants, at the defaults' batch
    variant = {"defaults": {}, "tanh": {"activation": "tanh"}, "fp32": {"precision": "fp32"},
               "onethread": one,
               "threads": {"torch_threads": cores, "numba_threads": cores},
               "serial": {"overlap": False}}[path.split("-")[1]]
    return [_torchrl(scenario, control, args.defaults_envs, args.defaults_minibatch,
                     args.iters, **variant, **dev)]


# %%
def main(argv: list[str] | None = None) -> Path:
    """Measure; returns the CSV path."""
    from tqdm.auto import tqdm

    from netsense.engine.control import MODES
    from netsense.rl.config import PPOConfig

    defaults = PPOConfig("comm_process_noise-v0")
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="message_cost-v1",
                   help="scenario of the full-control paths")
    p.add_argument("--comm-scenario", default="comm_process_noise-v0",
                   help="scenario of the communication-only (-tx) paths")
    p.add_argument("--comm-control", default=None, choices=[m for m in MODES if m != "full"],
                   help="control mode of the TorchRL -tx paths (default: the communication "
                        "scenario's own); SB3 trains the scenario's own, so its -tx paths "
                        "are refused with it")
    p.add_argument("--paths", nargs="+", default=list(PATHS), choices=PATHS)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--iters", type=int, default=4,
                   help="PPO iterations per measurement (TorchRL paths: the rate is that of "
                        "the iterations after the first; at least 2)")
    p.add_argument("--grid", default="256:2048,512:4096,1024:8192,1024:16384",
                   help="num_envs:minibatch points of the tuned paths (minibatch in "
                        "env-steps)")
    p.add_argument("--defaults-envs", type=int, default=defaults.num_envs,
                   help="num_envs of the defaults paths (default: PPOConfig's)")
    p.add_argument("--defaults-minibatch", type=int, default=defaults.minibatch,
                   help="minibatch of the defaults paths (default: PPOConfig's)")
    p.add_argument("--sb3-steps", type=int, default=30_000,
                   help="agent-steps per SB3 measurement")
    p.add_argument("--device", default="cpu",
                   help="the TorchRL learner's device (cpu, cuda, auto); the core and the "
                        "collection stay on the CPU")
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--tag", default="bench_train_throughput", help="output file stem")
    args = p.parse_args(argv)
    if args.comm_control and any(x.startswith("sb3") and x.endswith("-tx")
                                 for x in args.paths):
        p.error("--comm-control: the SB3 paths train the scenario's own control mode; leave "
                "the sb3-*-tx paths out with --paths")
    if args.iters < 2:
        p.error(f"--iters must be at least 2 (the rate is taken after the first iteration), "
                f"got {args.iters}")
    import torch

    args.start_threads = torch.get_num_threads()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scratch = out / f".{args.tag}_scratch"
    rows: list[dict] = []
    for path in tqdm(args.paths, desc="warm-up", leave=False):
        measure(path, args, scratch, warm=True)
    bar = tqdm(total=args.rounds * len(args.paths), desc="measure")
    for r in range(args.rounds):
        for path in args.paths:
            for m in measure(path, args, scratch):
                rows.append({"round": r, "path": path,
                             "num_envs": m.get("num_envs", ""), "minibatch": m.get(
                                 "minibatch", ""), "agent_steps": m["agent_steps"],
                             "wall_s": round(m["wall_s"], 3),
                             "agent_steps_per_s": round(m["agent_steps"] / m["wall_s"], 1),
                             "whole_agent_steps_per_s": round(m["whole_agent_steps_per_s"], 1),
                             "collect_s": round(m.get("collect_s", float("nan")), 3),
                             "learn_s": round(m.get("learn_s", float("nan")), 3)})
            bar.update(1)
            bar.set_postfix(path=path, aps=rows[-1]["agent_steps_per_s"])
    bar.close()
    torch.set_num_threads(args.start_threads)
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


def _summary(rows: list[dict]) -> dict[str, dict]:
    """path -> median agent-steps/s, min, max, learn share, and (tuned) the grid point."""
    out = {}
    for path in dict.fromkeys(r["path"] for r in rows):
        rs = [r for r in rows if r["path"] == path]
        points = dict.fromkeys((r["num_envs"], r["minibatch"]) for r in rs)
        med = {pt: statistics.median(r["agent_steps_per_s"] for r in rs
                                     if (r["num_envs"], r["minibatch"]) == pt) for pt in points}
        best = max(med, key=med.get)
        v = [r["agent_steps_per_s"] for r in rs if (r["num_envs"], r["minibatch"]) == best]
        share = [r["learn_s"] / r["wall_s"] for r in rs
                 if (r["num_envs"], r["minibatch"]) == best and np.isfinite(r["learn_s"])]
        out[path] = {"median": med[best], "min": min(v), "max": max(v),
                     "share": statistics.median(share) if share else float("nan"),
                     "point": best, "grid": med}
    return out


def _ratio(s: dict, a: str, b: str) -> str:
    return f"{s[a]['median'] / s[b]['median']:.2f}x" if a in s and b in s else "-"


def _fastest(s: dict, mode: str) -> str:
    """The fastest path ending in ``mode`` (``-tx``, ``-full``) and its grid point."""
    paths = [p for p in s if p.endswith(mode)]
    if not paths:
        return f"fastest ({mode}): -"
    best = max(paths, key=lambda p: s[p]["median"])
    b, m = s[best]["point"]
    return (f"fastest ({mode}): {best} at num_envs:minibatch {b}:{m}, "
            f"{s[best]['median']:,.0f} agent-steps/s; defaults / fastest "
            f"{_ratio(s, 'torchrl-defaults' + mode, best)}")


def _against_sb3(s: dict, a: str, mode: str) -> str:
    """``a`` over the faster of SB3's two thread settings in ``mode`` (tx, full)."""
    sb3 = [p for p in (f"sb3-supersuit-{mode}", f"sb3-supersuit-cores-{mode}") if p in s]
    if a not in s or not sb3:
        return "-"
    best = max(sb3, key=lambda p: s[p]["median"])
    return f"{s[a]['median'] / s[best]['median']:.2f}x (against {best})"


def _precision(device: str) -> str:
    """What ``precision="auto"`` resolves to for a learner on ``device`` here."""
    from netsense.rl.config import device_of, learner_precision

    return learner_precision("auto", device_of(device))


def _report(rows: list[dict], args, path: Path) -> None:
    import torch

    s = _summary(rows)
    lines = [f"# {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, {platform.node()}, "
             f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the end, "
             f"torch {torch.__version__} with {args.start_threads} threads by default, "
             f"TorchRL learner on {args.device}",
             f"# {args.comm_scenario} (-tx: communication only"
             f"{f', control {args.comm_control}' if args.comm_control else ''}) and "
             f"{args.scenario} (-full); "
             f"TorchRL: PPOConfig defaults, {args.iters} iterations per measurement (rate after "
             f"the first), tuned over "
             f"num_envs:minibatch {args.grid}; SB3 + SuperSuit: TrainConfig defaults, "
             f"{args.sb3_steps} agent-steps; {args.rounds} interleaved rounds",
             "path                     median agent-steps/s  (min - max)        learn share  "
             "num_envs:minibatch"]
    for p_, d in s.items():
        pt = "" if d["point"][0] == "" else f"{d['point'][0]}:{d['point'][1]}"
        share = "" if not np.isfinite(d["share"]) else f"{d['share']:.0%}"
        lines.append(f"{p_:<24} {d['median']:>12,.0f}        ({d['min']:,.0f} - "
                     f"{d['max']:,.0f})   {share:>6}      {pt}")
    for p_, d in s.items():
        if len(d["grid"]) > 1:
            lines.append(f"# {p_} grid medians: " + ", ".join(
                f"{b}:{m} {v:,.0f}" for (b, m), v in d["grid"].items()))
    lines += [f"ratio defaults / tuned, communication only: "
              f"{_ratio(s, 'torchrl-defaults-tx', 'torchrl-tuned-tx')}; full control: "
              f"{_ratio(s, 'torchrl-defaults-full', 'torchrl-tuned-full')}",
              f"ratio defaults / SB3 + SuperSuit at the faster of its thread settings, "
              f"communication only: {_against_sb3(s, 'torchrl-defaults-tx', 'tx')}; full "
              f"control: {_against_sb3(s, 'torchrl-defaults-full', 'full')}",
              f"ratio defaults (precision {_precision(args.device)}) / the loss in float32: "
              f"communication only {_ratio(s, 'torchrl-defaults-tx', 'torchrl-fp32-tx')}, "
              f"full control {_ratio(s, 'torchrl-defaults-full', 'torchrl-fp32-full')}",
              f"ratio defaults (ReLU) / tanh layers, communication only: "
              f"{_ratio(s, 'torchrl-defaults-tx', 'torchrl-tanh-tx')}",
              f"ratio torch's {args.start_threads} threads (the TorchRL default) / one torch "
              f"thread: TorchRL "
              f"{_ratio(s, 'torchrl-defaults-tx', 'torchrl-onethread-tx')} communication "
              f"only, {_ratio(s, 'torchrl-defaults-full', 'torchrl-onethread-full')} full "
              f"control, fastest grid point "
              f"{_ratio(s, 'torchrl-tuned-tx', 'torchrl-tunedone-tx')}; SB3 + SuperSuit on "
              f"every core / one thread (its default) "
              f"{_ratio(s, 'sb3-supersuit-cores-tx', 'sb3-supersuit-tx')} and "
              f"{_ratio(s, 'sb3-supersuit-cores-full', 'sb3-supersuit-full')}",
              f"ratio defaults (collection overlapped with learning) / one after the "
              f"other: communication only "
              f"{_ratio(s, 'torchrl-defaults-tx', 'torchrl-serial-tx')}, full control "
              f"{_ratio(s, 'torchrl-defaults-full', 'torchrl-serial-full')}",
              f"ratio every core for torch and numba / defaults, communication only: "
              f"{_ratio(s, 'torchrl-threads-tx', 'torchrl-defaults-tx')}",
              _fastest(s, "-tx"), _fastest(s, "-full")]
    path.write_text("\n".join(lines) + "\n")


def _plot(rows: list[dict], args, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = _summary(rows)
    names = list(s)
    med = np.array([s[n]["median"] for n in names])
    err = np.array([[s[n]["median"] - s[n]["min"] for n in names],
                    [s[n]["max"] - s[n]["median"] for n in names]])
    fig, ax = plt.subplots(figsize=(7.0, 3.6))
    ax.bar(names, med, yerr=err, capsize=4,
           color=["C0" if n.startswith("torchrl") else "C1" for n in names])
    ax.set_yscale("log")
    ax.set_ylabel("agent-steps / s (collection + learning)")
    ax.set_title(f"training throughput (-tx: {args.comm_scenario}, -full: {args.scenario}), "
                 f"median of {args.rounds} (bars: min-max)", fontsize=8)
    ax.tick_params(axis="x", labelsize=7, rotation=15)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    print(main())
