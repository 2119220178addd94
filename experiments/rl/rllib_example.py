"""Train netsense under Ray RLlib: multi-agent PPO, one shared action-masked policy.

Reads ``experiments/rl/configs/rllib_ppo.toml`` (or ``--config``) and prints one line per
iteration. Locally::

    pip install torch==2.13.0 && pip install -e ".[rllib]"
    python experiments/rl/rllib_example.py --iterations 2

On a Ray cluster (start it with ``ray start --head`` on the head node and
``ray start --address=<head-ip>:6379`` on each worker, all with netsense installed)::

    python experiments/rl/rllib_example.py --address auto --num-env-runners 16

``--address`` is passed to ``ray.init``; sampling then runs on ``num_env_runners``
remote workers while the learner stays on the driver.
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

CONFIG = Path(__file__).resolve().parent / "configs" / "rllib_ppo.toml"


def load_config(path: Path = CONFIG) -> dict:
    """The TOML config as keyword arguments of :func:`netsense.rl.rllib.ppo_config`."""
    raw = tomllib.loads(Path(path).read_text())
    raw["hidden"] = tuple(raw.get("hidden", (64, 64)))
    return raw


# %%
def main(argv: list[str] | None = None) -> int:
    import ray

    from netsense.rl.rllib import ppo_config, train

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default=str(CONFIG))
    p.add_argument("--address", default=None, help="Ray cluster address (e.g. auto)")
    p.add_argument("--iterations", type=int, default=None)
    p.add_argument("--num-env-runners", type=int, default=None)
    args = p.parse_args(argv)
    cfg = load_config(Path(args.config))
    iterations = args.iterations or cfg.pop("iterations", 1)
    cfg.pop("iterations", None)
    if args.num_env_runners is not None:
        cfg["num_env_runners"] = args.num_env_runners
    scenario = cfg.pop("scenario")
    ray.init(address=args.address, include_dashboard=False, ignore_reinit_error=True)
    try:
        for row in train(ppo_config(scenario, **cfg), iterations):
            print(row)
    finally:
        ray.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
