"""Where a training iteration's time goes: the batched trainer at the command line's defaults,
split into its stages by a profile.

Trains ``--iters`` iterations of :func:`netsense.rl.ppo.train_ppo` with the
:class:`netsense.rl.config.PPOConfig` defaults with one torch thread (the defaults take
torch's own count; one leaves the other core of the 2-core machine to the second thread
measured below) and one numba thread, and with
collection and learning one after the other (``overlap=False``: :mod:`cProfile` sees only
the thread it runs in, and the defaults collect in a second one) under :mod:`cProfile`, and
attributes the wall time to disjoint stages by the cumulative time of
the functions that implement them:

==================  ==========================================================================
stage               functions
==================  ==========================================================================
start (stagger)     spreading the members' episode phases before the first rollout (one
                    horizon of random actions, once per run)
core step           the collection minus the three stages below: ``NetSenseBatchedEnv.
                    advance`` (the batched core's compiled step, the reward option),
                    partial resets, copies into the rollout buffers
global state        :func:`netsense.rl.envs.global_state` (the team critic's input, per step)
actor (collection)  the actor network's forward passes during collection
sampling            :class:`~netsense.rl.distributions.MaskedMultiCategorical`: building the
                    masked distribution, sampling, log-probabilities (collection)
advantage           :func:`netsense.rl.advantage.critic_values` (one critic pass over the
                    rollout) and :func:`~netsense.rl.advantage.estimate` (TorchRL's GAE)
loss batch          :func:`netsense.rl.advantage.loss_batch` (the rollout as a TensorDict)
minibatch gather    ``TensorDict`` indexing of the minibatches
loss forward        TorchRL's ``MAPPOLoss.forward`` (actor, distribution, critic, terms)
backward            autograd's backward pass
optimiser           ``Adam.step`` and gradient clipping
other               the rest of the loop (building the core and networks, logging)
==================  ==========================================================================

Evaluation is timed on its own (one greedy and one sampled :func:`netsense.rl.evaluation.
evaluate`, which the defaults run every 10 iterations).

Unprofiled, in ``--rounds`` interleaved rounds, the script also times the serial loop, the
overlapped defaults (learning and collection in two threads), and the serial loop beside a
second thread that runs compiled code on data in its cache (matrix products), streams
memory (copies of a 64 MiB array; both with the GIL released) or runs a Python loop: what
a thread beside it costs the learning and the collection, as medians of each round's
ratio to its own serial run.

Writes ``profile.txt`` (the table of seconds and share per stage, the unprofiled figures
above and the evaluation's cost) and ``profile.png`` into ``--out``::

    python experiments/bench/train_profile.py          # about 2 minutes
"""

# %%
from __future__ import annotations

import argparse
import cProfile
import pstats
import statistics
import time
from dataclasses import replace
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1] / "results" / "bench" / "train_profile"

#: stage -> (file suffix, function name) pairs whose cumulative time it takes
STAGES = {
    "start (stagger)": [("rl/rollout.py", "_stagger")],
    "core step": [("rl/rollout.py", "collect")],
    "global state": [("rl/envs.py", "global_state")],
    "actor (collection)": [("rollout.py", "_actor")],
    "sampling": [("rollout.py", "_sample")],
    "advantage": [("rl/advantage.py", "critic_values"), ("rl/advantage.py", "estimate")],
    "loss batch": [("rl/advantage.py", "loss_batch")],
    "minibatch gather": [("rl/ppo.py", "_gather")],
    "loss forward": [("torchrl/objectives/ppo.py", "forward")],
    "backward": [("torch/_tensor.py", "backward")],
    "optimiser": [("torch/optim/adam.py", "step"), ("torch/nn/utils/clip_grad.py",
                                                    "clip_grad_norm_")],
}
#: stages inside "core step" (its cumulative time is the whole collection): the rest of the
#: collection is the core's step and the buffer copies
INSIDE_COLLECTION = ("global state", "actor (collection)", "sampling")


def _cumulative(stats: pstats.Stats, suffix: str, name: str) -> float:
    total = 0.0
    for (file, _line, fn), (_cc, _nc, _tt, ct, _callers) in stats.stats.items():
        if fn == name and file.replace("\\", "/").endswith(suffix):
            total += ct
    return total


def main(argv: list[str] | None = None) -> Path:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="comm_process_noise-v0")
    p.add_argument("--iters", type=int, default=10, help="training iterations profiled")
    p.add_argument("--rounds", type=int, default=3,
                   help="rounds of the unprofiled runs (serial, overlapped, serial beside "
                        "a busy thread); medians are reported")
    p.add_argument("--out", default=str(RESULTS))
    args = p.parse_args(argv)
    if args.rounds < 1 or args.iters < 1:
        p.error(f"--rounds and --iters must be at least 1, got {args.rounds} and {args.iters}")
    from netsense.rl.config import PPOConfig
    from netsense.rl.evaluation import evaluate
    from netsense.rl.ppo import train_ppo

    base = PPOConfig(args.scenario)
    from netsense.rl.envs import make_core

    N = make_core(args.scenario, 1).N
    # one thread of work, which cProfile sees whole: the defaults collect the next rollout
    # in a second thread while the learner trains (PPOConfig.overlap), timed apart below
    cfg = PPOConfig(args.scenario, steps=base.num_envs * base.rollout * N * args.iters,
                    overlap=False, torch_threads=1)
    train_ppo(replace(cfg, steps=base.num_envs * base.rollout * N, overlap=True), None,
              evaluate_every=False)  # warm-up: compilation, allocation
    # rounds of: the serial loop alone, the defaults (collection in a second thread), and
    # the serial loop beside a second thread that runs compiled code on data in cache,
    # streams memory (both with the GIL released) or runs Python (_WORK); each round's
    # ratios are to its own serial run
    runs: dict[str, list] = {"serial": [], "overlap": [], **{kind: [] for kind in _WORK}}
    for _ in range(args.rounds):
        for kind, got in runs.items():
            t0 = time.perf_counter()
            if kind in _WORK:
                r = _beside(cfg, kind)
            else:
                r = train_ppo(replace(cfg, overlap=kind == "overlap"), None,
                              evaluate_every=False)
            got.append((time.perf_counter() - t0, r))
    res = runs["serial"][0][1]
    plain, overlapped = (statistics.median(w for w, _ in runs[k]) for k in ("serial", "overlap"))
    parts = {k: {key: statistics.median(r.rows[-1][key] for _, r in runs[k])
                 for key in ("collect_s", "learn_s")} for k in ("serial", "overlap")}

    def ratio(kind: str, key: str) -> str:  # median over rounds of kind / serial
        pairs = zip(runs[kind], runs["serial"], strict=True)
        med = statistics.median(_per_iteration(r, key) / _per_iteration(a, key)
                                for (_, r), (_, a) in pairs)
        return f"{med:.2f}x"

    prof = cProfile.Profile()
    prof.enable()
    t0 = time.perf_counter()
    train_ppo(cfg, None, evaluate_every=False)
    profiled = time.perf_counter() - t0
    prof.disable()
    from netsense.rl.policy import actor_net

    net = actor_net(cfg, make_core(args.scenario, 1))
    t0 = time.perf_counter()
    evaluate(net, cfg)
    evaluate(net, cfg, deterministic=False)
    eval_s = time.perf_counter() - t0
    stats = pstats.Stats(prof)
    got = {stage: sum(_cumulative(stats, *f) for f in funcs) for stage, funcs in STAGES.items()}
    got["core step"] -= sum(got[k] for k in INSIDE_COLLECTION)
    rows = list(got.items())
    rows.append(("other", max(0.0, profiled - sum(v for _, v in rows))))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    lines = [f"# {args.scenario}, PPOConfig defaults but overlap=False and one torch thread "
             f"(B = {cfg.num_envs}, "
             f"T = {cfg.rollout}, {cfg.epochs} epochs, minibatch {cfg.minibatch} env-steps, critic "
             f"{cfg.critic_kind}), {args.iters} iterations = {res.agent_steps} agent-steps",
             f"# without the profiler (medians of {args.rounds} rounds): {plain:.2f} s, "
             f"{res.agent_steps / plain:,.0f} agent-steps/s (collection "
             f"{parts['serial']['collect_s']:.2f} s, learning {parts['serial']['learn_s']:.2f} "
             f"s), collection and learning one after the other (overlap=False); the "
             f"overlapped loop (the defaults' overlap, one torch thread): {overlapped:.2f} s, "
             f"{res.agent_steps / overlapped:,.0f} "
             f"agent-steps/s (collection {parts['overlap']['collect_s']:.2f} s in its thread, "
             f"learning {parts['overlap']['learn_s']:.2f} s)",
             f"# beside each other, learning (with its proximal pass) took "
             f"{ratio('overlap', 'learn_s')} and the collection {ratio('overlap', 'collect_s')} "
             f"their time one after the other (median of the rounds' ratios)",
             *[f"# the serial loop beside a second thread busy with {_WORK[kind]}: learning "
               f"{ratio(kind, 'learn_s')}, collection {ratio(kind, 'collect_s')} their time "
               f"alone" for kind in _WORK],
             f"# under the profiler (shares below; the profiler slows Python-heavy stages "
             f"more): {profiled:.2f} s",
             f"# evaluation (not in the table): {eval_s:.2f} s for one greedy and one sampled "
             f"evaluation of {cfg.eval_envs} episodes, every {cfg.eval_interval} iterations by "
             f"default: {eval_s / cfg.eval_interval:.2f} s per iteration",
             "stage                  seconds   share"]
    for stage, v in rows:
        lines.append(f"{stage:<20} {v:>9.2f}   {v / profiled:>5.1%}")
    (out / "profile.txt").write_text("\n".join(lines) + "\n")
    _plot(rows, profiled, out / "profile.png", args.scenario)
    print("\n".join(lines))
    return out / "profile.txt"


_WORK = {"compiled": "matrix products (compiled code on data in cache, GIL released)",
         "memory": "copies of a 64 MiB array (memory traffic, GIL released)",
         "python": "a Python loop (GIL held between its torch operations)"}


def _beside(cfg, kind: str):
    """:func:`~netsense.rl.ppo.train_ppo` of ``cfg`` while a second thread runs ``kind`` of
    work (:data:`_WORK`) until it ends."""
    import threading

    import torch

    from netsense.rl.ppo import train_ppo

    stop = threading.Event()

    def work() -> None:
        a = torch.full((400, 400), 0.5)  # no draw from the generator the run seeds
        c = torch.empty(400, 400)
        big = torch.ones(16 * 2**20) if kind == "memory" else None  # 64 MiB of float32
        out = torch.empty_like(big) if big is not None else None
        while not stop.is_set():
            if kind == "compiled":
                torch.mm(a, a, out=c)
            elif kind == "memory":
                out.copy_(big)
            else:
                s = 0
                for i in range(200):
                    s += i
                c.add_(1.0)

    t = threading.Thread(target=work, name=f"train-profile-{kind}", daemon=True)
    t.start()
    try:
        return train_ppo(cfg, None, evaluate_every=False)
    finally:
        stop.set()
        t.join()


def _per_iteration(result, key: str) -> float:
    """Seconds of ``key`` (``collect_s``, ``learn_s``) per iteration of a run."""
    return result.rows[-1][key] / len(result.rows)


def _plot(rows, total: float, path: Path, scenario: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    names = [r[0] for r in rows][::-1]
    vals = [r[1] / total for r in rows][::-1]
    ax.barh(names, vals, color="C0")
    ax.set_xlabel("share of the training time (profiled)")
    ax.set_title(f"one training run at the defaults, {scenario}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
