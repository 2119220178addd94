"""Step time with the other cores idle and busy, per batch size and thread configuration.

Does a process that holds a core make the batched step collapse? One step is
:meth:`netsense.engine.core.BatchedCore.step` plus the freshness policy's ``act`` (both
compiled passes; what an RL loop runs), on the benchmark model of
:func:`netsense.speed.bench_model` at ``N = 10, n = 10`` (Markov link failures and
Gaussian noise drawn by the threaded refill every 64 steps, included), for
``B = 1, 64, 1024``. Every measurement runs in a fresh process (the thread pool and its
wait policy are fixed when a process starts it): warm-up, then ``--blocks`` blocks of
whole 64-step chunks, the median block. Conditions:

* ``idle`` — nothing else started by the script (other users of the machine may still
  run: the load average is recorded with every row);
* ``busy`` — ``--busy-procs`` busy-looping processes (default one per core but one),
  started by the script.

On a shared machine, ``--calm PERCENT`` waits before each measurement until the others'
demand for CPU is low (Linux pressure stall information); the pressure is recorded too.

Configurations (``--configs``): ``default`` (what netsense does unset: OpenMP with
passive waits, threads only for large batches), ``omp-spin`` (libgomp's own default
spinning, ``GOMP_SPINCOUNT=300000``), ``workqueue`` (``NUMBA_THREADING_LAYER``),
``serial`` (``NETSENSE_NUM_THREADS=1``). Conditions and configurations are interleaved
within each of ``--repeats`` rounds, so drifts of the machine hit all of them alike.

Writes ``experiments/results/bench/busy_cores/bench_busy_cores.csv`` (one row per process),
``.txt`` (medians, spreads and busy/idle ratios) and ``.png``. Run:
``python experiments/bench/busy_cores.py`` (about 5 minutes on 2 cores; ``--smoke`` for a
seconds-long check of the plumbing, no timing).
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
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
RESULTS = HERE.parent / "results" / "bench" / "busy_cores"
SIZES = (1, 64, 1024)
CONFIGS: dict[str, dict[str, str]] = {
    "default": {},
    "omp-spin": {"GOMP_SPINCOUNT": "300000"},
    "workqueue": {"NUMBA_THREADING_LAYER": "workqueue"},
    "serial": {"NETSENSE_NUM_THREADS": "1"},
}
#: Variables of the caller that would change a configuration: removed for every child.
CLEARED = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "NUMBA_THREADING_LAYER",
           "NUMBA_NUM_THREADS", "NETSENSE_NUM_THREADS", "OMP_NUM_THREADS")
COLUMNS = ("round", "condition", "config", "B", "model", "N", "n", "step_ms", "block_min_ms",
           "block_max_ms", "steps", "layer", "threads", "loadavg", "cpu_pressure")
#: The issue's bound: busy at most this many times idle, at every size, by default.
BOUND = 2.5


# %% One measurement (runs in the child process)
def child(B: int, N: int, n: int, steps: int, blocks: int, warmup: int = 70,
          scenario: str | None = None) -> dict:
    """Median seconds of one step over ``blocks`` blocks of ``steps`` steps (of the bench
    model at ``(N, n)``, or of a registered ``scenario``)."""
    import numba

    import netsense
    from netsense.engine.core import BatchedCore
    from netsense.env.policies import FreshnessPolicy

    if scenario:
        from netsense.env.vector import load_model

        model = load_model(scenario, horizon=10**9)[0]
    else:
        from netsense.speed import bench_model

        model = bench_model(N, n, horizon=10**9)
    core = BatchedCore(model, B)
    pol = FreshnessPolicy(core.layout)
    obs, mask = core.reset(0)
    for _ in range(warmup):  # compile or load every pass, one refill included
        out = core.step(pol.act(obs, mask))
        obs, mask = out.obs, out.action_mask
    times = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        for _ in range(steps):
            out = core.step(pol.act(obs, mask))
            obs, mask = out.obs, out.action_mask
        times.append((time.perf_counter() - t0) / steps)
    try:
        layer = numba.threading_layer()
    except ValueError:  # no threaded call ran: the pool never started
        layer = "-"
    return {"N": core.N, "n": core.n, "step_ms": statistics.median(times) * 1e3,
            "block_min_ms": min(times) * 1e3, "block_max_ms": max(times) * 1e3, "layer": layer,
            # (numba's count where netsense has no knob: the code before this script)
            "threads": getattr(netsense, "get_num_threads", numba.get_num_threads)()}


def _measure(config: str, B: int, N: int, n: int, steps: int, blocks: int,
             warmup: int, scenario: str | None) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in CLEARED}
    env.update(CONFIGS[config])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH"))
                                        if p)
    spec = f"{B},{N},{n},{steps},{blocks},{warmup}" + (f",{scenario}" if scenario else "")
    out = subprocess.run([sys.executable, __file__, "--child", spec], env=env,
                         capture_output=True, text=True, check=False, timeout=1800)
    if out.returncode != 0:
        raise RuntimeError(f"{config} at B = {B} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def cpu_pressure() -> float:
    """Percent of the last 10 s in which some runnable task waited for a CPU (Linux PSI,
    ``/proc/pressure/cpu``; NaN where unavailable): near 0 when nobody competes."""
    try:
        with open("/proc/pressure/cpu") as fh:
            some = fh.readline().split()
        return float(some[1].split("=")[1])
    except (OSError, IndexError, ValueError):
        return float("nan")


def wait_for_calm(limit: float | None, max_wait: float) -> float:
    """Wait (at most ``max_wait`` s) until :func:`cpu_pressure` is at most ``limit`` (other
    users of a shared machine quiet); returns the pressure when the wait ended."""
    t0 = time.monotonic()
    while True:
        p = cpu_pressure()
        if limit is None or not p > limit or time.monotonic() - t0 > max_wait:
            return p
        time.sleep(2)


class BusyLoops:
    """``count`` processes that each keep a core busy (a Python busy loop) while open."""

    def __init__(self, count: int) -> None:
        self.count = count
        self.procs: list[subprocess.Popen] = []

    def __enter__(self) -> BusyLoops:
        self.procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                      for _ in range(self.count)]
        time.sleep(0.5)  # let them get going
        return self

    def __exit__(self, *exc) -> None:
        for p in self.procs:
            p.kill()
        for p in self.procs:
            p.wait()


# %% The run
def run(sizes, configs, repeats: int, blocks: int, busy_procs: int, N: int, n: int,
        steps_for, warmup: int = 70, calm: float | None = None,
        max_wait: float = 600, scenario: str | None = None) -> list[dict]:
    """Every (round, condition, B, config) in its own process; rows of :data:`COLUMNS`."""
    from tqdm import tqdm

    rows = []
    bar = tqdm(total=repeats * 2 * len(sizes) * len(configs), desc="busy-core benchmark")
    try:
        for r in range(repeats):
            for condition in ("idle", "busy"):
                with BusyLoops(busy_procs if condition == "busy" else 0):
                    for B in sizes:
                        for config in configs:
                            steps = steps_for(B)
                            pressure = wait_for_calm(calm, max_wait)
                            res = _measure(config, B, N, n, steps, blocks, warmup,
                                           scenario)
                            rows.append({"round": r, "condition": condition,
                                         "config": config, "B": B,
                                         "model": scenario or "bench_model",
                                         "N": res.pop("N"), "n": res.pop("n"),
                                         "steps": steps, "loadavg": os.getloadavg()[0],
                                         "cpu_pressure": pressure, **res})
                            bar.update()
    finally:
        bar.close()
    return rows


def read_csv(path: Path) -> list[dict]:
    """The rows of an earlier run's CSV, with numbers as numbers."""
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        for k in ("round", "B", "N", "n", "steps", "threads"):
            r[k] = int(r[k])
        for k in ("step_ms", "block_min_ms", "block_max_ms", "loadavg", "cpu_pressure"):
            r[k] = float(r[k])
    return rows


def summarise(rows: list[dict]) -> list[dict]:
    """Per (config, B): median and range of the rounds, idle and busy, and their ratio."""
    out = []
    for config in dict.fromkeys(r["config"] for r in rows):
        for B in dict.fromkeys(r["B"] for r in rows):
            cell = {"config": config, "B": B}
            for cond in ("idle", "busy"):
                v = [r["step_ms"] for r in rows
                     if (r["config"], r["B"], r["condition"]) == (config, B, cond)]
                cell[cond] = statistics.median(v) if v else float("nan")
                cell[f"{cond}_lo"], cell[f"{cond}_hi"] = (min(v), max(v)) if v else (0, 0)
            layers = {r["layer"] for r in rows if (r["config"], r["B"]) == (config, B)}
            cell["layer"] = "/".join(sorted(layers))
            cell["ratio"] = cell["busy"] / cell["idle"]
            out.append(cell)
    return out


def table(summary: list[dict], rows: list[dict], busy_procs: int) -> str:
    loads = [r["loadavg"] for r in rows]
    psi = [r["cpu_pressure"] for r in rows]
    lines = [f"python {' '.join(sys.argv)}; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; "
             f"{os.cpu_count()} cores; busy = {busy_procs} busy-looping process(es); "
             f"1-min load average during the run {min(loads):.1f}-{max(loads):.1f}, CPU "
             f"pressure before each measurement {min(psi):.0f}-{max(psi):.0f} %",
             f"step = BatchedCore.step + FreshnessPolicy.act, {rows[0]['model']} (N = "
             f"{rows[0]['N']}, n = {rows[0]['n']}); median over rounds [min-max] of each "
             "process's median block",
             "", "| config | B | layer | idle ms/step | busy ms/step | busy / idle |",
             "|---|---|---|---|---|---|"]
    for c in summary:
        lines.append(f"| {c['config']} | {c['B']} | {c['layer']} | {c['idle']:.3f} "
                     f"[{c['idle_lo']:.3f}-{c['idle_hi']:.3f}] | {c['busy']:.3f} "
                     f"[{c['busy_lo']:.3f}-{c['busy_hi']:.3f}] | {c['ratio']:.2f}x |")
    default = [c for c in summary if c["config"] == "default"]
    if default:
        worst = max(c["ratio"] for c in default)
        lines += ["", f"default: worst busy/idle {worst:.2f}x "
                  f"({'within' if worst <= BOUND else 'ABOVE'} the {BOUND}x bound)"]
    return "\n".join(lines)


# %% Figure
def plot(summary: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    configs = list(dict.fromkeys(c["config"] for c in summary))
    sizes = list(dict.fromkeys(c["B"] for c in summary))
    fig, axes = plt.subplots(1, len(sizes), figsize=(4.2 * len(sizes), 3.8), squeeze=False)
    x = np.arange(len(configs))
    for ax, B in zip(axes[0], sizes, strict=True):
        cells = [next(c for c in summary if (c["config"], c["B"]) == (k, B)) for k in configs]
        for off, cond, color in ((-0.2, "idle", "tab:blue"), (0.2, "busy", "tab:red")):
            v = np.array([c[cond] for c in cells])
            err = np.array([[c[cond] - c[f"{cond}_lo"] for c in cells],
                            [c[f"{cond}_hi"] - c[cond] for c in cells]])
            ax.bar(x + off, v, 0.4, yerr=err, color=color, label=cond, capsize=2)
        for xi, c in zip(x, cells, strict=True):
            ax.annotate(f"{c['ratio']:.1f}x", (xi, max(c["idle"], c["busy"])),
                        ha="center", va="bottom", fontsize=8)
        ax.set_ylim(bottom=0)
        ax.set_xticks(x, configs, rotation=20)
        ax.set_title(f"B = {B}")
        ax.set_ylabel("ms per step")
    axes[0][0].legend()
    fig.suptitle("Step time, other cores idle vs busy (label: busy / idle)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# %% Command line
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sizes", default=",".join(map(str, SIZES)), help="batch sizes B")
    p.add_argument("--configs", default=",".join(CONFIGS), help=f"of {list(CONFIGS)}")
    p.add_argument("--repeats", type=int, default=3, help="rounds (default 3)")
    p.add_argument("--blocks", type=int, default=5, help="timed blocks per process")
    p.add_argument("--busy-procs", type=int, default=max(1, (os.cpu_count() or 2) - 1))
    p.add_argument("--shape", default="10,10", help="N,n of the benchmark model")
    p.add_argument("--scenario", help="a registered scenario instead of the benchmark model")
    p.add_argument("--out", type=Path, default=RESULTS, help="directory for the results")
    p.add_argument("--calm", type=float, default=None, metavar="PERCENT",
                   help="before each measurement wait until the CPU pressure (Linux PSI "
                        "'some avg10': others competing for the cores) is at most PERCENT")
    p.add_argument("--max-wait", type=float, default=600, help="seconds --calm waits at most")
    p.add_argument("--smoke", action="store_true",
                   help="tiny run (B = 4, default config, one block of 4 steps)")
    p.add_argument("--from-csv", type=Path, metavar="CSV",
                   help="summarise and plot an earlier run's CSV instead of measuring")
    p.add_argument("--child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        parts = args.child.split(",")  # B, N, n, steps, blocks, warmup[, scenario]
        scenario = parts[6] if len(parts) > 6 else None
        print(json.dumps(child(*(int(v) for v in parts[:6]), scenario=scenario)))
        return 0
    unknown = set(args.configs.split(",")) - set(CONFIGS)
    if unknown:
        p.error(f"unknown configs {sorted(unknown)}; choose from {list(CONFIGS)}")
    N, n = (int(v) for v in args.shape.split(","))
    if args.smoke:
        sizes, configs, repeats, blocks, warmup = (4,), ["default"], 1, 1, 2

        def steps_for(B):
            return 4
    else:
        sizes = tuple(int(b) for b in args.sizes.split(","))
        configs, repeats, blocks = args.configs.split(","), args.repeats, args.blocks
        warmup = 70

        def steps_for(B):  # whole 64-step chunks (each holds one refill), ~20+ ms a block
            return 64 * max(1, 8 // max(1, B // 16)) if B < 128 else 64
    if args.from_csv:
        rows = read_csv(args.from_csv)
    else:
        rows = run(sizes, configs, repeats, blocks, args.busy_procs, N, n, steps_for, warmup,
                   args.calm, args.max_wait, args.scenario)
    summary = summarise(rows)
    text = table(summary, rows, args.busy_procs)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    with (args.out / "bench_busy_cores.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows({k: r[k] for k in COLUMNS} for r in rows)
    (args.out / "bench_busy_cores.txt").write_text(text + "\n")
    plot(summary, args.out / "bench_busy_cores.png")
    print(f"wrote {args.out / 'bench_busy_cores.csv'}, .txt and .png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
