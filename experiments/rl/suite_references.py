"""Build the benchmark suite's reference points from the committed results.

Writes ``netsense/benchmark/data/suite_references.json``, the one definition of the suite's
references (:mod:`netsense.benchmark.references`), from:

* the scripted frontier of every task, ``experiments/results/rl/comm_tasks/frontier_<task>.csv``:
  the best row of kind ``decentralised`` by mean return (the kind column decides, not the
  family's name); the rule and ``never`` are run again here on the protocol's 100
  evaluation episodes for their per-episode returns;
* the full-information reference schedulers' per-episode returns,
  ``experiments/results/rl/comm_bounds/episodes.csv`` (policies ``reference:*``, or
  ``bound:*`` as the lookahead references were once called): the best by mean return;
* the certified upper bounds, ``experiments/results/rl/upper_bounds/episodes.csv``
  (columns ``scenario``, ``seed``, ``upper_bound``: one row per task and episode). Where
  the file or a task's rows are missing, the task gets no bound (said on the console), and
  the suite then refuses to normalise it.

The tasks at scale (:data:`netsense.benchmark.references.SCALE_TASKS`) come from their
frontier, ``experiments/results/rl/scale_tasks/frontier_<task>.csv``
(``experiments/rl/scale_tasks.py``): the best decentralised rule as above and, as the
reference, the best centralised scheduler (kind ``centralised``, ``oldest:K``), each run
again here on the 100 episodes; no upper bound (its linear program does not scale to them).

Run from the repository root (about 10 s)::

    python experiments/rl/suite_references.py
"""

# %%
from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RL = ROOT / "experiments" / "results" / "rl"
FRONTIERS = RL / "comm_tasks"
SCALE_FRONTIERS = RL / "scale_tasks"
REFERENCE_EPISODES = RL / "comm_bounds" / "episodes.csv"
UPPER_BOUNDS = RL / "upper_bounds" / "episodes.csv"
OUT = ROOT / "netsense" / "benchmark" / "data" / "suite_references.json"
#: policy-name prefixes of the full-information references in REFERENCE_EPISODES
REFERENCE_PREFIXES = ("reference:", "bound:")


def _rel(path: Path) -> str:
    try:
        return str(path.relative_to(ROOT))
    except ValueError:
        return str(path)


def best_row(task: str, folder: Path = FRONTIERS, kind: str = "decentralised") -> dict:
    """The row of kind ``kind`` with the highest mean return in the task's frontier CSV."""
    path = folder / f"frontier_{task}.csv"
    if not path.exists():
        raise ValueError(f"{path}: no frontier for {task}; run experiments/rl/comm_tasks.py "
                         "(experiments/rl/scale_tasks.py for a task at scale)")
    with path.open() as fh:
        rows = [r for r in csv.DictReader(fh) if r.get("kind") == kind]
    if not rows:
        raise ValueError(f"{path}: no row of kind {kind!r}")
    return max(rows, key=lambda r: float(r["reward_mean"]))


def reference_episodes(task: str, path: Path = REFERENCE_EPISODES) -> dict[str, dict]:
    """``{name: {seed: return}}`` of the task's full-information references."""
    out: dict[str, dict] = {}
    if not path.exists():
        return out
    with path.open() as fh:
        for r in csv.DictReader(fh):
            kind = r.get("kind", "")
            if r["scenario"] == task and (r["policy"].startswith(REFERENCE_PREFIXES)
                                          or kind in ("reference", "bound")):
                out.setdefault(r["policy"], {})[int(r["seed"])] = float(r["reward"])
    return out


def upper_bounds(path: Path = UPPER_BOUNDS) -> dict[str, dict[int, float]]:
    """``{task: {seed: upper bound}}`` from the upper bounds' episodes file (empty when it
    does not exist)."""
    if not path.exists():
        return {}
    out: dict[str, dict[int, float]] = {}
    with path.open() as fh:
        reader = csv.DictReader(fh)
        missing = {"scenario", "seed", "upper_bound"} - set(reader.fieldnames or ())
        if missing:
            raise ValueError(f"{path}: columns {sorted(missing)} missing")
        for r in reader:
            v = float(r["upper_bound"])
            if not math.isfinite(v):
                raise ValueError(f"{path}: non-finite upper bound for {r['scenario']} seed "
                                 f"{r['seed']}")
            out.setdefault(r["scenario"], {})[int(r["seed"])] = v
    return out


def build(episodes: int = 100, frontiers: Path = FRONTIERS,
          references: Path = REFERENCE_EPISODES, bounds: Path = UPPER_BOUNDS) -> dict:
    """The references file's content (:mod:`netsense.benchmark.references`)."""
    from netsense.benchmark.protocol import eval_seeds, evaluate, frontier_overrides
    from netsense.benchmark.references import FORMAT, FORMAT_VERSION, KNOWN_TASKS, SCALE_TASKS

    seeds = eval_seeds(episodes)
    ub = upper_bounds(bounds)
    if not bounds.exists():
        print(f"NOTE: {_rel(bounds)} does not exist: no task gets an upper bound, and the "
              "suite will not normalise scores until it is written and this script re-run")
    tasks = {}
    for task in KNOWN_TASKS:
        scale = task in SCALE_TASKS
        folder, script = ((SCALE_FRONTIERS, "scale_tasks.py") if scale
                          else (frontiers, "comm_tasks.py"))
        over = frontier_overrides(task)
        best = best_row(task, folder)
        never = evaluate(task, "never", seeds, over)["reward"]
        dec = evaluate(task, best["policy"], seeds, over)["reward"]
        if int(best["episodes"]) == episodes and abs(
                dec.mean() - float(best["reward_mean"])) > 1e-3 * abs(dec.mean()) + 1e-6:
            raise ValueError(f"{task}: {best['policy']} returns {dec.mean():.6g} here and "
                             f"{best['reward_mean']} in its frontier CSV: the frontier is "
                             f"stale; run experiments/rl/{script} again")
        if scale:  # the best centralised scheduler, run again on the same episodes
            cen = best_row(task, folder, "centralised")["policy"]
            refs = {cen: dict(zip(seeds, evaluate(task, cen, seeds, over)["reward"].tolist(),
                                  strict=True))}
        else:
            refs = reference_episodes(task, references)
        entry = {"control": best["control"],
                 "never": {"seeds": seeds, "returns": [float(v) for v in never]},
                 "best_decentralised": {"spec": best["policy"], "seeds": seeds,
                                        "returns": [float(v) for v in dec]},
                 "best_reference": None, "upper_bound": None,
                 "sources": {"frontier": _rel(folder / f"frontier_{task}.csv")}}
        if refs:
            name = max(refs, key=lambda k: sum(refs[k].values()) / len(refs[k]))
            s = sorted(refs[name])
            entry["best_reference"] = {"name": name, "seeds": s,
                                       "returns": [refs[name][k] for k in s]}
            entry["sources"]["best_reference"] = (entry["sources"]["frontier"] if scale
                                                  else _rel(references))
        if task in ub:
            s = sorted(ub[task])
            entry["upper_bound"] = {"seeds": s, "values": [ub[task][k] for k in s]}
            entry["sources"]["upper_bound"] = _rel(bounds)
        elif bounds.exists() and not scale:
            print(f"NOTE: {_rel(bounds)} holds no upper bound for {task}: the task gets "
                  "none")
        tasks[task] = entry
        print(f"{task}: best decentralised {best['policy']} ({dec.mean():.2f}), never "
              f"{never.mean():.2f}, reference "
              f"{entry['best_reference']['name'] if entry['best_reference'] else '-'}, "
              f"upper bound on {len(ub.get(task, {}))} episodes")
    return {"format": FORMAT, "format_version": FORMAT_VERSION, "episodes": episodes,
            "tasks": tasks}


def dumps(data: dict) -> str:
    """JSON with every list of numbers on one line (a diff shows which task changed)."""
    flat = {}

    def mark(v):
        if isinstance(v, dict):
            return {k: mark(x) for k, x in v.items()}
        if isinstance(v, list) and all(isinstance(x, (int, float)) for x in v):
            key = f"@@{len(flat)}@@"
            flat[key] = json.dumps(v)
            return key
        return v

    text = json.dumps(mark(data), indent=1)
    for key, value in flat.items():
        text = text.replace(f'"{key}"', value)
    return text


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=OUT)
    p.add_argument("--episodes", type=int, default=100)
    args = p.parse_args(argv)
    from netsense.benchmark.references import references_json

    data = build(args.episodes)
    references_json(data)  # the file the suite will read passes its checks
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(dumps(data) + "\n")
    print(f"wrote {_rel(args.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
