"""The benchmark model and the timed contenders of :mod:`netsense.speed`.

:func:`bench_model` is the benchmark scenario at size ``(N, n)``. Each runner's
``block(steps)`` returns the seconds its contender spends in ``steps`` steps (what each
one measures is described in :mod:`netsense.speed`): ``core`` is :class:`_ReplayRunner`,
``core_live`` :class:`_CoreRunner`, ``kernel`` :class:`_KernelRunner` and ``vmas``
:class:`_VmasRunner` (driven in its own process by :class:`_VmasProcess`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from netsense.engine.core import BatchedCore
from netsense.engine.model import CoreModel


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
    from netsense.env.registry import build_model, load, with_overrides

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
        from netsense.env.policies import FreshnessPolicy

        self.core = BatchedCore(model, B)
        self.policy = FreshnessPolicy(self.core.layout)
        self.obs, self.mask = self.core.reset(seed)

    def block(self, steps: int) -> float:
        core, pol = self.core, self.policy
        total = 0.0
        for _ in range(steps):
            act = pol.act(self.obs, self.mask)
            t0 = time.perf_counter()
            out = core.step(act)
            total += time.perf_counter() - t0
            self.obs, self.mask = out.obs, out.action_mask
            if out.truncated.any():  # stay inside the horizon (reset is not timed)
                self.obs, self.mask = core.reset(int(core.k.sum()))
        return total


class _ReplayRunner:
    """The core stepping through ``steps`` freshness-policy actions recorded on a twin
    core from the same seed (so every action is valid); ``block()`` resets (not timed)
    and times the replay: the core in a hot loop of its own work, like the kernel."""

    def __init__(self, model: CoreModel, B: int, steps: int, seed: int = 0) -> None:
        from netsense.env.policies import FreshnessPolicy

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

    Written here in plain numpy (the roofline), not with the package's compiled
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
        # as many threads as the core's numba threads; on a loaded machine torch's
        # default thread pool is much slower and erratic (oversubscription)
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


class _VmasProcess:
    """:class:`_VmasRunner` in a process of its own (same ``block``/``threads``).

    torch brings its own OpenMP runtime; in the core's process its thread pool slowed
    the core's later blocks (measured at (64, 100, 20): 0.52x the kernel before a VMAS
    shape, 0.47x after it, and 0.37x at the end of a three-shape run), so VMAS runs in a
    spawned worker that the benchmark drives block by block, interleaved as before.
    """

    def __init__(self, B: int, N: int, seed: int = 0, threads: int | None = None) -> None:
        import multiprocessing as mp

        if threads is None:
            import numba

            threads = numba.get_num_threads()
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_vmas_worker, args=(child, B, N, seed, threads),
                                 daemon=True)
        self._proc.start()
        child.close()
        self.threads = self._recv()

    def _recv(self):
        kind, value = self._conn.recv()
        if kind == "error":
            self.close()
            raise RuntimeError(f"VMAS worker failed: {value}")
        return value

    def block(self, steps: int) -> float:
        self._conn.send(int(steps))
        return self._recv()

    def close(self) -> None:
        if self._proc.is_alive():
            try:
                self._conn.send(None)
            except (BrokenPipeError, OSError):
                pass
            self._proc.join(timeout=10)
        if self._proc.is_alive():
            self._proc.kill()
        self._conn.close()


def _vmas_worker(conn, B: int, N: int, seed: int, threads: int) -> None:
    try:
        runner = _VmasRunner(B, N, seed, threads)
        conn.send(("ok", runner.threads))
        while (steps := conn.recv()) is not None:
            conn.send(("ok", runner.block(steps)))
    except Exception as exc:  # noqa: BLE001 - reported to the benchmark process
        conn.send(("error", repr(exc)))
    finally:
        conn.close()


def vmas_available() -> bool:
    """Whether ``vmas`` can be imported."""
    try:
        import vmas  # noqa: F401
    except ImportError:
        return False
    return True
