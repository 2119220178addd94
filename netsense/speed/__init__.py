"""Measured speed and memory of the batched core (issue 8, items 4 and 5).

What is measured, in one process and interleaved (so a noisy, shared machine slows every
contender alike; compare the *ratios*):

``core``
    :meth:`netsense.envcore.BatchedCore.step` on ``B`` members of :func:`bench_model`
    (``N`` agents, plant dimension ``n``, Markov link failures on a circulant graph with
    in-degree ``D = 3``, measurement noise), replaying ``steps`` freshness-policy actions
    recorded on a twin core from the same seed. Only ``step`` is timed (graphs/noise
    refills, validation, update, rewards and the full observations and masks included),
    in a loop of its own work like the kernel; the policy's time is reported apart.
``core_live``
    The same core with the freshness policy computed between the steps (only ``step``
    timed): the policy's numpy passes (17 ms per step at ``B = 1024, N = 30``) evict the
    core's arrays from the caches and its threads fall asleep, so this figure is lower
    and noisier; it is reported for transparency, the ratios use ``core``.
``kernel``
    The bare numpy update on the same arrays — the roofline of issue 8: gather of the
    chosen agents' estimates (one flat ``np.take``) and the batched block-triangular
    multiply (two BLAS products), nothing else; written in plain numpy in this module.
``vmas``
    VMAS ``simple_spread`` on CPU with ``B`` environments and ``N`` agents (zero
    continuous actions), when ``vmas`` is installed.

Rates are agent-steps/s ``= B N / (time of one step)``; each figure is the best of
``repeats`` blocks of ``steps`` steps. Targets (issue 8): core >= 10x VMAS at
``B = 1024, N = 10`` and core >= 0.5x the kernel at every shape.

Run ``python -m netsense.speed`` or :func:`main`; ``netsense bench batched`` is this
module's :data:`HELP`, :func:`add_arguments` and :func:`run` (the :mod:`netsense.cli`
contract), and ``experiments/bench_batched.py`` adds the profile, the scaling figure, the
memory figures and the CSV files.
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import math
import os
import pstats
import time
import tracemalloc
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense.envcore import BatchedCore, CoreModel

#: ``(B, N, n)`` of issue 8, item 4.
SHAPES: tuple[tuple[int, int, int], ...] = ((1024, 10, 10), (1024, 30, 20), (64, 100, 20))
#: Targets of issue 8.
TARGET_VS_VMAS = 10.0
TARGET_VS_KERNEL = 0.5

__all__ = ["HELP", "SHAPES", "add_arguments", "allocation_growth", "bench_model",
           "core_state_bytes", "main", "measure", "measure_shape", "memory_footprint",
           "observation_cost", "profile_core", "run", "scaling"]


# ----------------------------------------------------------------------------- model
def bench_model(N: int, n: int, *, seed: int = 0, horizon: int = 200,
                offsets: Sequence[int] = (1, 3, 7), substates: str = "sources"
                ) -> CoreModel:
    """The benchmark scenario at size ``(N, n)``.

    ``large_n20_N100-v2`` resized: ``random_structured(n, N)`` plant (spectral radius
    1.1; ``min(n, N, max(2, N // 2))`` sources), Markov link failures (fail 0.1, recover
    0.5, one uniform per base link) on the circulant graph with the given offsets
    (in-degree ``D = len(offsets)``), Gaussian measurement noise 0.01; indices, actions
    and observations over the sources (``substates="all"``: over every agent, as
    ``large_n20_N100-v1``).
    """
    from netsense.scenarios import build_model, load, with_overrides

    offs = sorted({int(o) % N for o in offsets} - {0})
    if not offs:
        raise ValueError(f"offsets {list(offsets)} give no edge for N = {N}")
    sc = with_overrides(
        load("large_n20_N100-v2"), horizon=int(horizon), substates=substates,
        plant={"kind": "random_structured", "n": int(n), "num_agents": int(N),
               "seed": int(seed), "spectral_radius": 1.1},
        graph={"kind": "markov", "num_nodes": int(N), "p_fail": 0.1, "p_recover": 0.5,
               "draws": "base", "base": {"kind": "circulant", "offsets": offs}})
    return build_model(sc)


# ----------------------------------------------------------------------------- timers
class _CoreRunner:
    """A core under the freshness policy; ``block(steps)`` returns seconds in ``step``."""

    def __init__(self, model: CoreModel, B: int, seed: int = 0) -> None:
        from netsense.policies import FreshnessPolicy

        self.core = BatchedCore(model, B)
        self.policy = FreshnessPolicy(self.core.layout)
        self.obs, self.mask = self.core.reset(seed)
        self.policy_time = 0.0
        self.policy_steps = 0

    def block(self, steps: int) -> float:
        core, pol = self.core, self.policy
        total = 0.0
        for _ in range(steps):
            t0 = time.perf_counter()
            act = pol.act(self.obs, self.mask)
            t1 = time.perf_counter()
            out = core.step(act)
            total += time.perf_counter() - t1
            self.policy_time += t1 - t0
            self.policy_steps += 1
            self.obs, self.mask = out.obs, out.action_mask
            if out.truncated.any():  # stay inside the horizon (reset is not timed)
                self.obs, self.mask = core.reset(int(core.k.sum()))
        return total


class _ReplayRunner:
    """The core stepping through ``steps`` freshness-policy actions recorded on a twin
    core from the same seed (so every action is valid); ``block()`` resets (not timed)
    and times the replay: the core in a hot loop of its own work, like the kernel."""

    def __init__(self, model: CoreModel, B: int, steps: int, seed: int = 0) -> None:
        from netsense.policies import FreshnessPolicy

        twin = BatchedCore(model, B)
        pol = FreshnessPolicy(twin.layout)
        obs, mask = twin.reset(seed)
        self.actions = []
        self.policy_time = 0.0
        for _ in range(steps):
            t0 = time.perf_counter()
            act = pol.act(obs, mask)
            self.policy_time += time.perf_counter() - t0
            self.actions.append(act.astype(np.int8))  # choices <= D + 1: small to keep
            out = twin.step(act)
            obs, mask = out.obs, out.action_mask
        self.policy_time /= steps
        self.core = BatchedCore(model, B)
        self.seed = seed

    def block(self, steps: int | None = None) -> float:
        core = self.core
        core.reset(self.seed)
        total = 0.0
        for a8 in self.actions[:steps]:
            act = a8.astype(np.int64)  # the policy's dtype, converted before timing
            t0 = time.perf_counter()
            core.step(act)
            total += time.perf_counter() - t0
        return total


class _KernelRunner:
    """The bare numpy update: gather of chosen estimates + block-triangular multiply.

    Written here in plain numpy (the roofline of issue 8), not with the package's compiled
    kernels: one flat ``np.take`` for ``Z[b, src[b, i, block_of[c]], c]`` and the two
    matrix products ``Z_sel A_diag^T + Z A_lower^T`` (BLAS, with its own threads).
    """

    def __init__(self, core: BatchedCore, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        B, N, n = core.B, core.N, core.n
        self.Z = rng.standard_normal((B, N, n))
        self.srcs = [rng.integers(0, N, size=(B, N, N)) for _ in range(4)]
        self.block_of = core.block_of
        self.A_diag_T = np.ascontiguousarray(core.A_diag.T)
        self.A_lower_T = np.ascontiguousarray(core.A_lower.T)
        self.offset = np.arange(B)[:, None, None] * (N * n) + np.arange(n)

    def block(self, steps: int) -> float:
        Z, n = self.Z, self.Z.shape[2]
        t0 = time.perf_counter()
        for k in range(steps):
            idx = np.take(self.srcs[k % 4], self.block_of, axis=2)  # (B, N, n)
            idx *= n
            idx += self.offset
            Z_sel = np.take(Z.reshape(-1), idx)
            Z = Z_sel @ self.A_diag_T + Z @ self.A_lower_T
            Z *= 0.5  # keep the values bounded (one cheap pass; part of no rule)
        return time.perf_counter() - t0


class _VmasRunner:
    """VMAS ``simple_spread`` on CPU (torch) with zero continuous actions, ``threads``
    torch threads (None: as many as the core uses)."""

    def __init__(self, B: int, N: int, seed: int = 0, threads: int | None = None) -> None:
        import torch
        import vmas

        if threads is None:
            import numba

            threads = numba.get_num_threads()
        if threads is not None:
            # like the numpy core (one thread); on a loaded machine torch's default
            # thread pool is much slower and erratic (oversubscription)
            torch.set_num_threads(int(threads))
        self.env = vmas.make_env("simple_spread", num_envs=B, device="cpu",
                                 continuous_actions=True, seed=seed, n_agents=N)
        self.env.reset()
        self.actions = [torch.zeros(B, 2) for _ in range(N)]
        self.threads = torch.get_num_threads()

    def block(self, steps: int) -> float:
        t0 = time.perf_counter()
        for _ in range(steps):
            self.env.step(self.actions)
        return time.perf_counter() - t0


def vmas_available() -> bool:
    """Whether ``vmas`` can be imported."""
    try:
        import vmas  # noqa: F401
    except ImportError:
        return False
    return True


# ----------------------------------------------------------------------------- measure
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
        vm = _VmasRunner(B, N, seed, vmas_threads)
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


# ----------------------------------------------------------------------------- memory
def core_state_bytes(core: BatchedCore) -> dict[str, int]:
    """Bytes of every numpy array the core holds (its attributes, one level deep into
    lists, tuples and dicts); views are counted once at their base."""
    seen: set[int] = set()
    out: dict[str, int] = {}

    def add(name: str, a: np.ndarray) -> None:
        base = a if a.base is None else a.base
        while isinstance(base, np.ndarray) and base.base is not None:
            base = base.base
        if id(base) in seen or not isinstance(base, np.ndarray):
            return
        seen.add(id(base))
        out[name] = out.get(name, 0) + int(base.nbytes)

    for name, v in vars(core).items():
        if isinstance(v, np.ndarray):
            add(name, v)
        elif isinstance(v, (list, tuple)):
            for item in v:
                if isinstance(item, np.ndarray):
                    add(name, item)
        elif isinstance(v, dict):
            for item in v.values():
                if isinstance(item, np.ndarray):
                    add(name, item)
    src = getattr(core, "source", None)
    for name, v in vars(src).items() if src is not None else ():
        if isinstance(v, np.ndarray):
            add(f"source.{name}", v)
    return out


def memory_footprint(B: int = 1024, N: int = 30, n: int = 20, *, steps: int = 64,
                     seed: int = 0) -> dict:
    """State size of the core at ``(B, N, n)``, measured three ways.

    Returns
    -------
    dict
        ``state_bytes`` (sum of :func:`core_state_bytes` after ``steps`` steps),
        ``largest`` (the five largest arrays), ``traced_after_reset`` and
        ``traced_after_steps`` (tracemalloc: memory allocated by the core and still alive,
        incl. the last step's observations and masks), ``traced_peak`` (tracemalloc peak
        over reset + steps: state plus the transient temporaries of one step).
    """
    from netsense.policies import FreshnessPolicy

    model = bench_model(N, n, seed=seed)
    gc.collect()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        core = BatchedCore(model, B)
        obs, mask = core.reset(seed)
        after_reset = tracemalloc.get_traced_memory()[0] - base
        pol = FreshnessPolicy(core.layout)
        for _ in range(steps):
            out = core.step(pol.act(obs, mask))
            obs, mask = out.obs, out.action_mask
        del out
        gc.collect()
        after_steps = tracemalloc.get_traced_memory()[0] - base
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    sizes = core_state_bytes(core)
    largest = sorted(sizes.items(), key=lambda kv: -kv[1])[:5]
    return {"B": B, "N": N, "n": n, "state_bytes": int(sum(sizes.values())),
            "largest": largest, "traced_after_reset": int(after_reset),
            "traced_after_steps": int(after_steps), "traced_peak": int(peak),
            "chunk": int(getattr(core, "chunk", 0))}


def _rss_bytes() -> int:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:  # pragma: no cover - non-Linux
        import resource

        return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


def allocation_growth(steps: int = 100_000, *, scenario: str = "link_failures-v0",
                      B: int = 8, every: int = 1000, seed: int = 0,
                      progress: bool = True, top: int = 5) -> tuple[list[dict], list[str]]:
    """Run ``steps`` steps of :class:`netsense.vector.BatchedEnv` (auto-reset, freshness
    policy) under tracemalloc and sample the live allocations and the RSS.

    The sample buffers are allocated before tracing starts, so the bookkeeping itself does
    not count. Returns the rows ``{"step", "traced_bytes", "rss_bytes", "episodes"}``
    (every ``every`` steps) and the ``top`` source lines whose live allocations grew most
    between the first sample and the end (tracemalloc snapshot difference).
    """
    from tqdm import tqdm

    from netsense.policies import FreshnessPolicy
    from netsense.vector import BatchedEnv

    env = BatchedEnv(scenario, B)
    pol = FreshnessPolicy(env.layout)
    obs, info = env.reset(seed=seed)
    m = steps // every
    traced = np.zeros(m, dtype=np.int64)
    rss = np.zeros(m, dtype=np.int64)
    eps = np.zeros(m, dtype=np.int64)
    episodes = np.zeros(1, dtype=np.int64)
    bar = tqdm(total=steps, desc="steps", disable=not progress, mininterval=2.0)
    gc.collect()
    tracemalloc.start()
    first = None
    try:
        for k in range(1, steps + 1):
            obs, rew, term, trunc, info = env.step(pol.act(obs, info["action_mask"]))
            episodes += (term | trunc).sum()
            if k % every == 0:
                j = k // every - 1
                traced[j] = tracemalloc.get_traced_memory()[0]
                rss[j] = _rss_bytes()
                eps[j] = episodes[0]
                if j == 0:
                    first = tracemalloc.take_snapshot()
                bar.update(every)
        last = tracemalloc.take_snapshot()
    finally:
        tracemalloc.stop()
        bar.close()
    diff = [] if first is None else [
        str(d) for d in last.compare_to(first, "lineno")[:top]]
    rows = [{"step": (j + 1) * every, "traced_bytes": int(traced[j]),
             "rss_bytes": int(rss[j]), "episodes": int(eps[j])} for j in range(m)]
    return rows, diff


# ----------------------------------------------------------------------------- profile
def profile_core(B: int, N: int, n: int, *, steps: int = 64, top: int = 15,
                 seed: int = 0) -> list[tuple[str, float, float]]:
    """Where ``BatchedCore.step`` spends its time: ``(function, own s/step, share)``.

    cProfile over ``steps`` steps (actions precomputed by the freshness policy on a twin
    core, so only ``step`` is profiled), sorted by own time.
    """
    model = bench_model(N, n, seed=seed)
    twin = _CoreRunner(model, B, seed)
    acts = []
    for _ in range(steps):
        a = twin.policy.act(twin.obs, twin.mask)
        acts.append(a)
        out = twin.core.step(a)
        twin.obs, twin.mask = out.obs, out.action_mask
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
    twin = _CoreRunner(model, B, seed)
    acts = []
    for _ in range(steps):
        a = twin.policy.act(twin.obs, twin.mask)
        acts.append(a)
        out = twin.core.step(a)
        twin.obs, twin.mask = out.obs, out.action_mask
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
        "(issue 8 targets), optional profile and memory.")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``netsense bench batched`` (the :mod:`netsense.cli` contract)."""
    p.add_argument("--shapes", nargs="+", default=[",".join(map(str, s)) for s in SHAPES],
                   metavar="B,N,n", help="shapes (default: the three of issue 8)")
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


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
