"""Train the shared MaskablePPO policies behind the committed RL benchmark.

Reads ``experiments/rl/configs/train_maskable_ppo.toml`` and writes, per scenario,
``experiments/results/rl/train_maskable_ppo/<scenario>/`` with ``policy.zip``,
``training_curve.csv``, ``training_curve.png`` and ``train_config.json`` (wall time, masked
actions taken).

Usage::

    python experiments/rl/train_maskable_ppo.py                  # every scenario in the config
    python experiments/rl/train_maskable_ppo.py --only message_cost-v0
    python experiments/rl/train_maskable_ppo.py --smoke --out /tmp/x   # a few hundred steps
    python experiments/rl/train_maskable_ppo.py \\
        --config experiments/rl/configs/train_comm_tasks.toml

Needs the ``rl`` extra.
"""

# %%
from __future__ import annotations

import argparse
import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

HERE = Path(__file__).resolve().parent
CONFIG = HERE / "configs" / "train_maskable_ppo.toml"
RESULTS = HERE.parent / "results" / "rl" / "train_maskable_ppo"


def load_configs(path: Path = CONFIG, smoke: bool = False) -> dict:
    """``{scenario: TrainConfig}`` from the TOML file (``smoke`` shrinks every run)."""
    from netsense.rl.sb3 import TrainConfig

    raw = tomllib.loads(path.read_text())
    defaults = dict(raw.get("defaults", {}))
    defaults.pop("algo", None)
    out = {}
    for scenario, spec in raw["scenarios"].items():
        kw = {**defaults, **spec}
        kw["net_arch"] = tuple(kw["net_arch"])
        if smoke:
            kw.update(steps=256, n_steps=32, batch_size=64, num_vec_envs=1,
                      overrides={**kw.get("overrides", {}), "horizon": 8})
        out[scenario] = TrainConfig(scenario=scenario, **kw)
    return out


# %%
def main(argv: list[str] | None = None) -> int:
    from netsense.benchmark.baselines import baseline_returns
    from netsense.rl.sb3 import train

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="*", help="scenario ids to train (default: all)")
    p.add_argument("--config", default=str(CONFIG),
                   help="training config (default: configs/train_maskable_ppo.toml; the "
                        "communication tasks: configs/train_comm_tasks.toml)")
    p.add_argument("--out", default=str(RESULTS),
                   help="parent output directory (one folder per scenario)")
    p.add_argument("--smoke", action="store_true", help="tiny runs (tests)")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    configs = load_configs(Path(args.config), smoke=args.smoke)
    for scenario, cfg in configs.items():
        if args.only and scenario not in args.only:
            continue
        refs = baseline_returns(cfg, ("freshness", "uniform_consensus"))
        res = train(cfg, Path(args.out) / scenario, progress=not args.no_progress,
                    baselines=refs)
        last = res.curve[-1]["mean_episode_reward"] if res.curve else float("nan")
        print(f"{scenario}: {cfg.steps} agent-steps in {res.wall_s:.1f} s, final mean "
              f"episode return {last:.4g}, masked actions {res.mask_violations}/"
              f"{res.actions_checked}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
