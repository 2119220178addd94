"""Fig. 2 of the freshness-index paper: consensus diverges, the freshness observer converges.

Paper's claim (Section III): with a = 2 on the switching graphs of Fig. 1, both consensus
weightings of eq. (6) (uniform, and along the tree rooted at node 1) give unbounded errors,
while the freshness-index observer's errors vanish. Output:
``experiments/results/papers/freshness_fig2/fig2.csv``/``.png``.
"""

# %%
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from netsense.studies.examples import run_fig2, save_fig2, summarize_fig2

RESULTS = Path(__file__).resolve().parents[1] / "results" / "papers" / "freshness_fig2"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=str(RESULTS))
    args = parser.parse_args(argv)
    # %% simulate and write
    result = run_fig2(steps=args.steps, seed=args.seed)
    csv, png = save_fig2(result, args.out, stem="fig2")
    print(summarize_fig2(result))
    print(f"wrote {png} and {csv}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
