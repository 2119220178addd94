"""Env speed benchmark: netsense vs MPE2 simple_spread_v3 at the same N.

Writes ``experiments/results/bench/env/bench_env.csv`` and ``bench_env.png``. The same measurement
is ``netsense bench env``. Smoke size: ``python experiments/bench/env.py --smoke``.
"""

# %%
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from netsense.commands.bench import add_env_arguments, run_env

RESULTS = Path(__file__).resolve().parents[1] / "results" / "bench" / "env"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    add_env_arguments(parser)
    parser.add_argument("--smoke", action="store_true", help="tiny run (tests)")
    parser.add_argument("--png", type=Path, default=RESULTS / "bench_env.png")
    args = parser.parse_args(argv)
    if args.smoke:
        args.N, args.seconds, args.no_mpe = [3], 0.05, True
    if args.csv is None:
        args.csv = RESULTS / ("bench_env_smoke.csv" if args.smoke else "bench_env.csv")
    run_env(args)
    if not args.smoke:
        plot(args.csv, args.png)
    return 0


# %%
def plot(csv_path: Path, png_path: Path) -> None:
    """Agent-steps/s against N for netsense and MPE2 (log-log)."""
    import csv

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(csv.DictReader(open(csv_path)))
    N = [int(r["N"]) for r in rows]
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.loglog(N, [float(r["agent_steps_per_s"]) for r in rows], "o-", label="netsense")
    ax.loglog(N, [float(r["agent_steps_per_s_with_freshness_policy"]) for r in rows], "s--",
              label="netsense + freshness policy")
    mpe = [(n, float(r["mpe2_agent_steps_per_s"])) for n, r in zip(N, rows, strict=True)
           if r["mpe2_agent_steps_per_s"]]
    if mpe:
        ax.loglog(*zip(*mpe, strict=True), "^-", label="MPE2 simple_spread_v3")
    ax.set_xlabel("N (agents)")
    ax.set_ylabel("agent-steps / s (PettingZoo parallel API)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png_path, dpi=120)
    print(f"wrote {png_path}")


if __name__ == "__main__":
    sys.exit(main())
