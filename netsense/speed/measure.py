"""Timings of the batched core: speed table, scaling, profile and observation cost.

Every contender comes from :mod:`netsense.speed.runners`; timings are interleaved in one
process and each figure is the best of ``repeats`` blocks (see :mod:`netsense.speed`).
"""

from __future__ import annotations

import cProfile
import math
import pstats
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense.engine.core import BatchedCore
from netsense.speed.runners import (
    _CoreRunner,
    _KernelRunner,
    _ReplayRunner,
    _VmasProcess,
    bench_model,
    vmas_available,
)

#: ``(B, N, n)`` of the speed table (README, batched section).
SHAPES: tuple[tuple[int, int, int], ...] = ((1024, 10, 10), (1024, 30, 20), (64, 100, 20))


def measure_shape(B: int, N: int, n: int, *, steps: int = 64, repeats: int = 3,
                  vmas: bool = True, vmas_budget: float = 20.0,
                  vmas_threads: int | None = None, threads: int | None = None,
                  substates: str = "sources", seed: int = 0) -> dict:
    """Time core, kernel and (optionally) VMAS at one shape; returns one result row.

    Parameters
    ----------
    B, N, n : int
        Batch size, agents, plant dimension.
    steps, repeats : int
        Each rate is the best of ``repeats`` blocks of ``steps`` steps (warm-up first).
    vmas : bool
        Also time VMAS (skipped when not installed).
    vmas_budget : float
        Seconds VMAS may use per repeat; it runs fewer steps (at least 1) when one step
        is slower than ``vmas_budget / steps`` (VMAS scales like ``B N^2``).
    vmas_threads : int or None
        torch threads for VMAS (default: as many as the core's numba threads).
    threads : int or None
        numba threads for the core (default numba's, one per core); the kernel's BLAS
        products use BLAS's own threads (OpenBLAS: one per core).
    substates : {"sources", "all"}
        Substates of the benchmark model (:func:`bench_model`).
    seed : int

    Returns
    -------
    dict
        ``B, N, n, D, obs_dim``, seconds per step ``core_s``, ``policy_s``, ``kernel_s``,
        ``vmas_s`` (NaN if not run), agent-steps/s ``core_rate``, ``kernel_rate``,
        ``vmas_rate``, and ``core_vs_kernel``, ``core_vs_vmas`` (rate ratios).
    """
    import numba

    before = numba.get_num_threads()
    if threads is not None:
        numba.set_num_threads(int(threads))
    try:
        return _measure_shape(B, N, n, steps, repeats, vmas, vmas_budget, vmas_threads,
                              substates, seed)
    finally:
        numba.set_num_threads(before)


def _measure_shape(B, N, n, steps, repeats, vmas, vmas_budget, vmas_threads, substates,
                   seed) -> dict:
    import numba

    model = bench_model(N, n, seed=seed, substates=substates)
    core = _ReplayRunner(model, B, steps, seed)
    live = _CoreRunner(model, B, seed)
    kern = _KernelRunner(core.core, seed)
    vm = None
    if vmas and vmas_available():
        vm = _VmasProcess(B, N, seed, vmas_threads)
    try:
        core.block(2)
        live.block(2)
        kern.block(2)
        vm_steps = steps
        if vm is not None:
            one = vm.block(1)
            vm_steps = int(max(1, min(steps, vmas_budget // max(one, 1e-9))))
        best = {"core": math.inf, "live": math.inf, "kernel": math.inf, "vmas": math.inf}
        for _ in range(repeats):
            best["core"] = min(best["core"], core.block() / steps)
            best["kernel"] = min(best["kernel"], kern.block(steps) / steps)
            best["live"] = min(best["live"], live.block(steps) / steps)
            if vm is not None:
                best["vmas"] = min(best["vmas"], vm.block(vm_steps) / vm_steps)
    finally:
        if vm is not None:
            vm.close()
    c = core.core
    row = {"B": B, "N": N, "n": n, "D": c.D, "M": c.M, "substates": substates,
           "obs_dim": c.layout.size,
           "core_s": best["core"], "policy_s": core.policy_time,
           "core_live_s": best["live"], "kernel_s": best["kernel"],
           "vmas_s": best["vmas"] if vm is not None else math.nan,
           "vmas_steps": vm_steps if vm is not None else 0,
           "vmas_torch_threads": vm.threads if vm is not None else 0,
           "core_threads": numba.get_num_threads()}
    for k in ("core", "kernel", "vmas"):
        s = row[f"{k}_s"]
        row[f"{k}_rate"] = B * N / s if s == s and s > 0 else math.nan
    row["core_vs_kernel"] = row["core_rate"] / row["kernel_rate"]
    row["core_live_vs_kernel"] = best["kernel"] / best["live"]
    row["core_vs_vmas"] = row["core_rate"] / row["vmas_rate"] if vm is not None else math.nan
    return row


def measure(shapes: Sequence[tuple[int, int, int]] = SHAPES, *, steps: int = 64,
            repeats: int = 3, vmas: bool = True, progress: bool = True,
            **kwargs) -> list[dict]:
    """:func:`measure_shape` for every shape (with a tqdm bar)."""
    from tqdm import tqdm

    return [measure_shape(B, N, n, steps=steps, repeats=repeats, vmas=vmas, **kwargs)
            for B, N, n in tqdm(shapes, desc="shapes", disable=not progress)]


def scaling(Ns: Sequence[int] = (10, 20, 40, 80, 160), ns: Sequence[int] = (5, 10, 20, 40, 80),
            *, B: int = 64, N_fixed: int = 30, n_fixed: int = 20, steps: int = 32,
            repeats: int = 3, progress: bool = True) -> list[dict]:
    """Step time of core and kernel against ``N`` (``n = n_fixed``) and ``n`` (``N = N_fixed``).

    Returns rows ``{"axis": "N" or "n", "B", "N", "n", "core_s", "kernel_s", ...}``.
    """
    from tqdm import tqdm

    grid = [("N", N, n_fixed) for N in Ns] + [("n", N_fixed, n) for n in ns]
    rows = []
    for axis, N, n in tqdm(grid, desc="scaling", disable=not progress):
        r = measure_shape(B, N, n, steps=steps, repeats=repeats, vmas=False)
        rows.append({"axis": axis, **r})
    return rows


def loglog_slope(x: Sequence[float], y: Sequence[float]) -> float:
    """Least-squares slope of ``log y`` against ``log x``."""
    lx, ly = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    return float(np.polyfit(lx, ly, 1)[0])


# ----------------------------------------------------------------------------- profile
def profile_core(B: int, N: int, n: int, *, steps: int = 64, top: int = 15,
                 seed: int = 0) -> list[tuple[str, float, float]]:
    """Where ``BatchedCore.step`` spends its time: ``(function, own s/step, share)``.

    cProfile over ``steps`` steps (actions precomputed by the freshness policy on a twin
    core, so only ``step`` is profiled), sorted by own time.
    """
    model = bench_model(N, n, seed=seed)
    twin = _ReplayRunner(model, B, steps, seed)  # records the freshness policy's actions
    acts = [a.astype(np.int64) for a in twin.actions]
    core = BatchedCore(model, B)
    core.reset(seed)
    prof = cProfile.Profile()
    prof.enable()
    for a in acts:
        core.step(a)
    prof.disable()
    st = pstats.Stats(prof)
    total = sum(v[2] for v in st.stats.values())
    rows = []
    for (file, line, fn), v in st.stats.items():
        where = f"{Path(file).name}:{line}({fn})" if file != "~" else fn
        rows.append((where, v[2] / steps, v[2] / total if total else 0.0))
    rows.sort(key=lambda r: -r[1])
    return rows[:top]


def observation_cost(B: int, N: int, n: int, *, steps: int = 64, repeats: int = 3,
                     seed: int = 0) -> dict:
    """Diagnostic: the core's step with and without building observations.

    Replays the same freshness-policy actions (recorded on a twin) on a core stepped with
    observations and on one stepped with ``observe=False`` (no observation array and no
    mask; validation reads the slot table) — what that option saves. Best of
    ``repeats`` interleaved blocks; returns seconds per step ``full_s``, ``no_obs_s``,
    ``kernel_s`` and the rate ratios ``full_vs_kernel``, ``no_obs_vs_kernel``.
    """
    model = bench_model(N, n, seed=seed)
    twin = _ReplayRunner(model, B, steps, seed)  # records the freshness policy's actions
    acts = [a.astype(np.int64) for a in twin.actions]
    full, bare = BatchedCore(model, B), BatchedCore(model, B)
    kern = _KernelRunner(twin.core, seed)
    best = {"full": math.inf, "no_obs": math.inf, "kernel": math.inf}
    for _ in range(repeats):
        for name, core in (("full", full), ("no_obs", bare)):
            core.reset(seed)
            t0 = time.perf_counter()
            for a in acts:
                core.step(a, observe=name == "full")
            best[name] = min(best[name], (time.perf_counter() - t0) / steps)
        best["kernel"] = min(best["kernel"], kern.block(steps) / steps)
    if not np.array_equal(full.Z, bare.Z):
        raise AssertionError("the core stepped without observations diverged from the full one")
    return {"B": B, "N": N, "n": n, "full_s": best["full"], "no_obs_s": best["no_obs"],
            "kernel_s": best["kernel"], "full_vs_kernel": best["kernel"] / best["full"],
            "no_obs_vs_kernel": best["kernel"] / best["no_obs"]}
