"""The batched core on free and on busy cores, per numba threading layer.

numba's default threading layer (OpenMP where present) keeps its worker threads spinning
after every threaded call. On free cores that makes the next call start at once; when
another process holds a core, the step's threaded calls each wait for a time slice. This
script measures the effect: ``BatchedCore.step`` (the replayed freshness actions of
``netsense bench batched``) and the bare numpy kernel at two of the benchmark shapes, each in a
fresh process, under

* ``default`` — numba's own choice (reported: ``omp`` on this machine),
* ``workqueue`` — ``NUMBA_THREADING_LAYER=workqueue`` (no spinning workers),
* ``1 thread`` — ``NUMBA_NUM_THREADS=1``,

with the cores free and with one busy-looping process per core but one ("busy"). Rates are
agent-steps/s; compare ratios within a row group (the machine's speed drifts between runs).

Run ``python experiments/bench/batched_busy.py`` (about 3 min); writes
``experiments/results/bench/batched_busy/bench_batched_busy.txt`` and ``.csv``.
"""

from __future__ import annotations

import argparse
import csv
import json
import multiprocessing as mp
import os
import subprocess
import sys
import time
from pathlib import Path

from tqdm import tqdm

from netsense.speed import source_revision

HERE = Path(__file__).resolve().parent
RESULTS = HERE.parent / "results" / "bench" / "batched_busy"
SHAPES = ((1024, 10, 10), (64, 100, 20))
MODES = {"default": {}, "workqueue": {"NUMBA_THREADING_LAYER": "workqueue"},
         "1 thread": {"NUMBA_NUM_THREADS": "1"}}

_CHILD = """
import json, sys, numba
from netsense.speed import measure_shape
B, N, n = (int(v) for v in sys.argv[1].split(","))
row = measure_shape(B, N, n, steps=64, repeats=3, vmas=False)
print(json.dumps({"core_s": row["core_s"], "kernel_s": row["kernel_s"],
                  "layer": numba.threading_layer(), "threads": numba.get_num_threads()}))
"""


def _spin(stop) -> None:  # a process that keeps one core busy
    while not stop.is_set():
        pass


def _measure(shape, extra_env) -> dict:
    env = {**os.environ, **extra_env}
    out = subprocess.run([sys.executable, "-c", _CHILD, ",".join(map(str, shape))],
                         env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--busy-procs", type=int, default=max(1, (os.cpu_count() or 2) - 1),
                   help="busy-looping processes in the busy condition (default cores - 1)")
    args = p.parse_args(argv)
    rows = []
    runs = [(c, s, m) for c in ("free", "busy") for s in SHAPES for m in MODES]
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    hogs: list = []
    bar = tqdm(total=len(runs), desc="busy-core benchmark")
    try:
        for cond, shape, mode in runs:
            if cond == "busy" and not hogs:
                hogs = [ctx.Process(target=_spin, args=(stop,), daemon=True)
                        for _ in range(args.busy_procs)]
                for h in hogs:
                    h.start()
                time.sleep(0.5)
            r = _measure(shape, MODES[mode])
            B, N, n = shape
            rows.append({"condition": cond, "B": B, "N": N, "n": n, "mode": mode,
                         "layer": r["layer"], "threads": r["threads"],
                         "core_ms": r["core_s"] * 1e3, "kernel_ms": r["kernel_s"] * 1e3,
                         "core_rate": B * N / r["core_s"],
                         "core_vs_kernel": r["kernel_s"] / r["core_s"]})
            bar.update()
    finally:
        stop.set()
        for h in hogs:
            h.join(timeout=5)
        bar.close()
    for row in rows:  # slowdown of each mode against the same shape on free cores
        free = next(x for x in rows if x["condition"] == "free" and x["mode"] == row["mode"]
                    and (x["B"], x["N"], x["n"]) == (row["B"], row["N"], row["n"]))
        row["busy_slowdown"] = row["core_ms"] / free["core_ms"]
    lines = [f"netsense {source_revision()}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; "
             f"busy = {args.busy_procs} busy-looping process(es) on {os.cpu_count()} cores",
             "| condition | B, N, n | mode (layer, threads) | core ms/step | kernel ms/step "
             "| core/kernel | core time vs free |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['condition']} | {r['B']}, {r['N']}, {r['n']} | {r['mode']} "
                     f"({r['layer']}, {r['threads']}) | {r['core_ms']:.2f} | "
                     f"{r['kernel_ms']:.2f} | {r['core_vs_kernel']:.2f}x | "
                     f"{r['busy_slowdown']:.2f}x |")
    text = "\n".join(lines)
    print(text)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "bench_batched_busy.txt").write_text(text + "\n")
    with (RESULTS / "bench_batched_busy.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {RESULTS / 'bench_batched_busy.txt'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
