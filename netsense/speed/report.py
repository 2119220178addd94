"""What ``netsense bench batched`` prints and writes: the speed table, the verdicts on
the speed targets, CSV files, and the command itself (the :mod:`netsense.cli`
contract: :data:`HELP`, :func:`add_arguments`, :func:`run`; :func:`main` standalone).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from netsense.speed.measure import SHAPES, measure, profile_core
from netsense.speed.memory import memory_footprint


def source_revision(path: str = ".") -> str:
    """Short hash of the last commit touching ``path`` (relative to the netsense checkout;
    ``"."``: the checkout's HEAD) for stamping measured results; ``"?"`` outside a git
    checkout (an installed package)."""
    import subprocess

    root = Path(__file__).resolve().parents[2]
    try:
        return subprocess.run(["git", "log", "-1", "--format=%h", "--", path], cwd=root,
                              capture_output=True, text=True, check=True).stdout.strip() or "?"
    except (OSError, subprocess.CalledProcessError):
        return "?"


#: Speed targets: the core >= 10x VMAS at (1024, 10, 10), >= 0.5x the bare kernel.
TARGET_VS_VMAS = 10.0
TARGET_VS_KERNEL = 0.5


def format_table(rows: Sequence[dict]) -> str:
    """The speed table (Markdown) with the ratios and whether each target is met."""
    head = ("| B | N | n | M | core agent-steps/s | kernel agent-steps/s | VMAS agent-steps/s "
            "| core/kernel | core/VMAS |\n|---|---|---|---|---|---|---|---|---|")
    lines = [head]
    for r in rows:
        vm = "n/a" if r["vmas_rate"] != r["vmas_rate"] else f"{r['vmas_rate']:.3g}"
        cv = "n/a" if r["core_vs_vmas"] != r["core_vs_vmas"] else f"{r['core_vs_vmas']:.2f}x"
        lines.append(f"| {r['B']} | {r['N']} | {r['n']} | {r.get('M', r['N'])} | "
                     f"{r['core_rate']:.3g} | "
                     f"{r['kernel_rate']:.3g} | {vm} | {r['core_vs_kernel']:.2f}x | {cv} |")
    return "\n".join(lines)


def verdicts(rows: Sequence[dict]) -> list[str]:
    """One line per target: met or missed, with the measured ratio."""
    out = []
    for r in rows:
        ok = r["core_vs_kernel"] >= TARGET_VS_KERNEL
        out.append(f"core >= {TARGET_VS_KERNEL:g} x kernel at (B, N, n) = "
                   f"({r['B']}, {r['N']}, {r['n']}): {r['core_vs_kernel']:.3f} -> "
                   f"{'met' if ok else 'MISSED'}")
        if r["B"] == 1024 and r["N"] == 10:
            if r["core_vs_vmas"] == r["core_vs_vmas"]:
                ok = r["core_vs_vmas"] >= TARGET_VS_VMAS
                out.append(f"core >= {TARGET_VS_VMAS:g} x VMAS-CPU at B = 1024, N = 10: "
                           f"{r['core_vs_vmas']:.2f} -> {'met' if ok else 'MISSED'}")
            else:
                out.append("core vs VMAS-CPU at B = 1024, N = 10: not measured (pip "
                           "install vmas)")
    return out


#: One-line help of ``netsense bench batched``.
HELP = ("Agent-steps/s of the batched core vs the bare update kernel and VMAS simple_spread "
        "(targets: >= 10x VMAS, >= 0.5x the kernel), optional profile and memory.")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``netsense bench batched`` (the :mod:`netsense.cli` contract)."""
    p.add_argument("--shapes", nargs="+", default=[",".join(map(str, s)) for s in SHAPES],
                   metavar="B,N,n", help="shapes (default: 1024,10,10 1024,30,20 64,100,20)")
    p.add_argument("--steps", type=int, default=64, help="steps per timed block")
    p.add_argument("--repeats", type=int, default=3, help="blocks per contender (best)")
    p.add_argument("--no-vmas", action="store_true", help="skip VMAS")
    p.add_argument("--vmas-budget", type=float, default=20.0,
                   help="seconds per VMAS block at most (default 20)")
    p.add_argument("--vmas-threads", type=int, default=None,
                   help="torch threads for VMAS (default: as many as the core)")
    p.add_argument("--threads", type=int, default=None,
                   help="numba threads for the core (default: one per core)")
    p.add_argument("--substates", choices=("sources", "all"), default="sources",
                   help="substates of the benchmark model (default: sources, as "
                        "large_n20_N100-v2; 'all' as v1)")
    p.add_argument("--profile", action="store_true", help="print where the core's time goes")
    p.add_argument("--memory", action="store_true",
                   help="measure the state size at B=1024, N=30, n=20")
    p.add_argument("--csv", default=None, help="write the rows to this CSV file")
    p.add_argument("--no-progress", action="store_true")


def run(args: argparse.Namespace) -> int:
    """Run ``netsense bench batched`` with parsed ``args`` (see :func:`add_arguments`)."""
    try:
        shapes = [tuple(int(v) for v in s.split(",")) for s in args.shapes]
    except ValueError:
        raise SystemExit("--shapes takes B,N,n triples of integers") from None
    if any(len(s) != 3 or min(s) < 1 for s in shapes):
        raise SystemExit("--shapes takes B,N,n triples of positive integers")
    if args.steps < 1 or args.repeats < 1:
        raise SystemExit("--steps and --repeats must be >= 1")
    rows = measure(shapes, steps=args.steps, repeats=args.repeats, vmas=not args.no_vmas,
                   progress=not args.no_progress, vmas_budget=args.vmas_budget,
                   vmas_threads=args.vmas_threads, threads=args.threads,
                   substates=args.substates)
    print(format_table(rows))
    for line in verdicts(rows):
        print(line)
    if args.csv:
        write_csv(rows, args.csv)
        print(f"wrote {args.csv}")
    if args.profile:
        for B, N, n in shapes:
            print(f"\nprofile of BatchedCore.step at (B, N, n) = ({B}, {N}, {n}):")
            for where, s, share in profile_core(B, N, n, steps=args.steps):
                print(f"  {share:6.1%}  {s * 1e3:8.2f} ms/step  {where}")
    if args.memory:
        m = memory_footprint()
        print(f"\nstate at (B, N, n) = (1024, 30, 20): {m['state_bytes'] / 1e6:.1f} MB "
              f"(arrays held by the core; chunk = {m['chunk']}), tracemalloc live "
              f"{m['traced_after_steps'] / 1e6:.1f} MB, peak {m['traced_peak'] / 1e6:.1f} MB")
        for name, b in m["largest"]:
            print(f"  {name:20s} {b / 1e6:8.1f} MB")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``netsense bench batched``: agent-steps/s of core, kernel and VMAS; ratios.

    Options: ``--shapes B,N,n ...``, ``--steps``, ``--repeats``, ``--no-vmas``,
    ``--vmas-threads``, ``--profile`` (cProfile of the core at every shape), ``--memory``
    (state size at ``B = 1024, N = 30, n = 20``), ``--csv PATH``.
    """
    p = argparse.ArgumentParser(prog="netsense bench batched", description=HELP)
    add_arguments(p)
    return run(p.parse_args(argv))


def write_csv(rows: Sequence[dict], path: str | Path) -> None:
    """Rows (dicts with the same keys) as CSV."""
    import csv

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    keys = list(rows[0])
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k) for k in keys})
