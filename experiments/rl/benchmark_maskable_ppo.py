"""The committed RL benchmark: learned MaskablePPO policies vs the scripted observers.

Four scenarios (Fig. 1 scalar, random structured N = 10, message cost v0 and v1) x the
policies ``learned`` (``experiments/results/rl/train_maskable_ppo/<scenario>/policy.zip``, from
``experiments/rl/train_maskable_ppo.py``), ``freshness``, ``uniform_consensus``,
``tree_consensus`` (periodic-graph scenarios only), ``open_loop``, ``random`` and the
centralized ``kf_oracle``, over 10 seeds (1000..1009, disjoint from the training seeds).
Writes ``experiments/results/rl/benchmark_maskable_ppo/``: ``episodes.csv``, ``summary.csv``,
``summary.md``, ``errors_<scenario>.png`` and ``reward_vs_messages.png``.

Usage::

    python experiments/rl/benchmark_maskable_ppo.py            # worker processes
    python experiments/rl/benchmark_maskable_ppo.py --backend ray --address auto   # Ray cluster
"""

# %%
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE.parent / "results" / "rl" / "benchmark_maskable_ppo"
TRAIN_DIR = HERE.parent / "results" / "rl" / "train_maskable_ppo"
SCENARIOS = ("fig1_scalar-v0", "random_structured_n20_N10-v0", "message_cost-v0",
             "message_cost-v1")
POLICIES = ("learned", "freshness", "uniform_consensus", "tree_consensus", "open_loop",
            "random", "kf_oracle")


# %%
def main(argv: list[str] | None = None) -> int:
    from netsense.benchmark import markdown_table, run_benchmark

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    p.add_argument("--policies", nargs="+", default=list(POLICIES))
    p.add_argument("--train-dir", default=str(TRAIN_DIR),
                   help="parent of the <scenario>/policy.zip folders")
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--backend", default="process", choices=("process", "serial", "ray"))
    p.add_argument("--address", default=None, help="Ray address for --backend ray")
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--override", action="append", default=[], metavar="KEY=JSON")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    from netsense.commands.train import parse_overrides

    policies = [f"learned:{args.train_dir}/{{scenario}}/policy.zip" if q == "learned"
                else q for q in args.policies]
    t0 = time.perf_counter()
    _, rows = run_benchmark(args.scenarios, policies, range(1000, 1000 + args.seeds),
                            out=args.out, backend=args.backend, workers=args.workers,
                            ray_address=args.address, overrides=parse_overrides(args.override),
                            progress=not args.no_progress)
    print(markdown_table(rows))
    print(f"{len(rows)} rows in {time.perf_counter() - t0:.1f} s -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
