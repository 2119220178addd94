"""A/B of two checkouts of netsense: ``BatchedCore.step`` at the three benchmark shapes.

Model: ``large_n20_N100-v1`` resized (Markov links drawn per base link, one index column
per agent -- the form every version supports), freshness policy computed between the
steps (only ``step`` timed), best of 5 blocks of 32 steps; the bare numpy kernel (flat
gather + two BLAS products) is timed in the same process as a yardstick. Prints one JSON
line. Run it once per checkout, alternating, e.g.::

    git worktree add /tmp/old <commit>
    PYTHONPATH=/tmp/old python experiments/bench/batched_ab.py
    PYTHONPATH=. python experiments/bench/batched_ab.py

``--replay``: the table's setting instead (``netsense.speed.runners``: the benchmark model in
the sources form, freshness-policy actions recorded on a twin core and replayed, best of 4
blocks of 128 steps from a reset; needs a checkout with ``netsense.speed.runners``).

Results: ``experiments/results/bench/batched_ab/bench_batched_ab.txt`` (paper form) and
``experiments/results/bench/batched_ab/bench_batched_ab_replay.txt`` (``--replay``).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from netsense.engine.core import BatchedCore
from netsense.env.policies import FreshnessPolicy
from netsense.env.registry import build_model, load, with_overrides

SHAPES = ((1024, 10, 10), (1024, 30, 20), (64, 100, 20))

# model() and kernel_ms() restate netsense.speed's bench_model(substates="all") and
# kernel runner on purpose: the paper-form A/B must also run on checkouts that predate
# netsense.speed (e.g. 4ee9591).


def model(N: int, n: int):
    offs = sorted({o % N for o in (1, 3, 7)} - {0})
    sc = with_overrides(
        load("large_n20_N100-v1"), horizon=200,
        plant={"kind": "random_structured", "n": n, "num_agents": N, "seed": 0,
               "spectral_radius": 1.1},
        graph={"kind": "markov", "num_nodes": N, "p_fail": 0.1, "p_recover": 0.5,
               "draws": "base", "base": {"kind": "circulant", "offsets": offs}})
    return build_model(sc)


def core_ms(core: BatchedCore, pol: FreshnessPolicy, state: list, steps: int) -> float:
    """Seconds per ``step`` (policy between the steps, not timed) over ``steps`` steps."""
    obs, mask = state
    total = 0.0
    for _ in range(steps):
        act = pol.act(obs, mask)
        t0 = time.perf_counter()
        out = core.step(act)
        total += time.perf_counter() - t0
        obs, mask = out.obs, out.action_mask
        if out.truncated.any():
            obs, mask = core.reset(int(core.k.sum()))
    state[:] = [obs, mask]
    return total / steps * 1e3


def kernel_ms(Z, srcs, block_of, ADT, ALT, steps: int) -> float:
    B, N, n = Z.shape
    off = np.arange(B)[:, None, None] * (N * n) + np.arange(n)
    t0 = time.perf_counter()
    for k in range(steps):
        idx = np.take(srcs[k % 4], block_of, axis=2)
        idx *= n
        idx += off
        Z = np.take(Z.reshape(-1), idx) @ ADT + Z @ ALT
        Z *= 0.5
    return (time.perf_counter() - t0) / steps * 1e3


def replay_ms(B: int, N: int, n: int, steps: int = 128, repeats: int = 4) -> float:
    """Best ms per ``step`` replaying ``steps`` recorded freshness-policy actions."""
    from netsense.speed.runners import _ReplayRunner, bench_model

    rep = _ReplayRunner(bench_model(N, n), B, steps, 0)
    return min(rep.block() for _ in range(repeats)) / steps * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--replay", action="store_true", help="the speed table's setting")
    if ap.parse_args().replay:
        print(json.dumps({f"{B},{N},{n}": round(replay_ms(B, N, n), 3) for B, N, n in SHAPES}))
        return
    out = {}
    for B, N, n in SHAPES:
        m = model(N, n)
        core = BatchedCore(m, B)
        pol = FreshnessPolicy(core.layout)
        state = list(core.reset(0))
        dec = m.design.decomposition
        rng = np.random.default_rng(0)
        Z = rng.standard_normal((B, N, n))
        srcs = [rng.integers(0, N, (B, N, N)) for _ in range(4)]
        ADT, ALT = np.ascontiguousarray(dec.A_diag.T), np.ascontiguousarray(dec.A_lower.T)
        core_ms(core, pol, state, 4)
        kernel_ms(Z, srcs, dec.block_of, ADT, ALT, 2)
        best_c = best_k = float("inf")
        for _ in range(5):
            best_c = min(best_c, core_ms(core, pol, state, 32))
            best_k = min(best_k, kernel_ms(Z, srcs, dec.block_of, ADT, ALT, 32))
        out[f"{B},{N},{n}"] = {"core_ms": round(best_c, 3), "kernel_ms": round(best_k, 3)}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
