"""Speed and memory of the batched core.

In one run (so every contender sees the same machine load; compare ratios):

1. agent-steps/s of :class:`netsense.engine.core.BatchedCore` at ``(B, N, n)`` in
   {(1024, 10, 10), (1024, 30, 20), (64, 100, 20)}, of the bare update kernel on the same
   arrays (gather + block-triangular multiply) and of VMAS ``simple_spread`` on CPU
   (:func:`netsense.speed.measure`);
   a cProfile of the core's step at each shape (:func:`netsense.speed.profile_core`) and
   its step time without building observations (:func:`netsense.speed.observation_cost`);
2. step time against ``N`` (``n = 20``) and against ``n`` (``N = 30``) at ``B = 64``, as
   a log-log figure with fitted slopes (:func:`netsense.speed.scaling`);
3. the state size at ``B = 1024, N = 30, n = 20`` (:func:`netsense.speed.memory_footprint`);
4. live allocations and RSS over ``--growth-steps`` steps (default ``10^5``) of the
   auto-resetting array API (:func:`netsense.speed.allocation_growth`).

Writes, into ``experiments/results/bench/batched/``, ``bench_batched.csv`` (speed table),
``bench_batched_scaling.csv`` / ``.png``, ``bench_batched_growth.csv`` / ``.png`` and one
``bench_batched_<section>.txt`` per section (speed, profile, observations, scaling, memory,
growth) headed by the commits measured.

Run: ``python experiments/bench/batched.py`` (about 10-15 minutes on 2 shared cores;
``--smoke`` for a seconds-long check).
"""

# %%
from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense import speed

RESULTS = Path(__file__).resolve().parents[1] / "results" / "bench" / "batched"


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# %% Figures
def plot_scaling(rows: list[dict], path: Path) -> dict[str, float]:
    """Log-log step time (per member) against N and n, with slopes; returns the slopes."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    slopes = {}
    for ax, axis in zip(axes, ("N", "n"), strict=True):
        rs = [r for r in rows if r["axis"] == axis]
        if not rs:
            continue
        x = np.array([r[axis] for r in rs], float)
        B = rs[0]["B"]
        for key, label, style in (("core_s", "batched core step", "o-"),
                                  ("kernel_s", "bare kernel (gather + multiply)", "s--")):
            y = np.array([r[key] for r in rs]) / B * 1e6  # microseconds per member-step
            s = speed.loglog_slope(x, y)
            slopes[f"{key[:-2]}_vs_{axis}"] = s
            ax.loglog(x, y, style, label=f"{label}: slope {s:.2f}")
        y0 = np.array([r["core_s"] for r in rs])[0] / B * 1e6
        for p, ls in ((1, ":"), (2, "-.")):
            ax.loglog(x, y0 * (x / x[0]) ** p, ls, color="gray", lw=0.8,
                      label=f"~ {axis}^{p}")
        fixed = (f"n = {rs[0]['n']}" if axis == "N" else f"N = {rs[0]['N']}")
        ax.set_xticks(x)
        ax.set_xticklabels([f"{v:g}" for v in x])
        ax.minorticks_off()
        ax.set_xlabel(axis)
        ax.set_title(f"step time vs {axis} ({fixed}, B = {B}, D = {rs[0]['D']})")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("microseconds per member-step")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return slopes


def growth_rates(rows: list[dict], parts: int = 4) -> list[tuple[int, int, float]]:
    """``(first step, last step, bytes per step)`` of the live allocations per part."""
    k = np.array([r["step"] for r in rows])
    t = np.array([r["traced_bytes"] for r in rows], dtype=float)
    out = []
    for idx in np.array_split(np.arange(len(rows)), parts):
        if len(idx) >= 2:
            a, b = idx[0], idx[-1]
            out.append((int(k[a]), int(k[b]), float((t[b] - t[a]) / (k[b] - k[a]))))
    return out


def plot_growth(rows: list[dict], path: Path) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    k = [r["step"] for r in rows]
    ax.plot(k, [r["traced_bytes"] / 1e6 for r in rows], label="tracemalloc live (MB)")
    ax.plot(k, [r["rss_bytes"] / 1e6 for r in rows], label="RSS (MB)")
    ax.set_xlabel("step")
    ax.set_ylabel("MB")
    ax.set_title("allocations over a long auto-resetting run")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# %% Main
def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--steps", type=int, default=64, help="steps per timed block")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--growth-steps", type=int, default=100_000)
    p.add_argument("--no-vmas", action="store_true")
    p.add_argument("--skip", nargs="*", default=[],
                   choices=["speed", "profile", "observations", "scaling", "memory",
                            "growth"])
    p.add_argument("--smoke", action="store_true", help="tiny shapes, seconds")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    prog = not args.no_progress
    stem = "bench_batched_smoke" if args.smoke else "bench_batched"
    if args.smoke:
        shapes, steps, rep = [(8, 6, 4), (4, 12, 6)], 4, 1
        Ns, ns, sB, mem, growth = (6, 12), (4, 8), 4, (16, 6, 4), 200
    else:
        shapes, steps, rep = speed.SHAPES, args.steps, args.repeats
        Ns, ns, sB, mem, growth = (10, 20, 40, 80, 160), (5, 10, 20, 40, 80), 64, \
            (1024, 30, 20), args.growth_steps
    sections: dict[str, list[str]] = {}
    # %% 1. speed table
    if "speed" not in args.skip:
        rows = speed.measure(shapes, steps=steps, repeats=rep, vmas=not args.no_vmas,
                             progress=prog)
        speed.write_csv(rows, out / f"{stem}.csv")
        lines = [speed.format_table(rows), ""] + speed.verdicts(rows)
        print("\n".join(lines))
        sections["speed"] = lines
    # %% 1b. where the core's time goes
    if "profile" not in args.skip:
        lines = []
        for B, N, n in shapes:
            lines.append(f"cProfile of BatchedCore.step at (B, N, n) = ({B}, {N}, {n}), "
                         f"{steps} steps (own time per function):")
            for where, sec, share in speed.profile_core(B, N, n, steps=steps):
                lines.append(f"  {share:6.1%}  {sec * 1e3:8.2f} ms/step  {where}")
        print("\n".join(lines))
        sections["profile"] = lines
    # %% 1c. what building the observations costs
    if "observations" not in args.skip:
        lines = ["core step with and without building observations (same actions), vs the "
                 "bare kernel:"]
        for B, N, n in shapes:
            o = speed.observation_cost(B, N, n, steps=steps, repeats=rep)
            lines.append(f"  (B, N, n) = ({B}, {N}, {n}): full {o['full_s'] * 1e3:.2f} ms, "
                         f"without observations {o['no_obs_s'] * 1e3:.2f} ms, kernel "
                         f"{o['kernel_s'] * 1e3:.2f} ms per step -> core/kernel "
                         f"{o['full_vs_kernel']:.3f} (full), {o['no_obs_vs_kernel']:.3f} "
                         "(without observations)")
        print("\n".join(lines))
        sections["observations"] = lines
    # %% 2. scaling in N and n
    if "scaling" not in args.skip:
        srows = speed.scaling(Ns, ns, B=sB, N_fixed=min(30, max(Ns)), n_fixed=min(20, max(ns)),
                              steps=max(steps // 2, 2), repeats=rep, progress=prog)
        speed.write_csv(srows, out / f"{stem}_scaling.csv")
        slopes = plot_scaling(srows, out / f"{stem}_scaling.png")
        line = "log-log slopes: " + ", ".join(f"{k} {v:.2f}" for k, v in slopes.items())
        print(line)
        sections["scaling"] = [line]
    # %% 3. memory of the state
    if "memory" not in args.skip:
        m = speed.memory_footprint(*mem)
        lines = [f"state at (B, N, n) = {mem}: {m['state_bytes'] / 1e6:.1f} MB in the "
                 f"core's arrays (chunk = {m['chunk']} steps pre-drawn); tracemalloc: "
                 f"{m['traced_after_reset'] / 1e6:.1f} MB after reset, "
                 f"{m['traced_after_steps'] / 1e6:.1f} MB live after steps (state + last "
                 f"observation and mask), peak {m['traced_peak'] / 1e6:.1f} MB (incl. "
                 "one step's temporaries)",
                 "largest arrays: " + ", ".join(f"{k} {v / 1e6:.1f} MB"
                                                for k, v in m["largest"])]
        print("\n".join(lines))
        sections["memory"] = lines
    # %% 4. allocation growth over many steps
    if "growth" not in args.skip:
        grow, diff = speed.allocation_growth(growth, every=max(growth // 100, 1),
                                             progress=prog)
        speed.write_csv(grow, out / f"{stem}_growth.csv")
        plot_growth(grow, out / f"{stem}_growth.png")
        g0, g1 = grow[0], grow[-1]
        line = (f"{g1['step']} steps (B = 8, link_failures-v0, {g1['episodes']} episodes "
                f"with auto-reset): live allocations {g0['traced_bytes'] / 1e6:.3f} MB at "
                f"step {g0['step']} -> {g1['traced_bytes'] / 1e6:.3f} MB at the end "
                f"(max {max(r['traced_bytes'] for r in grow) / 1e6:.3f} MB); RSS "
                f"{g0['rss_bytes'] / 1e6:.1f} -> {g1['rss_bytes'] / 1e6:.1f} MB")
        lines = [line, "growth rate of the live allocations per quarter of the run: "
                 + ", ".join(f"steps {a}-{b}: {v:.3f} B/step"
                             for a, b, v in growth_rates(grow)),
                 "largest growth by source line (first sample -> end):"] + diff
        print("\n".join(lines))
        sections["growth"] = lines
    rev = speed.source_revision
    head = [f"netsense {rev()}, engine/core.py at {rev('netsense/engine/core.py')}, "
            f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}"]
    for name, lines in sections.items():
        (out / f"{stem}_{name}.txt").write_text("\n".join(head + lines) + "\n")
    print(f"wrote {out}/{stem}*")
    return 0


if __name__ == "__main__":
    sys.exit(main())
