"""``netsense train``: train a parameter-shared, action-masked policy on a scenario."""

from __future__ import annotations

import argparse
import json

NAME = "train"
HELP = ("Train a shared MaskablePPO policy (SB3 + SuperSuit) on a scenario; saves the policy "
        "and its training curve (PNG + CSV). Needs the 'rl' extra.")

ALGOS = ("maskable_ppo",)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", help="scenario id, e.g. fig1_scalar-v0 (see `netsense list`)")
    parser.add_argument("--algo", choices=ALGOS, default="maskable_ppo",
                        help="learning algorithm (default: maskable_ppo)")
    parser.add_argument("--steps", type=int, default=50_000,
                        help="agent-steps of experience, rounded up to whole PPO rollouts "
                             "(default: 50000)")
    parser.add_argument("--out", default=None,
                        help="output directory (default: runs/SCENARIO, the path "
                             "`netsense benchmark --policies learned:runs/{scenario}/policy.zip` "
                             "reads)")
    parser.add_argument("--seed", type=int, default=0, help="seed (default: 0)")
    parser.add_argument("--num-envs", type=int, default=4,
                        help="environment copies stepped together (default: 4)")
    parser.add_argument("--n-steps", type=int, default=128,
                        help="PPO rollout length per vector slot (default: 128)")
    parser.add_argument("--batch-size", type=int, default=256, help="PPO minibatch (default: 256)")
    parser.add_argument("--lr", type=float, default=3e-4, help="learning rate (default: 3e-4)")
    parser.add_argument("--gamma", type=float, default=0.95, help="discount (default: 0.95)")
    parser.add_argument("--ent-coef", type=float, default=0.01,
                        help="entropy bonus (default: 0.01)")
    parser.add_argument("--override", action="append", default=[], metavar="KEY=JSON",
                        help="scenario override passed to netsense.make, e.g. horizon=40 "
                             "(repeatable; the value is parsed as JSON)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def parse_overrides(items: list[str]) -> dict:
    """``["horizon=40", 'reward={"message_cost": 0.1}']`` -> dict (values parsed as JSON)."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"override must look like KEY=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def run(args: argparse.Namespace) -> int:
    from netsense.benchmark.baselines import baseline_returns
    from netsense.rl.sb3 import TrainConfig, train

    cfg = TrainConfig(scenario=args.scenario, steps=args.steps, seed=args.seed,
                      num_vec_envs=args.num_envs, n_steps=args.n_steps,
                      batch_size=args.batch_size, learning_rate=args.lr, gamma=args.gamma,
                      ent_coef=args.ent_coef, overrides=parse_overrides(args.override))
    refs = baseline_returns(cfg, ("freshness", "uniform_consensus"))
    out = args.out if args.out is not None else f"runs/{args.scenario}"
    res = train(cfg, out, progress=not args.no_progress, baselines=refs)
    last = res.curve[-1]["mean_episode_reward"] if res.curve else float("nan")
    asked = "" if res.agent_steps == args.steps else f" ({args.steps} asked, whole rollouts)"
    print(f"trained {args.algo} on {args.scenario} for {res.agent_steps} agent-steps{asked} "
          f"in {res.wall_s:.1f} s; final mean episode return {last:.4g}; "
          f"masked actions taken: {res.mask_violations}/{res.actions_checked}")
    print(f"wrote {res.policy_path}, {res.curve_csv}, {res.curve_png}")
    return 0
