"""Compile every numba driver ahead of time (``netsense warmup``).

netsense's compiled passes are built by numba on first use and cached on disk (next to the
sources in ``__pycache__``, or in ``NUMBA_CACHE_DIR``). :func:`warmup` runs the code paths
real scenarios take, so that the cache holds every driver in the type signatures they use:

1. every registered scenario as a single PettingZoo env (``B = 1``: the serial builds),
   stepped by the freshness and uniform-consensus policies;
2. the library's observers (``FreshnessObserver``, ``ConsensusObserver``), single and
   batched;
3. batches large enough for the threaded builds (``BatchedEnv`` with 256 members, which
   also crosses the Markov link pass's threading threshold);
4. for every driver, the build (serial or threaded) not yet compiled for a signature the
   other build was compiled for.

A second run finds everything in the cache and takes a few seconds (the scenarios' gain
design). See ``docs/first-run.md``.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["WarmupReport", "compiled_drivers", "warmup", "warmup_tasks"]

#: Members of the batched warm-up runs: over every driver's threading threshold, including
#: the Markov link pass's 256 runs (``netsense.graphs.processes.MARKOV_THREADED_RUNS``).
BATCH = 256
#: Scenarios run batched (the kinds of graph process and noise the registry uses).
BATCHED_SCENARIOS = ("link_failures-v0", "random_structured_n20_N10-v0", "drops_kfio-v0")


@dataclass(frozen=True)
class WarmupReport:
    """What :func:`warmup` did.

    Attributes
    ----------
    compiled : functions of netsense numba compiled (cache misses) in this run.
    loaded : driver builds loaded from the on-disk cache (cache hits).
    tasks : warm-up tasks run.
    seconds : wall time.
    """

    compiled: int
    loaded: int
    tasks: int
    seconds: float


def _policies(model) -> tuple[str, str]:
    """Freshness and uniform consensus; in a communication-only scenario (which refuses an
    adoption rule of its own) freshness and random transmit bits."""
    return ("freshness", "random") if model.control.comm_only else ("freshness", "uniform")


def _run_env(scenario: str) -> None:
    from netsense.env.policies import make_policy
    from netsense.env.registry import make

    env = make(scenario)
    for name in _policies(env.model):
        policy = make_policy(name, env)
        obs, infos = env.reset(seed=0)
        for _ in range(3):
            obs, _r, _te, _tr, infos = env.step(policy.act_dict(env, obs, infos))


def _run_batched(scenario: str) -> None:
    from netsense.env.policies import make_policy
    from netsense.env.vector import BatchedEnv

    env = BatchedEnv(scenario, num_envs=BATCH)
    for name in _policies(env.core.model):
        policy = make_policy(name, env.core)
        obs, info = env.reset(seed=0)
        for _ in range(3):
            obs, _r, _te, _tr, info = env.step(policy.act(obs, info["action_mask"]))


def _run_observers(batch_size: int | None) -> None:
    from netsense.graphs.processes import RandomJointlyConnected
    from netsense.observers.consensus import ConsensusObserver
    from netsense.observers.freshness import FreshnessObserver
    from netsense.systems.design import design_observer
    from netsense.systems.plants import random_structured

    plant = random_structured(n=6, num_agents=4, rng=0)
    design = design_observer(plant, rho=0.8)
    graphs = RandomJointlyConnected(4, period=2).sequence(4, rng=1)
    kw = {} if batch_size is None else {"batch_size": batch_size}
    shape = (6,) if batch_size is None else (batch_size, 6)
    for obs in (FreshnessObserver(design, **kw), ConsensusObserver(design, **kw),
                ConsensusObserver(design, weights="tree", **kw)):
        x = np.ones(shape)
        for k in range(4):
            obs.step(plant.measure(x), graphs[k])
            x = plant.step(x)


def warmup_tasks(scenarios: Sequence[str] | None = None, *, threaded: bool = True
                 ) -> list[tuple[str, Callable[[], None]]]:
    """``(label, function)`` for the workloads of steps 1-3 (see the module docstring)."""
    from netsense.env.registry import list_scenarios

    ids = list(list_scenarios() if scenarios is None else scenarios)
    tasks: list[tuple[str, Callable[[], None]]] = [
        (sid, lambda sid=sid: _run_env(sid)) for sid in ids]
    tasks.append(("observers", lambda: _run_observers(None)))
    if threaded:
        tasks.append(("observers, batched", lambda: _run_observers(BATCH)))
        batched = [s for s in BATCHED_SCENARIOS if s in ids] or ids[:1]
        tasks += [(f"{sid}, {BATCH} members", lambda sid=sid: _run_batched(sid))
                  for sid in batched]
    return tasks


def compiled_drivers() -> list[tuple[str, object]]:
    """``(name, Driver)`` of every driver in the netsense modules imported so far."""
    from netsense.kernels.jit import Driver

    out = []
    for modname, mod in sorted(sys.modules.items()):
        if not modname.startswith("netsense.") or mod is None:
            continue
        for attr, value in sorted(vars(mod).items()):
            if isinstance(value, Driver) and all(value is not d for _, d in out):
                out.append((f"{modname}.{attr}", value))
    return out


def _pair_tasks(threaded: bool) -> list[tuple[str, Callable[[], None]]]:
    """Step 4: compile each driver's other build for the signatures seen so far."""
    tasks = []
    for name, drv in compiled_drivers():
        builds = [("serial", drv.serial)] + ([("threaded", drv.parallel)] if threaded else [])
        seen = {tuple(sig) for _, d in builds for sig in d.signatures}
        for label, d in builds:
            missing = seen - {tuple(sig) for sig in d.signatures}
            if missing:
                tasks.append((f"{name.rpartition('.')[2]} ({label})",
                              lambda d=d, missing=missing: [d.compile(s) for s in missing]))
    return tasks


class _Counter:
    """Counts netsense compilations and shows the function being compiled."""

    def __init__(self, bar) -> None:
        self.bar = bar
        self.compiled = 0

    def on_start(self, ev) -> None:
        fn = getattr((ev.data or {}).get("dispatcher"), "py_func", None)
        if fn is not None and (fn.__module__ or "").startswith("netsense."):
            self.compiled += 1
            if self.bar is not None:
                self.bar.set_postfix_str(f"compiling {fn.__name__.split('_serial')[0]}"
                                         .split("_parallel")[0], refresh=True)

    def on_end(self, ev) -> None:
        pass


def warmup(scenarios: Iterable[str] | None = None, *, threaded: bool = True,
           progress: bool = True) -> WarmupReport:
    """Compile (or load from numba's cache) every driver the scenarios use.

    Parameters
    ----------
    scenarios : scenario ids to run (default: every registered one).
    threaded : also the threaded builds (batches of :data:`BATCH` members).
    progress : show a tqdm progress bar on stderr.
    """
    from numba.core import event

    from netsense.kernels import notice

    notice.mark_shown()  # the bar says what is compiling
    t0 = time.perf_counter()
    tasks = warmup_tasks(None if scenarios is None else list(scenarios), threaded=threaded)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(tasks), desc="netsense warmup", unit="task", file=sys.stderr)
    counter = _Counter(bar)
    listener = type("_L", (event.Listener,), {"on_start": lambda s, e: counter.on_start(e),
                                              "on_end": lambda s, e: None})()
    event.register("numba:compile", listener)
    done = 0
    try:
        for stage in (0, 1):
            if stage == 1:  # the signatures are known now: the other builds
                tasks = _pair_tasks(threaded)
                if bar is not None:
                    bar.total += len(tasks)
                    bar.refresh()
            for label, fn in tasks:
                if bar is not None:
                    bar.set_description_str(f"netsense warmup: {label}", refresh=False)
                    bar.set_postfix_str("", refresh=True)
                fn()
                done += 1
                if bar is not None:
                    bar.update(1)
    finally:
        event.unregister("numba:compile", listener)
        if bar is not None:
            bar.set_description_str("netsense warmup", refresh=False)
            bar.set_postfix_str("", refresh=True)
            bar.close()
    loaded = sum(sum(d.stats.cache_hits.values()) for _, drv in compiled_drivers()
                 for d in (drv.serial, drv.parallel))
    return WarmupReport(compiled=counter.compiled, loaded=loaded, tasks=done,
                        seconds=time.perf_counter() - t0)
