"""What a new user waits for: import time and the first reset/step, cold and warm.

Every measurement runs in a fresh interpreter. *Cold* means an empty numba cache (a fresh
``NUMBA_CACHE_DIR``: what a new install, a new numba or an edited rule costs, once);
*warm* is a second process on the same cache. Cases: ``import netsense``,
``import netsense; netsense.make``, the first ``reset`` and ``step`` of a few scenarios as
PettingZoo envs, the README's ``BatchedEnv`` snippet (64 copies of ``link_failures-v0``),
and ``netsense warmup`` itself. Each child also reports how many netsense functions numba
compiled.

Writes ``experiments/results/bench/first_run/bench_first_run.csv`` and ``.png``
(``docs/first-run.md`` discusses them). Smoke size:
``python experiments/bench/first_run.py --smoke``.
"""

# %%
from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments" / "results" / "bench" / "first_run"
SCENARIOS = ("fig1_scalar-v0", "random_structured_n20_N10-v0", "large_n20_N100-v1")

#: Child prologue: a clock (started before anything is imported) and, except for the
#: import timings, a count of the netsense functions numba compiles (numba's compile event;
#: netsense imports numba anyway, so the clock includes it either way).
PROLOGUE = """
import json, time
t0 = time.perf_counter()
out = {}
"""
COUNTER = """
from numba.core import event
compiled = []
class _L(event.Listener):
    def on_start(self, ev):
        if ev.data["dispatcher"].py_func.__module__.startswith("netsense."):
            compiled.append(1)
    def on_end(self, ev):
        pass
event.register("numba:compile", _L())
"""
EPILOGUE = """
out["compiled"] = len(globals().get("compiled", ()))
print("RESULT=" + json.dumps(out))
"""

CHILD = {
    "import": "import netsense\nout['total_s'] = time.perf_counter() - t0\n",
    "import+make": "import netsense\nnetsense.make\nout['total_s'] = time.perf_counter() - t0\n",
    "env": """
import numpy as np
import netsense
env = netsense.make(SCENARIO)
t1 = time.perf_counter(); out['make_s'] = t1 - t0
obs, infos = env.reset(seed=0)
t2 = time.perf_counter(); out['reset_s'] = t2 - t1
act = {a: np.r_[np.zeros(env.action_space(a).shape[0] - 1, np.int64), 1] for a in env.agents}
env.step(act)
t3 = time.perf_counter(); out['first_step_s'] = t3 - t2
env.step(act)
out['second_step_s'] = time.perf_counter() - t3
out['total_s'] = time.perf_counter() - t0
""",
    "batched_snippet": """
from netsense.env.policies import make_policy
from netsense.env.vector import BatchedEnv
env = BatchedEnv("link_failures-v0", num_envs=64, horizon=20)
policy = make_policy("freshness", env.core)
t1 = time.perf_counter(); out['make_s'] = t1 - t0
obs, info = env.reset(seed=0)
t2 = time.perf_counter(); out['reset_s'] = t2 - t1
obs, reward, terminated, truncated, info = env.step(policy.act(obs, info["action_mask"]))
t3 = time.perf_counter(); out['first_step_s'] = t3 - t2
for _ in range(29):
    obs, reward, terminated, truncated, info = env.step(policy.act(obs, info["action_mask"]))
out['second_step_s'] = (time.perf_counter() - t3) / 29
out['total_s'] = time.perf_counter() - t0
""",
    "warmup": """
from netsense.env.warmup import warmup
rep = warmup(progress=False)
out['total_s'] = time.perf_counter() - t0
""",
}

FIELDS = ["case", "scenario", "cache", "make_s", "reset_s", "first_step_s", "second_step_s",
          "total_s", "compiled"]


def child(case: str, cache: Path, scenario: str = "") -> dict:
    """Run one case in a fresh interpreter on the numba cache ``cache``."""
    counter = "" if case.startswith("import") else COUNTER
    code = PROLOGUE + counter + f"SCENARIO = {scenario!r}\n" + CHILD[case] + EPILOGUE
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), MPLBACKEND="Agg",
               PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, check=True,
                         capture_output=True, text=True)
    line = next(s for s in res.stdout.splitlines() if s.startswith("RESULT="))
    return json.loads(line.partition("=")[2])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    parser.add_argument("--repeats", type=int, default=3,
                        help="fresh processes per import timing (median) and fresh caches "
                             "per first-step case (the fastest; netsense warmup runs once)")
    parser.add_argument("--no-warmup", action="store_true", help="skip timing netsense warmup")
    parser.add_argument("--smoke", action="store_true", help="tiny run (tests)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    if args.smoke:
        args.scenarios, args.repeats, args.no_warmup = ["fig1_scalar-v0"], 1, True
    jobs: list[tuple[str, str, str]] = [("import", "", "warm"), ("import+make", "", "warm")]
    for sid in args.scenarios:
        jobs += [("env", sid, "cold"), ("env", sid, "warm")]
    if not args.smoke:
        jobs += [("batched_snippet", "link_failures-v0", "cold"),
                 ("batched_snippet", "link_failures-v0", "warm")]
    if not args.no_warmup:
        jobs += [("warmup", "", "cold"), ("warmup", "", "warm")]

    from tqdm.auto import tqdm

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        shared = Path(tmp) / "shared"  # the import timings: a warm cache is irrelevant
        for case, sid, cache in tqdm(jobs, desc="first run", disable=args.no_progress):
            if case in ("import", "import+make"):
                got = [child(case, shared) for _ in range(args.repeats)]
                rows.append({"case": case, "scenario": sid, "cache": cache, "compiled": 0,
                             "total_s": statistics.median(r["total_s"] for r in got)})
                continue
            # repeat r: cold in a cache of its own (tmp/case-sid-r), then warm on the same
            # cache in a second process; the row is the repeat with the shortest total
            # (the machine is shared: the minimum is the least disturbed run)
            reps = 1 if case == "warmup" else args.repeats
            got = [child(case, Path(tmp) / f"{case}-{sid}-{r}", sid) for r in range(reps)]
            rows.append({"case": case, "scenario": sid, "cache": cache,
                         **min(got, key=lambda r: r["total_s"])})
    args.out.mkdir(parents=True, exist_ok=True)
    stem = "bench_first_run_smoke" if args.smoke else "bench_first_run"
    csv_path = args.out / f"{stem}.csv"
    with csv_path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{r[k]:.4g}" if isinstance(r.get(k), float) else r.get(k, ""))
                        for k in FIELDS})
    for r in rows:
        what = f"{r['case']} {r['scenario']}".strip()
        parts = [f"{k.removesuffix('_s')} {r[k]:.3g} s" for k in FIELDS[3:8] if k in r]
        print(f"{what:<44} {r['cache']:<5} " + ", ".join(parts) + f", compiled {r['compiled']}")
    print(f"wrote {csv_path}")
    if not args.smoke:
        plot(rows, args.out / f"{stem}.png")
    return 0


# %%
def plot(rows: list[dict], path: Path) -> None:
    """Time to the end of the first step (make + reset + step), cold vs warm, per case."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = [r for r in rows if r["case"] in ("env", "batched_snippet", "warmup")]
    labels = sorted({(r["case"], r["scenario"]) for r in cases},
                    key=lambda c: [(r["case"], r["scenario"]) for r in cases].index(c))
    fig, ax = plt.subplots(figsize=(7, 3.6))
    width = 0.38
    for k, cache in enumerate(("cold", "warm")):
        vals = [next((r["total_s"] for r in cases if (r["case"], r["scenario"]) == lab
                      and r["cache"] == cache), 0.0) for lab in labels]
        bars = ax.bar([i + (k - 0.5) * width for i in range(len(labels))], vals, width,
                      label=f"{cache} numba cache")
        ax.bar_label(bars, fmt="%.1f", fontsize=7)
    ax.set_xticks(range(len(labels)),
                  [("netsense warmup" if c == "warmup" else
                    "BatchedEnv snippet" if c == "batched_snippet" else s) for c, s in labels],
                  rotation=15, fontsize=8)
    ax.set_ylabel("seconds, fresh process (incl. import)")
    ax.set_title("Time to the first step (snippet: all 30 steps; warmup: whole run)",
                 fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    sys.exit(main())
