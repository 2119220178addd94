"""Memory of the batched core: the arrays it holds and whether long runs grow.

:func:`core_state_bytes` and :func:`memory_footprint` measure the state at one shape;
:func:`allocation_growth` samples tracemalloc and the RSS over a long auto-resetting run.
"""

from __future__ import annotations

import gc
import os
import tracemalloc

import numpy as np

from netsense.engine.core import BatchedCore
from netsense.engine.observation import FillBuffers
from netsense.kernels.update import StepBuffers
from netsense.speed.runners import bench_model


# ----------------------------------------------------------------------------- memory
def core_state_bytes(core: BatchedCore) -> dict[str, int]:
    """Bytes of every numpy array the core holds (its attributes, one level deep into
    lists, tuples and dicts, and its working buffers); views are counted once at their
    base."""
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
                elif isinstance(item, StepBuffers):
                    _add_buffers(add, name, item)
        elif isinstance(v, FillBuffers):
            _add_buffers(add, name, v)
        elif isinstance(v, dict):
            for item in v.values():
                if isinstance(item, np.ndarray):
                    add(name, item)
    src = getattr(core, "source", None)
    for name, v in vars(src).items() if src is not None else ():
        if isinstance(v, np.ndarray):
            add(f"source.{name}", v)
    return out


def _add_buffers(add, name: str, buffers) -> None:
    """The working buffers' arrays (:class:`~netsense.kernels.update.StepBuffers`,
    :class:`~netsense.engine.observation.FillBuffers`), their scratch tuple included."""
    for v in vars(buffers).values():
        for a in v if isinstance(v, tuple) else (v,):
            if isinstance(a, np.ndarray):
                add(name, a)


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
    from netsense.env.policies import FreshnessPolicy

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
    """Run ``steps`` steps of :class:`netsense.env.vector.BatchedEnv` (auto-reset, freshness
    policy) under tracemalloc and sample the live allocations and the RSS.

    The sample buffers are allocated before tracing starts, so the bookkeeping itself does
    not count. Returns the rows ``{"step", "traced_bytes", "rss_bytes", "episodes"}``
    (every ``every`` steps) and the ``top`` source lines whose live allocations grew most
    between the first sample and the end (tracemalloc snapshot difference).
    """
    from tqdm import tqdm

    from netsense.env.policies import FreshnessPolicy
    from netsense.env.vector import BatchedEnv

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
