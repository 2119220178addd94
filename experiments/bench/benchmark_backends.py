"""Wall time of ``netsense benchmark`` per backend: batched vs serial vs process.

The README's benchmark example without the learned policy (scenarios ``fig1_scalar-v0``
and ``message_cost-v0``, the default policies freshness, uniform_consensus, open_loop,
random and kf_oracle, seeds 1000..1000+S-1), run once per backend in this process, in
the order given; the kernels are compiled (or loaded from numba's cache) by a small
warm-up run first, so no backend pays for compilation in this process (worker processes
of ``process`` do pay their start-up, as they do in use). ``batched:1`` is the batched
backend with numba's thread pool set to one thread (``numba.set_num_threads(1)``): with
numba's OpenMP layer and the default (active) ``OMP_WAIT_POLICY``, a threaded kernel on a
core another process is using waits for a time slice at every call, so the report names
the threading layer, the thread count and ``OMP_WAIT_POLICY``. The results of every
backend are checked against the first one's (same jobs, metrics within 1e-9). Writes
``experiments/results/bench/benchmark_backends/bench_benchmark_backends.txt`` (``--append``
adds to it)::

    python experiments/bench/benchmark_backends.py --seeds 32
    OMP_WAIT_POLICY=passive python experiments/bench/benchmark_backends.py --seeds 32 --append
    python experiments/bench/benchmark_backends.py --seeds 2 --horizon 5 --out /tmp/x.txt
"""

# %%
from __future__ import annotations

import argparse
import math
import os
import platform
import time
from datetime import datetime, timezone
from pathlib import Path

import numba

from netsense.benchmark import DEFAULT_POLICIES, execute, make_jobs
from netsense.speed import source_revision

SCENARIOS = ("fig1_scalar-v0", "message_cost-v0")
RESULTS = Path(__file__).resolve().parents[1] / "results" / "bench" / "benchmark_backends"


def _same(a: list[dict], b: list[dict]) -> bool:
    """Same jobs in the same order and the same metrics (up to 1e-9 relative)."""
    if [r["job"] for r in a] != [r["job"] for r in b]:
        return False
    for x, y in zip(a, b, strict=True):
        for m, v in x["metrics"].items():
            w = y["metrics"][m]
            if not (math.isclose(v, w, rel_tol=1e-9, abs_tol=1e-12)
                    or (math.isnan(v) and math.isnan(w))):
                return False
    return True


def _layer() -> str:
    try:
        return numba.threading_layer()
    except ValueError:  # no threaded kernel ran
        return "(none started)"


# %%
def main(argv: list[str] | None = None) -> str:
    """Time the backends; returns the report (also written to ``--out``)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=32, help="seeds per scenario and policy")
    p.add_argument("--horizon", type=int, default=None, help="override every horizon")
    p.add_argument("--backends", nargs="+", default=["batched", "batched:1", "serial",
                                                     "process"],
                   choices=("batched", "batched:1", "serial", "process"))
    p.add_argument("--workers", type=int, default=2, help="processes of the process backend")
    p.add_argument("--out", default=str(RESULTS / "bench_benchmark_backends.txt"))
    p.add_argument("--append", action="store_true", help="append to --out")
    args = p.parse_args(argv)
    if args.seeds < 1:
        p.error("--seeds must be >= 1")
    over = {} if args.horizon is None else {"horizon": args.horizon}
    jobs = make_jobs(SCENARIOS, DEFAULT_POLICIES, range(1000, 1000 + args.seeds),
                     overrides=over)
    # warm-up: compile / load the kernels of both scenarios in this process
    execute(make_jobs(SCENARIOS, DEFAULT_POLICIES, [0], overrides={"horizon": 3}),
            backend="batched", progress=False)
    times: dict[str, float] = {}
    first: list[dict] | None = None
    threads = numba.get_num_threads()
    for label in args.backends:
        backend, _, nt = label.partition(":")
        numba.set_num_threads(int(nt) if nt else threads)
        try:
            t0 = time.perf_counter()
            res = execute(jobs, backend=backend, progress=False,
                          workers=args.workers if backend == "process" else None)
            times[label] = time.perf_counter() - t0
        finally:
            numba.set_num_threads(threads)
        if first is None:
            first = res
        elif not _same(res, first):
            raise RuntimeError(f"backend {label} disagrees with {args.backends[0]}")
    base = times[args.backends[0]]
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        f"netsense benchmark wall time per backend, {stamp}, commit {source_revision()}, "
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores (shared)",
        f"command: python experiments/bench/benchmark_backends.py --seeds {args.seeds}"
        + (f" --horizon {args.horizon}" if args.horizon else "")
        + f" --backends {' '.join(args.backends)} --workers {args.workers}"
        + (" --append" if args.append else ""),
        f"jobs: {len(jobs)} episodes = scenarios {' '.join(SCENARIOS)} x policies "
        f"{' '.join(DEFAULT_POLICIES)} x {args.seeds} seeds"
        + (f" (horizon {args.horizon})" if args.horizon else " (scenario horizons 30, 100)"),
        f"numba threading layer {_layer()}, {threads} threads, OMP_WAIT_POLICY="
        f"{os.environ.get('OMP_WAIT_POLICY', '(unset)')}",
        "results of every backend equal (same jobs and order, metrics within 1e-9)",
        "",
        f"{'backend':<10} {'seconds':>9} {'episodes/s':>11} {'time / ' + args.backends[0]:>16}",
    ]
    for backend, t in times.items():
        lines.append(f"{backend:<10} {t:9.2f} {len(jobs) / t:11.1f} {t / base:16.2f}")
    report = "\n".join(lines) + "\n"
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("a" if args.append else "w") as fh:
        fh.write(("\n" if args.append and out.stat().st_size else "") + report)
    print(report, end="")
    return report


if __name__ == "__main__":
    main()
