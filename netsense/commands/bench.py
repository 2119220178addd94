"""``netsense bench``: speed measurements.

Sub-benchmarks: ``netsense bench env`` (this module: the PettingZoo environment against
MPE2's ``simple_spread_v3`` at the same N). More sub-benchmarks plug in without editing
this file: any module ``netsense/commands/_bench_<name>.py`` defining ``NAME``, ``HELP``,
``add_arguments(parser)`` and ``run(args) -> int`` (the contract of :mod:`netsense.cli`)
becomes ``netsense bench <name>``.
"""

from __future__ import annotations

import argparse
import csv
import importlib
import pkgutil
import time
from pathlib import Path

import numpy as np

from netsense.commands._args import positive_float, positive_int
from netsense.rl.atomic import atomic_path

NAME = "bench"
HELP = "Speed benchmarks (netsense bench env: env steps/s vs MPE2 simple_spread)."

#: Scenario family of the env benchmark: n = 20, Markov link failures on a circulant base
#: graph (in-degree <= 3), resized to N agents.
FAMILY = "large_n20_N100-v0"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="bench", metavar="BENCH")
    env = sub.add_parser("env", help=ENV_HELP, description=ENV_HELP)
    add_env_arguments(env)
    env.set_defaults(_bench_run=run_env)
    import netsense.commands as pkg

    for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda m: m.name):
        if info.name.startswith("_bench_"):
            mod = importlib.import_module(f"netsense.commands.{info.name}")
            p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
            mod.add_arguments(p)
            p.set_defaults(_bench_run=mod.run)


def run(args: argparse.Namespace) -> int:
    fn = getattr(args, "_bench_run", None)
    if fn is None:  # plain `netsense bench`: the env benchmark with its defaults
        parser = argparse.ArgumentParser()
        add_env_arguments(parser)
        return run_env(parser.parse_args([]))
    return fn(args)


# ----------------------------------------------------------------------------- env
ENV_HELP = ("Env steps/s and agent-steps/s through the PettingZoo API for several N, "
            "with MPE2 simple_spread_v3 at the same N when mpe2 is installed.")


def add_env_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--N", type=positive_int, nargs="+", default=[3, 10, 30, 100],
                        help="numbers of agents (default: 3 10 30 100)")
    parser.add_argument("--seconds", type=positive_float, default=2.0,
                        help="wall time per measurement (default 2)")
    parser.add_argument("--horizon", type=positive_int, default=100,
                        help="episode length for both environments (resets are timed)")
    parser.add_argument("--no-mpe", action="store_true", help="skip MPE2")
    parser.add_argument("--csv", type=Path, default=None, help="also write the rows here")


def _time_loop(env, actions_fn, seconds: float) -> float:
    """Env steps per second of ``env.step`` (with resets at episode ends), after an untimed
    warm-up of a tenth of ``seconds`` (at least 0.2 s) on the same env: the first call of
    each compiled pass loads or compiles it, so a cold first cell would measure that."""
    obs, infos = env.reset(seed=0)
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < max(0.2, 0.1 * seconds):
        obs, rew, term, trunc, infos = env.step(actions_fn(obs, infos))
        if not env.agents:
            obs, infos = env.reset()
    obs, infos = env.reset(seed=0)
    steps, t0 = 0, time.perf_counter()
    while True:
        obs, rew, term, trunc, infos = env.step(actions_fn(obs, infos))
        steps += 1
        if not env.agents:
            obs, infos = env.reset()
        if steps % 8 == 0 and time.perf_counter() - t0 >= seconds:
            return steps / (time.perf_counter() - t0)


def bench_netsense(N: int, seconds: float, horizon: int, policy: str | None = None) -> float:
    """Env steps/s of the netsense env (scenario family :data:`FAMILY` with N agents).

    ``policy=None`` steps with a fixed valid action (keep every estimate, transmit);
    otherwise the named scripted policy computes the actions (its cost included).
    """
    from netsense.env.policies import make_policy
    from netsense.env.registry import make

    env = make(FAMILY, plant={"num_agents": N}, graph={"num_nodes": N}, horizon=horizon)
    if policy is None:
        fixed = {a: np.r_[np.zeros(N, np.int64), 1] for a in env.possible_agents}
        return _time_loop(env, lambda o, i: fixed, seconds)
    pol = make_policy(policy, env)
    return _time_loop(env, lambda o, i: pol.act_dict(env, o, i), seconds)


def bench_mpe(N: int, seconds: float, horizon: int) -> float | None:
    """Env steps/s of MPE2 ``simple_spread_v3`` (discrete actions, fixed no-op action)."""
    try:
        from mpe2 import simple_spread_v3
    except ImportError:
        return None
    env = simple_spread_v3.parallel_env(N=N, max_cycles=horizon, continuous_actions=False)
    fixed = {a: 0 for a in env.possible_agents}
    return _time_loop(env, lambda o, i: fixed, seconds)


def run_env(args: argparse.Namespace) -> int:
    rows = []
    print(f"netsense env ({FAMILY} resized to N, n = 20, horizon {args.horizon}) vs MPE2 "
          f"simple_spread_v3; {args.seconds:g} s per cell; PettingZoo parallel API")
    head = (f"{'N':>4} {'env steps/s':>12} {'agent-steps/s':>14} {'+freshness pol.':>16} "
            f"{'MPE2 agent-st/s':>16} {'ratio':>7}")
    print(head)
    for N in args.N:
        sps = bench_netsense(N, args.seconds, args.horizon)
        pol = bench_netsense(N, args.seconds, args.horizon, "freshness")
        mpe = None if args.no_mpe else bench_mpe(N, args.seconds, args.horizon)
        ratio = None if mpe is None else sps / mpe
        rows.append({"N": N, "env_steps_per_s": sps, "agent_steps_per_s": sps * N,
                     "agent_steps_per_s_with_freshness_policy": pol * N,
                     "mpe2_agent_steps_per_s": None if mpe is None else mpe * N,
                     "ratio_vs_mpe2": ratio})
        print(f"{N:>4} {sps:12.0f} {sps * N:14.0f} {pol * N:16.0f} "
              f"{'n/a' if mpe is None else f'{mpe * N:.0f}':>16} "
              f"{'n/a' if ratio is None else f'{ratio:.1f}x':>7}", flush=True)
    if args.csv is not None:
        args.csv.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(args.csv) as tmp, open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        print(f"wrote {args.csv}")
    return 0
