"""Cost per agent as N grows: the PettingZoo env, the batched core, training and memory
at N = 10, 50, 200 and 1,000, in one run.

The task is ``comm_process_noise-v0`` (communication-only control: a transmit bit per agent,
freshness fusion; five noisy oscillators ``x_j[k+1] = 0.99 R(theta_j) x_j[k] + w_j[k]``
measured by five sources) resized to ``N`` agents through the scenario loader's overrides
(:func:`scale_overrides`): the same plant (``n = 10``, ``M = 5`` sources spread evenly over
the ``N`` agents, the other agents relays), so that an agent's own work does not depend on
``N`` and only the network grows. Two graph processes:

``markov`` (the scale family, every figure below)
    Markov link failures (``p_fail = 0.1``, ``p_recover = 0.5``, one uniform per base link
    and step: ``draws = "base"``) on a circulant base graph with offsets ``(1, 3, 7)``: in-degree
    ``D = 3`` at every ``N``, a sparse graph.
``jsc`` (a diagnostic row of the core only)
    The registered task's own process, random jointly connected graphs (period 2) with
    ``extra_edge_prob = 0.5 / N`` (the registered task's 0.05 at ``N = 10``: at
    ``N = 10`` this *is* ``comm_process_noise-v0``, tested), about 1.5 expected
    in-neighbours per step at every ``N``.

Measured per ``N``, contenders interleaved where they share a machine state:

a. **env**: agent-steps/s through the PettingZoo parallel API
   (:class:`netsense.env.pettingzoo_env.NetSenseEnv`), every agent transmitting at every
   step (a fixed valid action), resets included; best of ``--repeats`` blocks;
b. **core**: agent-steps/s of :meth:`netsense.engine.core.BatchedCore.step` at ``B = 64``
   and at ``B = 10,000 / N`` (``B N`` constant), random transmit bits pre-drawn; best of
   ``--repeats`` blocks of at least ``--block-seconds`` each;
c. **training**: agent-steps/s of :func:`netsense.rl.ppo.train_ppo` at the
   :class:`netsense.rl.config.PPOConfig` defaults (B = 256, T = 32, MAPPO with the team
   critic, overlapped collection) for ``--train-iters`` iterations, more at small N (at
   least ``--train-min-steps`` agent-steps after the first iteration); the median of the
   per-iteration rates after the first (the first collection has nothing to overlap). The
   team critic's global state (:func:`netsense.rl.envs.global_state`) holds the adjacency
   on the graph process's support (here the ``N D`` base links), so it grows like ``N``;
   a rollout whose states would pass ``--train-max-gb`` is skipped with its size stated;
d. **memory**: live bytes (``tracemalloc``) of building, resetting and stepping the core at
   ``B = 64`` (and the env), divided by ``B N`` (``N``).

Then profiles (``cProfile``, own time per function) of the core step at ``N = 50`` and
``N = 1,000`` (both graph processes, the ``jsc`` one at ``N = 200`` for its size) and of the
training loop (serial collection and learning, one torch thread, the stages of
``experiments/bench/train_profile.py``) at ``N = 10`` and ``N = 200``.

VMAS is not installed on this machine (and cannot be): its column says so.

Writes ``scale.csv``, ``scale.md`` (the table, the ratios against the targets and the
profiles) and ``scale.png`` into ``--out`` (default ``experiments/results/bench/scale``),
each file whole or not at all (:mod:`netsense.rl.atomic`)::

    python experiments/bench/scale.py            # about 10 minutes on 2 shared cores
    python experiments/bench/scale.py --smoke    # seconds: N = 6, 12, tiny blocks
"""

# %%
from __future__ import annotations

import argparse
import cProfile
import csv
import gc
import importlib.util
import io
import json
import math
import os
import platform
import pstats
import statistics
import sys
import time
import tracemalloc
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments" / "results" / "bench" / "scale"

#: The registered task every scenario here is an override of.
BASE = "comm_process_noise-v0"
#: Rotation angles of ``comm_process_noise-v0``'s five oscillators (its ``A`` is
#: ``0.99 R(theta_j)`` rounded to six decimals, block by block).
THETAS = (0.1, 0.2, 0.3, 0.5, 0.7)
#: Agent counts measured.
NS = (10, 50, 200, 1000)
#: Circulant offsets of the Markov family's base graph (in-degree 3).
OFFSETS = (1, 3, 7)
#: Agents per batch in the ``B N`` constant measurement of the core.
AGENTS_PER_BATCH = 10_000
#: Graph processes of :func:`scale_overrides`.
GRAPHS = ("markov", "jsc")
#: Registered scale tasks measured beside the family where they exist (``{N}``: the agent
#: count): the K-of-N collision channel and the spatial network of docs/tasks.md.
REGISTERED = {"kofn": "comm_channel_kofn_n{N}-v0", "spatial": "comm_spatial_n{N}-v0"}
#: Targets: the core's cost per agent-step at N = 1,000 within 2x of N = 50; training's at
#: N = 200 within 2x of N = 10.
TARGET = 2.0


# %% The scenarios
def oscillator_plant(N: int) -> dict:
    """The ``[plant]`` table of ``comm_process_noise-v0`` with ``N`` agents.

    Parameters
    ----------
    N : int
        Number of agents, at least ``len(THETAS)``.

    Returns
    -------
    dict
        ``kind = "matrices"``: ``A`` block-diagonal with the blocks
        ``0.99 [[cos t, -sin t], [sin t, cos t]]`` (rounded to six decimals) for ``t`` in
        :data:`THETAS`, and ``C``: source ``j`` (agent ``round(j N / S)``, ``S`` the number
        of oscillators) measures block ``j`` (two rows of the identity), every other agent
        nothing.
    """
    S = len(THETAS)
    if N < S:
        raise ValueError(f"N must be at least {S} (one agent per oscillator), got {N}")
    n = 2 * S
    A = np.zeros((n, n))
    for j, t in enumerate(THETAS):
        c, s = round(0.99 * math.cos(t), 6), round(0.99 * math.sin(t), 6)
        A[2 * j:2 * j + 2, 2 * j:2 * j + 2] = [[c, -s], [s, c]]
    C: list[list] = [[] for _ in range(N)]
    eye = np.eye(n)
    for j, i in enumerate(sources(N)):
        C[i] = eye[2 * j:2 * j + 2].tolist()
    return {"kind": "matrices", "A": A.tolist(), "C": C}


def sources(N: int) -> list[int]:
    """The agents that measure an oscillator: ``round(j N / S)`` for ``j < S``."""
    S = len(THETAS)
    return [round(j * N / S) for j in range(S)]


def scale_overrides(N: int, graph: str = "markov") -> dict:
    """Scenario overrides of :data:`BASE` for ``N`` agents (:func:`oscillator_plant` and
    the graph process ``graph``, one of :data:`GRAPHS`; see the module docstring)."""
    if graph == "markov":
        g = {"kind": "markov", "num_nodes": N, "p_fail": 0.1, "p_recover": 0.5,
             "draws": "base", "base": {"kind": "circulant", "offsets": list(OFFSETS)}}
    elif graph == "jsc":
        g = {"kind": "random_jsc", "num_nodes": N, "period": 2, "extra_edge_prob": 0.5 / N}
    else:
        raise ValueError(f"graph must be one of {GRAPHS}, got {graph!r}")
    return {"plant": oscillator_plant(N), "graph": g}


def scale_model(N: int, graph: str = "markov"):
    """The :class:`netsense.engine.model.CoreModel` of :func:`scale_overrides`."""
    from netsense.env.registry import build_model, load, with_overrides

    return build_model(with_overrides(load(BASE), **scale_overrides(N, graph)))


def registered_model(family: str, N: int):
    """The model of the registered scale task of ``family`` (:data:`REGISTERED`) with ``N``
    agents, or None where no such scenario is registered."""
    from netsense.env.registry import build_model, list_scenarios, load

    sid = REGISTERED[family].format(N=N)
    return build_model(load(sid)) if sid in list_scenarios() else None


# %% Arithmetic of the table
def cost_us(agent_steps_per_s: float) -> float:
    """Microseconds per agent-step of a rate in agent-steps/s (``nan`` for no rate)."""
    if not agent_steps_per_s or not math.isfinite(agent_steps_per_s):
        return float("nan")
    return 1e6 / agent_steps_per_s


def cost_ratio(rates: dict[int, float], reference: int) -> dict[int, float]:
    """Cost per agent-step at each ``N`` over that at ``reference`` (``rate[ref] /
    rate[N]``; above 1: an agent-step costs more at ``N``); ``nan`` where a rate is
    missing."""
    ref = rates.get(reference, float("nan"))
    out = {}
    for N, r in rates.items():
        ok = r and math.isfinite(r) and ref and math.isfinite(ref)
        out[N] = ref / r if ok else float("nan")
    return out


def bytes_per_agent(live_bytes: float, B: int, N: int) -> float:
    """Live bytes over the ``B N`` agents they hold."""
    return live_bytes / (B * N)


# %% Measurements
def _core_rate(core, actions: np.ndarray, block_s: float, repeats: int) -> float:
    """Best agent-steps/s of ``core.step(actions)`` over ``repeats`` blocks of at least
    ``block_s`` seconds (the step count is fixed by one calibration step)."""
    B, N = core.B, core.N
    core.step(actions)  # compiled passes loaded, buffers touched
    t0 = time.perf_counter()
    core.step(actions)
    steps = max(2, int(block_s / max(time.perf_counter() - t0, 1e-9)))
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(steps):
            core.step(actions)
        best = min(best, (time.perf_counter() - t0) / steps)
    return B * N / best


def measure_core(model, B: int, block_s: float, repeats: int, seed: int = 0) -> float:
    """Agent-steps/s of the batched core of ``model`` at batch ``B`` (random transmit
    bits, drawn once; members are never reset, the horizon does not end a member)."""
    from netsense.engine.core import BatchedCore

    core = BatchedCore(model, B)
    core.reset(seed)
    acts = np.random.default_rng(seed).integers(0, 2, size=(B, model.plant.num_agents, 1))
    return _core_rate(core, acts, block_s, repeats)


def measure_env(model, block_s: float, repeats: int, seed: int = 0) -> float:
    """Agent-steps/s of the PettingZoo parallel API on ``model`` (every agent transmits;
    resets at the horizon included); best of ``repeats`` blocks."""
    from netsense.env.pettingzoo_env import NetSenseEnv

    env = NetSenseEnv(model, scenario_id=f"{BASE} (scaled)")
    env.reset(seed=seed)
    N = len(env.possible_agents)
    act = {a: np.ones(1, dtype=np.int64) for a in env.possible_agents}

    def block(steps: int) -> float:
        t0 = time.perf_counter()
        for _ in range(steps):
            env.step(act)
            if not env.agents:
                env.reset()
        return time.perf_counter() - t0

    steps = max(2, int(block_s / max(block(2) / 2, 1e-9)))
    return N * steps / min(block(steps) for _ in range(repeats))


def measure_memory(model, B: int, steps: int, seed: int = 0) -> dict:
    """Live bytes (``tracemalloc``) after building, resetting and stepping the core at
    batch ``B`` for ``steps`` steps (its arrays, pre-drawn chunks and last outputs), and
    after building, resetting and stepping one PettingZoo env the same way (then again
    once its ``state_space`` is built: ``env_state_space_bytes``, what an env held before
    that space was built on first use); the core's own array bytes
    (:func:`netsense.speed.memory.core_state_bytes`)."""
    from netsense.engine.core import BatchedCore
    from netsense.env.pettingzoo_env import NetSenseEnv
    from netsense.speed.memory import core_state_bytes

    N = model.plant.num_agents
    acts = np.random.default_rng(seed).integers(0, 2, size=(B, N, 1))
    out = {}
    for what in ("core", "env"):
        gc.collect()
        tracemalloc.start()
        try:
            base = tracemalloc.get_traced_memory()[0]
            if what == "core":
                obj = BatchedCore(model, B)
                obj.reset(seed)
                for _ in range(steps):
                    obj.step(acts)
            else:
                obj = NetSenseEnv(model)
                obj.reset(seed=seed)
                act = {a: np.ones(1, dtype=np.int64) for a in obj.possible_agents}
                for _ in range(steps):
                    obj.step(act)
            gc.collect()
            out[f"{what}_bytes"] = tracemalloc.get_traced_memory()[0] - base
            if what == "env":  # what the env held when it built state_space up front
                _ = obj.state_space
                out["env_state_space_bytes"] = tracemalloc.get_traced_memory()[0] - base
        finally:
            tracemalloc.stop()
        if what == "core":
            out["core_array_bytes"] = int(sum(core_state_bytes(obj).values()))
        del obj
    return out


def support_edges(model) -> int | None:
    """Adjacency entries of the team critic's global state for ``model``: the edges of its
    graph process's support (:func:`netsense.rl.envs.state_edges`), ``None`` for all
    ``N^2``."""
    support = model.graphs.edge_support
    return None if support is None else int(support.sum())


def train_state_bytes(N: int, M: int, num_envs: int, rollout: int,
                      edges: int | None = None) -> int:
    """Bytes of the team critic's global states over one rollout at the defaults
    (``(rollout + 1) num_envs`` states of :func:`netsense.rl.envs.state_size` float32,
    ``edges`` adjacency entries each)."""
    from netsense.rl.envs import state_size

    return 4 * (rollout + 1) * num_envs * state_size(N, M, edges)


def steady_rate(rows: Sequence[dict]) -> float:
    """Median agent-steps/s of a training log's iterations after the first (the first
    collection has nothing to overlap); NaN with fewer than two iterations."""
    rates = [(b["agent_steps"] - a["agent_steps"]) / (b["wall_s"] - a["wall_s"])
             for a, b in zip(rows, rows[1:], strict=False)]
    return statistics.median(rates) if rates else float("nan")


def measure_train(N: int, iters: int, **fields) -> dict:
    """``iters`` iterations of the PPOConfig defaults on :func:`scale_overrides` ``(N)``:
    the median rate of the iterations after the first, collection and learning seconds."""
    from netsense.rl.config import PPOConfig
    from netsense.rl.ppo import train_ppo

    over = scale_overrides(N)
    base = PPOConfig(BASE, overrides=over, **fields)
    # one iteration is num_envs x rollout x N agent-steps of *this* configuration (fields
    # may change num_envs or rollout), so the run is ``iters`` iterations long
    cfg = PPOConfig(BASE, overrides=over, steps=base.num_envs * base.rollout * N * iters,
                    **fields)
    res = train_ppo(cfg, None, evaluate_every=False)
    rows = res.rows
    return {"agent_steps_per_s": steady_rate(rows),
            "collect_s": rows[-1]["collect_s"] - rows[0]["collect_s"],
            "learn_s": rows[-1]["learn_s"] - rows[0]["learn_s"],
            "wall_s": rows[-1]["wall_s"] - rows[0]["wall_s"], "iterations": len(rows),
            "num_envs": cfg.num_envs}


def learner_macs(N: int, obs_dim: int, M: int, hidden: Sequence[int] = (64, 64),
                 critic_hidden: Sequence[int] = (128, 128), edges: int | None = None
                 ) -> dict[str, float]:
    """Multiply-adds of one forward pass per agent-step of the defaults' networks, from the
    layer widths: the actor's MLP once per agent (``obs_dim`` inputs, two actions) and the
    team critic's once per member on the global state (:func:`netsense.rl.envs.state_size`
    inputs, ``edges`` adjacency entries), shared by its ``N`` agents. The agent features
    the actor appends are left out (a few inputs)."""
    from netsense.rl.envs import state_size

    def mlp(inputs: int, widths: Sequence[int], outputs: int) -> int:
        sizes = [inputs, *widths, outputs]
        return sum(a * b for a, b in zip(sizes, sizes[1:], strict=False))

    actor = mlp(obs_dim, hidden, 2)
    critic = mlp(state_size(N, M, edges), critic_hidden, 1)
    return {"actor_macs_per_agent_step": float(actor),
            "critic_macs_per_agent_step": critic / N}


# %% Profiles
def profile_core(model, B: int, steps: int, top: int = 8, seed: int = 0
                 ) -> list[tuple[str, float, float]]:
    """``(function, own ms per step, share)`` of ``steps`` core steps under cProfile,
    largest first (``top`` rows)."""
    from netsense.engine.core import BatchedCore

    core = BatchedCore(model, B)
    core.reset(seed)
    acts = np.random.default_rng(seed).integers(0, 2, size=(B, core.N, 1))
    core.step(acts)
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(steps):
        core.step(acts)
    prof.disable()
    return _own_times(pstats.Stats(prof, stream=io.StringIO()), steps, top)


def _own_times(st: pstats.Stats, per: int, top: int) -> list[tuple[str, float, float]]:
    total = sum(v[2] for v in st.stats.values())
    rows = []
    for (file, line, fn), v in st.stats.items():
        where = f"{Path(file).name}:{line}({fn})" if file != "~" else fn
        rows.append((where, v[2] / per * 1e3, v[2] / total if total else 0.0))
    rows.sort(key=lambda r: -r[1])
    return rows[:top]


def _train_profile_module():
    """``experiments/bench/train_profile.py`` (its stage table) as a module."""
    path = Path(__file__).resolve().parent / "train_profile.py"
    spec = importlib.util.spec_from_file_location("_scale_train_profile", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def profile_train(N: int, iters: int) -> dict[str, float]:
    """Share of each stage of ``experiments/bench/train_profile.py`` in ``iters``
    iterations of the defaults at ``N`` with collection and learning one after the other
    and one torch thread (cProfile sees one thread); ``"total_s"`` the profiled seconds."""
    from netsense.rl.config import PPOConfig
    from netsense.rl.ppo import train_ppo

    tp = _train_profile_module()
    over = scale_overrides(N)
    base = PPOConfig(BASE, overrides=over)
    cfg = PPOConfig(BASE, overrides=over, overlap=False, torch_threads=1,
                    steps=base.num_envs * base.rollout * N * iters)
    prof = cProfile.Profile()
    t0 = time.perf_counter()
    prof.enable()
    train_ppo(cfg, None, evaluate_every=False)
    prof.disable()
    wall = time.perf_counter() - t0
    st = pstats.Stats(prof, stream=io.StringIO())
    sec = {s: sum(tp._cumulative(st, f, n) for f, n in pairs)
           for s, pairs in tp.STAGES.items()}
    sec["core step"] -= sum(sec[s] for s in tp.INSIDE_COLLECTION)
    sec["other"] = wall - sum(sec.values())
    out = {s: v / wall for s, v in sec.items()}
    out["total_s"] = wall
    out["agent_steps"] = float(cfg.steps)
    return out


# %% Output
COLUMNS = ("N", "B", "n", "M", "D", "env_agent_steps_per_s", "env_cost_us",
           "core_agent_steps_per_s", "core_cost_us", "core_cost_vs_N50",
           "core_BN_const_B", "core_BN_const_agent_steps_per_s", "core_BN_const_cost_us",
           "core_BN_const_cost_vs_N50", "core_jsc_agent_steps_per_s", "core_jsc_cost_us",
           "core_jsc_cost_vs_N50", "core_jsc_D", "core_kofn_agent_steps_per_s",
           "core_kofn_cost_us", "core_kofn_cost_vs_N50", "core_kofn_D",
           "core_spatial_agent_steps_per_s", "core_spatial_cost_us", "core_spatial_cost_vs_N50",
           "core_spatial_D", "train_agent_steps_per_s", "train_cost_us",
           "train_cost_vs_N10", "train_iterations", "train_collect_s", "train_learn_s",
           "train_note",
           "core_bytes_per_agent", "core_array_bytes_per_agent", "env_bytes_per_agent",
           "env_state_space_bytes_per_agent",
           "train_state_MB", "actor_macs_per_agent_step", "critic_macs_per_agent_step",
           "vmas")
VMAS_NOTE = "not installed here (cannot be): not measured"


def write_csv(rows: Sequence[dict], path: Path) -> None:
    """The rows, columns :data:`COLUMNS`, written atomically."""
    from netsense.rl.atomic import atomic_path

    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(COLUMNS), extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: _fmt(r.get(k, "")) for k in COLUMNS})


def read_csv(path: Path) -> list[dict]:
    """The rows of :func:`write_csv`, numbers as numbers (an empty cell as ``nan``)."""
    def num(k: str, v: str):
        if k in ("train_note", "vmas"):
            return v
        if v == "":
            return float("nan")
        return int(v) if k in ("N", "B", "n", "M", "D", "core_BN_const_B", "core_jsc_D",
                               "core_kofn_D", "core_spatial_D", "train_iterations") \
            else float(v)

    with open(path, newline="") as fh:
        return [{k: num(k, v) for k, v in r.items()} for r in csv.DictReader(fh)]


def _fmt(v):
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.9g}"
    return v


def _x(v: float) -> str:
    return "-" if not math.isfinite(v) else f"{v:.2f}x"


def _n(v: float, f: str = ",.0f") -> str:
    return "-" if not (isinstance(v, (int, float)) and math.isfinite(v)) else format(v, f)


def markdown(rows: Sequence[dict], profiles: dict, meta: dict) -> str:
    """``scale.md``: the table, the targets and the profiles."""
    by = {r["N"]: r for r in rows}
    lines = [f"# Cost per agent as N grows ({meta['when']})", "",
             f"{meta['host']}: {meta['cores']} cores, load average {meta['load']:.2f} at the "
             f"end; netsense {meta['rev']}. Command: `{meta['command']}`.", "",
             f"Task: `{BASE}` resized to N agents (the same five oscillators, n = 10, M = 5 "
             f"sources spread over the N agents), Markov link failures on a circulant base "
             f"graph with offsets {list(OFFSETS)} (D = 3). Rates are agent-steps/s; cost = "
             "microseconds per agent-step; ratios are costs over the reference N's, in "
             "this run. VMAS: " + VMAS_NOTE + ".", "",
             "| N | env agent-steps/s (us) | core B = 64 agent-steps/s (us) | core cost vs "
             "N = 50 | core B N = 10^4: B, agent-steps/s | vs N = 50 | core, jsc graphs "
             "(D) | vs N = 50 | training agent-steps/s (us) | vs N = 10 | bytes per agent: core "
             "/ env (env with `state_space` built) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        tr = (f"{_n(r['train_agent_steps_per_s'])} ({_n(r['train_cost_us'], '.2f')})"
              if math.isfinite(r["train_agent_steps_per_s"]) else f"not run: {r['train_note']}")
        lines.append(
            f"| {r['N']} | {_n(r['env_agent_steps_per_s'])} ({_n(r['env_cost_us'], '.3f')}) "
            f"| {_n(r['core_agent_steps_per_s'])} ({_n(r['core_cost_us'], '.3f')}) "
            f"| {_x(r['core_cost_vs_N50'])} | {r['core_BN_const_B']}, "
            f"{_n(r['core_BN_const_agent_steps_per_s'])} | {_x(r['core_BN_const_cost_vs_N50'])} "
            f"| {_n(r['core_jsc_agent_steps_per_s'])} ({r['core_jsc_D']}) "
            f"| {_x(r['core_jsc_cost_vs_N50'])} | {tr} | {_x(r['train_cost_vs_N10'])} "
            f"| {_n(r['core_bytes_per_agent'])} / {_n(r['env_bytes_per_agent'])} "
            f"({_n(r['env_state_space_bytes_per_agent'])}) |")
    lines += ["", "Registered scale tasks (docs/tasks.md), the core at B = 64 where the id is "
              "registered: " + "; ".join(
                  f"`{REGISTERED[f].format(N=r['N'])}` "
                  f"{_n(r[f'core_{f}_agent_steps_per_s'])} agent-steps/s, cost "
                  f"{_x(r[f'core_{f}_cost_vs_N50'])} N = 50's (D = {r[f'core_{f}_D']})"
                  for f in REGISTERED for r in rows
                  if math.isfinite(r[f"core_{f}_agent_steps_per_s"])) + "."]
    core_r = by.get(1000, {}).get("core_cost_vs_N50", float("nan"))
    train_r = by.get(200, {}).get("train_cost_vs_N10", float("nan"))
    lines += ["", "Targets (cost per agent-step, this run):", "",
              f"* batched core, N = 1,000 against N = 50 (B = 64): {_x(core_r)} -> "
              f"{_verdict(core_r)} (B N = 10^4: "
              f"{_x(by.get(1000, {}).get('core_BN_const_cost_vs_N50', float('nan')))});",
              f"* training at the defaults, N = 200 against N = 10: {_x(train_r)} -> "
              f"{_verdict(train_r)}.", ""]
    lines += ["Learner multiply-adds per agent-step (one forward pass, from the layer widths): "
              + "; ".join(f"N = {r['N']}: actor {_n(r['actor_macs_per_agent_step'])}, team "
                          f"critic {_n(r['critic_macs_per_agent_step'])}" for r in rows)
              + ". The critic reads the global state once per member: its size grows "
              "like N (the adjacency on the base graph's N D links, the freshness "
              "indices' N M), so per agent-step its cost stays flat.", ""]
    for title, prof in profiles.items():
        lines += [f"## {title}", ""]
        if isinstance(prof, dict):
            total, steps = prof["total_s"], prof["agent_steps"]
            lines += [f"{total:.1f} s profiled, {steps:,.0f} agent-steps (the start "
                      "included).", "", "| stage | share | us per agent-step |",
                      "|---|---|---|"]
            lines += [f"| {s} | {v:.1%} | {v * total / steps * 1e6:.2f} |"
                      for s, v in prof.items() if s not in ("total_s", "agent_steps")]
        else:
            lines += ["| function (own time) | ms per step | share |", "|---|---|---|"]
            lines += [f"| `{w}` | {ms:.3f} | {sh:.1%} |" for w, ms, sh in prof]
        lines.append("")
    return "\n".join(lines)


def _verdict(ratio: float) -> str:
    if not math.isfinite(ratio):
        return "not measured"
    return f"holds (within {TARGET:g}x)" if ratio <= TARGET else f"fails (over {TARGET:g}x)"


def plot(rows: Sequence[dict], path: Path) -> None:
    """Cost per agent-step against N (log-log) for every measured path, written
    atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from netsense.rl.atomic import atomic_path

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for key, label, style in (("env_cost_us", "PettingZoo env", "o-"),
                              ("core_cost_us", "batched core, B = 64", "s-"),
                              ("core_BN_const_cost_us", "batched core, B N = 10^4", "s--"),
                              ("core_jsc_cost_us", "batched core, jsc graphs, B = 64", "x:"),
                              ("core_kofn_cost_us", "core, registered K-of-N tasks", "d:"),
                              ("core_spatial_cost_us", "core, registered spatial tasks", "v:"),
                              ("train_cost_us", "training (defaults)", "^-")):
        pts = [(r["N"], r[key]) for r in rows if math.isfinite(r[key])]
        if pts:
            ax.loglog(*zip(*pts, strict=True), style, label=label)
    Ns = [r["N"] for r in rows]
    ax.set_xticks(Ns)
    ax.set_xticklabels([str(v) for v in Ns])
    ax.minorticks_off()
    ax.set_xlabel("N (agents)")
    ax.set_ylabel("microseconds per agent-step")
    ax.set_title(f"{BASE} resized to N (Markov circulant graphs, D = 3)", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


# %% Main
def main(argv: Sequence[str] | None = None) -> Path:
    """Measure, write the outputs; returns the CSV path."""
    from tqdm.auto import tqdm

    from netsense.rl.atomic import write_atomic, write_json
    from netsense.rl.config import PPOConfig
    from netsense.speed.report import source_revision

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--N", type=int, nargs="+", default=list(NS))
    p.add_argument("--batch", type=int, default=64, help="B of the core's fixed-B column")
    p.add_argument("--repeats", type=int, default=3, help="blocks per rate (best is kept)")
    p.add_argument("--block-seconds", type=float, default=0.5,
                   help="shortest timed block of the env and the core")
    p.add_argument("--train-iters", type=int, default=3,
                   help="training iterations per N (the rate: median of those after the "
                        "first; at least 2)")
    p.add_argument("--train-min-steps", type=int, default=1_000_000,
                   help="at least this many agent-steps after the first iteration per N "
                        "(more iterations at small N, whose iterations are short and so "
                        "most exposed to other jobs' load)")
    p.add_argument("--train-max-gb", type=float, default=4.0,
                   help="skip training where one rollout's global states exceed this")
    p.add_argument("--memory-steps", type=int, default=8)
    p.add_argument("--profile-steps", type=int, default=16)
    p.add_argument("--profile-train-iters", type=int, default=1)
    p.add_argument("--no-profile", action="store_true")
    p.add_argument("--no-train", action="store_true")
    p.add_argument("--smoke", action="store_true", help="tiny sizes, seconds (tests)")
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--replot", action="store_true",
                   help="rewrite scale.md and scale.png from scale.csv and "
                        "scale_profiles.json in --out (no measurement)")
    args = p.parse_args(argv)
    if args.train_iters < 2:
        p.error(f"--train-iters must be at least 2, got {args.train_iters}")
    if args.smoke:
        args.N, args.batch, args.repeats, args.block_seconds = [6, 12], 4, 1, 0.01
        args.memory_steps, args.profile_steps, args.train_iters = 2, 2, 2
        args.profile_train_iters = 1
    out = Path(args.out)
    stem = "scale_smoke" if args.smoke else "scale"
    if args.replot:
        rows = read_csv(out / f"{stem}.csv")
        doc = json.loads((out / f"{stem}_profiles.json").read_text())
        write_atomic(out / f"{stem}.md", markdown(rows, doc["profiles"], doc["meta"]) + "\n")
        plot(rows, out / f"{stem}.png")
        return out / f"{stem}.csv"
    Ns = sorted(set(args.N))
    ref_core = 50 if 50 in Ns else Ns[0]
    ref_train = 10 if 10 in Ns else Ns[0]
    out.mkdir(parents=True, exist_ok=True)
    quiet = args.no_progress
    defaults = PPOConfig(BASE)
    rows = []
    bar = tqdm(total=len(Ns) * 6, desc="scale", disable=quiet)
    for N in Ns:
        r: dict = {"N": N, "B": args.batch, "vmas": VMAS_NOTE}
        model = scale_model(N)
        jsc = scale_model(N, "jsc")
        r.update(n=int(model.plant.A.shape[0]), M=len(sources(N)),
                 D=int(model.graphs.max_in_degree),
                 core_jsc_D=int(jsc.graphs.max_in_degree))
        bar.set_postfix(N=N, what="env")
        r["env_agent_steps_per_s"] = measure_env(model, args.block_seconds, args.repeats)
        bar.update()
        bar.set_postfix(N=N, what="core")
        r["core_agent_steps_per_s"] = measure_core(model, args.batch, args.block_seconds,
                                                   args.repeats)
        bar.update()
        Bc = max(1, (4 if args.smoke else AGENTS_PER_BATCH) // N)
        r["core_BN_const_B"] = Bc
        r["core_BN_const_agent_steps_per_s"] = measure_core(model, Bc, args.block_seconds,
                                                            args.repeats)
        bar.update()
        bar.set_postfix(N=N, what="core jsc")
        r["core_jsc_agent_steps_per_s"] = measure_core(jsc, args.batch, args.block_seconds,
                                                       1 if N >= 1000 else args.repeats)
        for fam in REGISTERED:  # the registered scale tasks, where they exist
            reg = registered_model(fam, N)
            r[f"core_{fam}_agent_steps_per_s"] = float("nan") if reg is None else \
                measure_core(reg, args.batch, args.block_seconds, args.repeats)
            r[f"core_{fam}_D"] = "" if reg is None else int(reg.graphs.max_in_degree)
        bar.update()
        bar.set_postfix(N=N, what="memory")
        mem = measure_memory(model, args.batch, args.memory_steps)
        r["core_bytes_per_agent"] = bytes_per_agent(mem["core_bytes"], args.batch, N)
        r["core_array_bytes_per_agent"] = bytes_per_agent(mem["core_array_bytes"],
                                                          args.batch, N)
        r["env_bytes_per_agent"] = bytes_per_agent(mem["env_bytes"], 1, N)
        r["env_state_space_bytes_per_agent"] = bytes_per_agent(mem["env_state_space_bytes"],
                                                               1, N)
        bar.update()
        edges = support_edges(model)
        state = train_state_bytes(N, len(sources(N)), defaults.num_envs, defaults.rollout,
                                  edges)
        r["train_state_MB"] = state / 2**20
        from netsense.engine.core import BatchedCore

        r.update(learner_macs(N, BatchedCore(model, 1).layout.size, len(sources(N)),
                              defaults.hidden, defaults.critic_hidden, edges))
        r["train_agent_steps_per_s"] = float("nan")
        r["train_note"] = ""
        if args.no_train:
            r["train_note"] = "--no-train"
        elif state > args.train_max_gb * 2**30:
            r["train_note"] = (f"the team critic's global states of one rollout take "
                               f"{state / 2**30:.1f} GiB")
        else:
            bar.set_postfix(N=N, what="training")
            fields = {"num_envs": 4, "minibatch": 16} if args.smoke else {}
            per_iter = (fields.get("num_envs", defaults.num_envs) * defaults.rollout * N)
            iters = max(args.train_iters, 1 + math.ceil(args.train_min_steps / per_iter))
            t = measure_train(N, 2 if args.smoke else iters, **fields)
            r["train_iterations"] = t["iterations"]
            r["train_agent_steps_per_s"] = t["agent_steps_per_s"]
            r["train_collect_s"], r["train_learn_s"] = t["collect_s"], t["learn_s"]
        bar.update()
        rows.append(r)
    bar.close()
    for key, ref in (("core", ref_core), ("core_BN_const", ref_core), ("core_jsc", ref_core),
                     ("core_kofn", ref_core), ("core_spatial", ref_core),
                     ("train", ref_train), ("env", ref_core)):
        rates = {r["N"]: r[f"{key}_agent_steps_per_s"] for r in rows}
        ratio = cost_ratio(rates, ref)
        for r in rows:
            r[f"{key}_cost_us"] = cost_us(r[f"{key}_agent_steps_per_s"])
            if key != "env":  # the columns name the full run's references
                r["train_cost_vs_N10" if key == "train" else f"{key}_cost_vs_N50"] = \
                    ratio[r["N"]]
    profiles: dict = {}
    if not args.no_profile:
        lo, hi = ref_core, max(Ns)
        todo = [(f"core step at N = {N}, B = {args.batch}, {g} graphs", N, g)
                for g, Nset in (("markov", (lo, hi)), ("jsc", (lo, min(200, hi))))
                for N in dict.fromkeys(Nset)]
        for title, N, g in tqdm(todo, desc="profile core", disable=quiet):
            profiles[title] = profile_core(scale_model(N, g), args.batch, args.profile_steps)
        if not args.no_train:
            t_lo = ref_train
            t_hi = max((N for N in Ns if math.isfinite(
                next(r for r in rows if r["N"] == N)["train_agent_steps_per_s"])),
                default=t_lo)
            for N in tqdm(list(dict.fromkeys((t_lo, t_hi))), desc="profile training",
                          disable=quiet):
                profiles[f"training at N = {N} (serial, one torch thread, "
                         f"{args.profile_train_iters} iterations)"] = profile_train(
                    N, args.profile_train_iters)
    csv_path = out / f"{stem}.csv"
    write_csv(rows, csv_path)
    meta = {"when": f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC",
            "host": platform.node(), "cores": os.cpu_count(), "load": os.getloadavg()[0],
            "rev": source_revision(),
            "command": "python experiments/bench/scale.py" + (
                " " + " ".join(argv if argv is not None else sys.argv[1:])).rstrip()}
    write_json(out / f"{stem}_profiles.json", {"profiles": profiles, "meta": meta})
    write_atomic(out / f"{stem}.md", markdown(rows, profiles, meta) + "\n")
    plot(rows, out / f"{stem}.png")
    print(f"wrote {csv_path} and {stem}.md, {stem}.png")
    return csv_path


if __name__ == "__main__":
    main()
