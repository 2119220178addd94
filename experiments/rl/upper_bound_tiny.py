"""How loose are the upper bound and the lookahead references? Exact optima on instances
small enough to enumerate.

``python experiments/rl/upper_bound_tiny.py`` (six task types x 3 seeds, N = 3 agents,
horizon 5; a few minutes) takes the reduced instances of ``tests/data/tiny/`` (plain
process noise, a collision channel of capacity 1, Gilbert-Elliott fading, a periodic
schedule, a coupled noiseless plant, per-substate messages with horizon 2) and, per
episode, writes into ``experiments/results/rl/upper_bound_tiny/``:

* the exact optimum with the realised future known (every transmit sequence enumerated:
  :func:`netsense.benchmark.upper_bound.exhaustive_optimum`),
* the certified upper bound (:func:`~netsense.benchmark.upper_bound.upper_bound`), which
  must be at least the optimum,
* the full-information reference schedulers (causal and clairvoyant lookahead), and the
  best of a few scripted rules,

as ``tiny.csv`` and ``tiny.md`` (per type: the mean of each and the mean gaps to the
optimum).
"""

# %%
from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "tests/data/tiny"
RESULTS = ROOT / "experiments/results/rl/upper_bound_tiny"
TYPES = ("base", "channel", "fading", "schedule", "coupled", "substates")
SCRIPTED = ("always", "never", "event:1", "event:2", "sources:0", "periodic:2")


def run(types=TYPES, seeds=(1, 2, 3)) -> list[dict]:
    from tqdm import tqdm

    from netsense.benchmark.protocol import evaluate
    from netsense.benchmark.upper_bound import episode_data, exhaustive_optimum, upper_bound
    from netsense.env.registry import build_model, load_file

    rows = []
    for name in tqdm(types, desc="instances", unit="type"):
        model = build_model(load_file(TINY / f"{name}.toml"))
        for seed in seeds:
            opt, count = exhaustive_optimum(model, seed)
            (data,) = episode_data(model, [seed])
            ub = upper_bound(data, window=5, rounds=2)
            refs = {p: float(evaluate(model, p, [seed])["reward"][0])
                    for p in ("reference:causal", "reference:clairvoyant")}
            scripted = {p: float(evaluate(model, p, [seed])["reward"][0]) for p in SCRIPTED}
            best = max(scripted, key=scripted.get)
            rows.append({"instance": name, "seed": seed, "sequences": count,
                         "optimum": opt, "upper_bound": ub.value,
                         "causal_reference": refs["reference:causal"],
                         "clairvoyant_reference": refs["reference:clairvoyant"],
                         "best_scripted": best, "best_scripted_return": scripted[best],
                         "exact_substates": int(data.exact.sum()),
                         "substates": int(data.nonempty.sum())})
    return rows


def markdown(rows: list[dict]) -> str:
    lines = ["| instance | optimum | upper bound (gap) | clairvoyant reference (gap) | "
             "causal reference (gap) | best scripted (gap) |", "|---|---|---|---|---|---|"]
    for name in dict.fromkeys(r["instance"] for r in rows):
        rs = [r for r in rows if r["instance"] == name]

        def m(key, rs=rs):
            return float(np.mean([r[key] for r in rs]))

        def gap(key, rs=rs):
            return float(np.mean([r[key] - r["optimum"] for r in rs]))

        lines.append(f"| {name} | {m('optimum'):.3f} | {m('upper_bound'):.3f} "
                     f"({gap('upper_bound'):+.3f}) | {m('clairvoyant_reference'):.3f} "
                     f"({gap('clairvoyant_reference'):+.3f}) | {m('causal_reference'):.3f} "
                     f"({gap('causal_reference'):+.3f}) | {m('best_scripted_return'):.3f} "
                     f"({gap('best_scripted_return'):+.3f}) |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--types", nargs="+", default=list(TYPES), choices=TYPES)
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    rows = run(args.types, args.seeds)
    for r in rows:
        if r["upper_bound"] < r["optimum"] - 1e-9:
            raise AssertionError(f"bound below the optimum: {r}")
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "tiny.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (args.out / "tiny.md").write_text(markdown(rows))
    print(markdown(rows))
    return rows


if __name__ == "__main__":
    main()
