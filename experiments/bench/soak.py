"""Soak test: does a long training run's memory stay flat after warm-up?

Runs ``netsense train SCENARIO --steps STEPS`` at the defaults (the TorchRL trainer, its
overlapped collection thread, periodic evaluations and checkpoints, ``log.csv``) in a
subprocess and samples the resident memory (RSS, from ``/proc``) of that process and all
its children every ``--interval`` seconds, with the agent-steps the run has logged so far
(the last row of its ``log.csv``). Linux only (``/proc``).

Writes into ``--out`` (default ``experiments/results/bench/soak``):

* ``soak.csv``: one row per sample: wall seconds, agent-steps, RSS (MiB) of the tree;
* ``soak.png``: RSS against agent-steps, the warm-up's end marked;
* ``soak.txt``: RSS at the end of warm-up (the first ``--warmup`` of the steps) and at
  the end, the medians of the first and the last fifth of the samples after warm-up, and
  the least-squares slope of RSS against agent-steps after warm-up, in MiB per 10M
  agent-steps.

Usage::

    python experiments/bench/soak.py                        # 50M agent-steps
    python experiments/bench/soak.py --steps 2000000 --interval 0.5   # a quick look
    python experiments/bench/soak.py --replot      # soak.txt and soak.png from soak.csv

The training run writes into a temporary folder, removed at the end.
"""

# %%
from __future__ import annotations

import argparse
import csv
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments" / "results" / "bench" / "soak"
PAGE = os.sysconf("SC_PAGE_SIZE")


def tree(pid: int) -> list[int]:
    """``pid`` and its descendants (from ``/proc/*/stat``)."""
    parent: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        # the command name is in parentheses and may hold spaces
        fields = stat[stat.rindex(")") + 2:].split()
        parent[int(entry.name)] = int(fields[1])
    found, frontier = [pid], [pid]
    while frontier:
        p = frontier.pop()
        kids = [c for c, pp in parent.items() if pp == p]
        found += kids
        frontier += kids
    return found


def rss_mib(pid: int) -> float:
    """Resident memory of ``pid`` and its descendants, MiB (``/proc/<pid>/statm``)."""
    total = 0
    for p in tree(pid):
        try:
            total += int(Path(f"/proc/{p}/statm").read_text().split()[1]) * PAGE
        except (OSError, IndexError, ValueError):
            continue
    return total / 2**20


def logged_steps(log: Path) -> int:
    """Agent-steps of the last complete row of a run's ``log.csv`` (0 before the first)."""
    try:
        with log.open("rb") as fh:
            fh.seek(0, os.SEEK_END)
            size = fh.tell()
            fh.seek(max(0, size - 65536))
            tail = fh.read().decode(errors="replace")
            fh.seek(0)
            header = fh.readline().decode().strip().split(",")
    except OSError:
        return 0
    if not tail.endswith("\n"):  # the row being written: not complete yet
        tail = tail[:tail.rfind("\n") + 1]
    lines = [ln for ln in tail.splitlines() if ln.strip()]
    if len(lines) < 2 or "agent_steps" not in header:
        return 0
    row = next(csv.reader([lines[-1]]))
    try:
        return int(float(row[header.index("agent_steps")]))
    except (ValueError, IndexError):
        return 0


def fit(rows: list[dict], warmup_steps: float) -> dict:
    """RSS at warm-up end and at the end; slope after warm-up (MiB per 10M agent-steps)."""
    steps = np.array([r["agent_steps"] for r in rows], float)
    rss = np.array([r["rss_mib"] for r in rows], float)
    after = steps >= warmup_steps
    out = {"samples": len(rows), "warmup_steps": int(warmup_steps),
           "peak_mib": float(rss.max()) if len(rss) else float("nan")}
    if after.sum() >= 2 and np.ptp(steps[after]) > 0:
        slope = np.polyfit(steps[after], rss[after], 1)[0]
        tail = rss[after]
        fifth = max(1, len(tail) // 5)
        out.update(warmup_end_mib=float(rss[after][0]), end_mib=float(rss[-1]),
                   first_fifth_median_mib=float(np.median(tail[:fifth])),
                   last_fifth_median_mib=float(np.median(tail[-fifth:])),
                   slope_mib_per_10m=float(slope * 1e7),
                   after_min_mib=float(rss[after].min()),
                   after_max_mib=float(rss[after].max()))
    return out


def plot(rows: list[dict], summary: dict, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 3.6))
    ax.plot([r["agent_steps"] / 1e6 for r in rows], [r["rss_mib"] for r in rows], lw=1.0)
    ax.axvline(summary["warmup_steps"] / 1e6, ls=":", color="C1", label="end of warm-up")
    ax.set_xlabel("agent-steps (millions)")
    ax.set_ylabel("RSS of the run's processes (MiB)")
    ax.set_title(title, fontsize=9)
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="comm_process_noise-v0")
    p.add_argument("--steps", type=int, default=50_000_000, help="agent-steps (default 50M)")
    p.add_argument("--interval", type=float, default=2.0, help="seconds between samples")
    p.add_argument("--warmup", type=float, default=0.1,
                   help="fraction of the steps counted as warm-up (default 0.1)")
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument("--replot", action="store_true",
                   help="no run: soak.txt and soak.png again from --out's soak.csv")
    p.add_argument("train_args", nargs="*", help="more `netsense train` flags (after --)")
    args = p.parse_args(argv)
    if args.replot:
        with (args.out / "soak.csv").open() as fh:
            rows = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(fh)]
        cmd = [sys.executable, "-m", "netsense.cli", "train", args.scenario]
        report(args, rows, cmd, rows[-1]["wall_s"])
        return 0
    from tqdm.auto import tqdm

    args.out.mkdir(parents=True, exist_ok=True)
    run = Path(tempfile.mkdtemp(prefix="netsense-soak-"))
    cmd = [sys.executable, "-m", "netsense.cli", "train", args.scenario, "--steps",
           str(args.steps), "--out", str(run), "--no-progress", *args.train_args]
    print(" ".join(cmd[1:]), flush=True)
    rows: list[dict] = []
    t0 = time.perf_counter()
    # the child's output goes to a file, not a pipe: a pipe read only after the exit would
    # block a child that printed more than the pipe's buffer
    out_file = (run / "train.out").open("w+")
    proc = subprocess.Popen(cmd, stdout=out_file, stderr=subprocess.STDOUT, text=True)
    log = run / "seed_0" / "log.csv"
    bar = tqdm(total=args.steps, unit="agent-step", unit_scale=True, desc="soak",
               mininterval=5.0)
    try:
        while proc.poll() is None:
            steps = logged_steps(log)
            sample = {"wall_s": round(time.perf_counter() - t0, 2), "agent_steps": steps,
                      "rss_mib": round(rss_mib(proc.pid), 1)}
            if sample["rss_mib"] <= 0 or proc.poll() is not None:
                # it exited while being sampled: an exiting or exited, unreaped process
                # reads as 0 MiB in /proc, which is not its memory, so the sample is dropped
                break
            rows.append(sample)
            bar.update(steps - bar.n)
            bar.set_postfix(rss=f"{rows[-1]['rss_mib']:.0f} MiB")
            time.sleep(args.interval)
        proc.wait()
        out_file.seek(0)
        text = out_file.read()
    finally:
        bar.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        out_file.close()
        shutil.rmtree(run, ignore_errors=True)
    print(text)
    if proc.returncode != 0:
        print(f"training failed (exit {proc.returncode})", file=sys.stderr)
        return 1
    rows = [r for r in rows if r["agent_steps"] > 0]  # before the first iteration: start-up
    with (args.out / "soak.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["wall_s", "agent_steps", "rss_mib"])
        w.writeheader()
        w.writerows(rows)
    report(args, rows, cmd, time.perf_counter() - t0)
    return 0


def report(args, rows: list[dict], cmd: list[str], wall: float) -> None:
    """``soak.png`` and ``soak.txt`` (printed too) from the samples."""
    summary = fit(rows, args.warmup * args.steps)
    nan = float("nan")
    title = f"netsense train {args.scenario} --steps {args.steps:,}: RSS vs agent-steps"
    plot(rows, summary, args.out / "soak.png", title)
    lines = [" ".join(["netsense", *cmd[3:5], "--steps", str(args.steps),
                       *args.train_args]),
             f"wall {wall:.0f} s, {summary['samples']} samples every {args.interval:g} s",
             f"RSS at the end of warm-up ({summary['warmup_steps']:,} agent-steps): "
             f"{summary.get('warmup_end_mib', nan):.0f} MiB",
             f"RSS at the end: {summary.get('end_mib', nan):.0f} MiB "
             f"(after warm-up: min {summary.get('after_min_mib', nan):.0f}, max "
             f"{summary.get('after_max_mib', nan):.0f}; peak "
             f"{summary['peak_mib']:.0f})",
             f"median RSS of the first and the last fifth after warm-up: "
             f"{summary.get('first_fifth_median_mib', nan):.0f} and "
             f"{summary.get('last_fifth_median_mib', nan):.0f} MiB",
             f"slope after warm-up: {summary.get('slope_mib_per_10m', nan):+.1f} "
             "MiB per 10M agent-steps"]
    (args.out / "soak.txt").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


# %%
if __name__ == "__main__":
    sys.exit(main())
