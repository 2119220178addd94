"""Benchmark harness: scenarios x policies x seeds, with metrics, tables and plots.

One *job* is one episode of one scenario under one policy and one seed. A job returns an
:class:`EpisodeRecord` (per-step curves) which :func:`episode_metrics` reduces to the
numbers of the table:

==========================  ================================================================
metric                      definition
==========================  ================================================================
``mean_rel_error``          mean over steps ``k = 1..K`` and agents ``i`` of
                            ``e_i[k] = ||x_hat_i[k] - x[k]|| / max(||x[k]||, floor)``
``final_rel_error``         mean over agents of ``e_i[K]`` (the last step)
``steps_to_eps``            first ``k`` from which ``max_i e_i[k'] <= eps`` for every
                            ``k' >= k`` (NaN when it is never reached)
``msgs_per_agent_step``     transmissions / (``N`` x ``K``)
``aoi_mean``, ``aoi_max``   mean / max over steps, agents and substates ``j != i`` of the
                            freshness index ``tau_i^{(j)}`` (finite entries only)
``aoi_omega_frac``          fraction of those entries still equal to omega
``reward``                  the scenario's episode return, averaged over agents
==========================  ================================================================

Policies (names accepted by :func:`run_benchmark` and ``netsense benchmark``):

``freshness``, ``uniform_consensus``, ``tree_consensus``, ``open_loop``, ``random``
    the scripted policies of :mod:`netsense.env.policies`, acting through the environment;
``kf_oracle``
    a centralized Kalman filter that sees every agent's measurement every step (no
    network): a lower bound on the error, no messages and no reward;
``always``, ``never``, ``periodic:P``, ``bernoulli:p``, ``sources:P``, ``event:d``,
``until:T``, ``settle:e``, ``aloha:g,q``, ``tdma:F``, ``oldest:m``, ``whittle:m``,
``gated(BASE)``, ``acked[:T](BASE)``, ``phased[:P](BASE)``, ``oracle(BASE)``,
``oracle_channel(BASE)``
    the communication baselines of
    :mod:`netsense.env.comm_policies` (communication-only scenarios; not applicable, hence
    skipped, on full-control ones); the informed rules refuse, by name, a scenario whose
    observation lacks the field they read; the ``oracle`` rules are privileged;
``learned`` / ``learned:PATH`` / ``learned_sampled:PATH``
    a policy trained by :mod:`netsense.rl.sb3` and loaded from ``PATH`` (a ``.zip``); in
    ``PATH`` the text ``{scenario}`` is replaced by the scenario id; ``learned_sampled``
    samples its actions (torch seeded with the episode's seed) instead of taking the most
    likely one.

The evaluation protocol of the communication tasks (seeds, bootstrap intervals, the
scripted frontier, Pareto plots; ``netsense benchmark --frontier``) is
:mod:`~netsense.benchmark.protocol`.

Backends (:func:`execute`), all with a tqdm bar and the same results in job order:

``batched`` (default)
    the jobs of one (scenario, policy, overrides) run as **one** batched simulation
    (:func:`netsense.benchmark.batched.rollout_seeds`, one :class:`netsense.engine.core.BatchedCore`
    member per seed) instead of one episode per seed; every policy but ``learned``
    batches (``random`` with one generator per member, ``kf_oracle`` with a batched
    centralized filter), and member ``b``'s record equals the single episode of its seed.
    ``learned`` policies run episode by episode in the calling process;
``process`` / ``serial``
    one episode per job (:func:`run_job`) in worker processes / in the calling process;
``ray``
    one episode per job as Ray tasks, optionally on a cluster given by ``ray_address``
    (for learned policies or many scenarios on many machines).

Modules: :mod:`~netsense.benchmark.records` (episode records, jobs),
:mod:`~netsense.benchmark.metrics` (the table's metrics), :mod:`~netsense.estimators.oracle`
(the centralized filter), :mod:`~netsense.benchmark.rollouts` (policy names, single
episodes), :mod:`~netsense.benchmark.backends` (running jobs), :mod:`~netsense.benchmark.report`
(aggregation, CSV, table, plots); this module re-exports their public names and holds
:func:`make_jobs` and :func:`run_benchmark`.

Tool layer. May import every layer up to :mod:`netsense.env`, and :mod:`netsense.grid`
and :mod:`netsense.rl` (learned policies).
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

from netsense.benchmark.backends import BACKENDS, execute, run_batched, run_job
from netsense.benchmark.metrics import METRICS, aoi_statistics, episode_metrics, steps_to_epsilon
from netsense.benchmark.records import EpisodeRecord, EpisodeRecorder, Job, relative_errors
from netsense.benchmark.report import (
    _fmt_csv,
    aggregate,
    markdown_table,
    plot_errors,
    plot_reward_vs_messages,
    write_csv,
)
from netsense.benchmark.rollouts import (
    DEFAULT_POLICIES,
    POLICY_NAMES,
    NotApplicable,
    rollout,
    rollout_oracle,
    scripted_policy,
)
from netsense.env.policies import SCRIPTED_POLICIES
from netsense.estimators.oracle import CentralizedKF
from netsense.rl.atomic import atomic_path, write_atomic

__all__ = [
    "BACKENDS", "DEFAULT_POLICIES", "METRICS", "POLICY_NAMES",
    "SCRIPTED_POLICIES", "CentralizedKF", "EpisodeRecord", "EpisodeRecorder", "Job",
    "NotApplicable", "aggregate", "aoi_statistics", "episode_metrics", "execute",
    "make_jobs", "markdown_table", "plot_errors", "plot_reward_vs_messages",
    "relative_errors", "rollout", "rollout_oracle", "run_batched", "run_benchmark",
    "run_job", "scripted_policy", "steps_to_epsilon", "write_csv",
]


def make_jobs(scenarios: Sequence[str], policies: Sequence[str], seeds: Sequence[int], *,
              overrides: dict | None = None, eps: float = 1e-2) -> list[Job]:
    """Cartesian product of scenarios x policies x seeds (unknown policy names raise)."""
    from netsense.env.comm_policies import spec_family
    from netsense.kernels import checks  # (seeds and eps checked: 1.5 is not a seed)

    seeds = [checks.seed_value("seeds[]", s) for s in seeds]
    checks.number("eps", eps, 0, lo_open=True)
    for p in policies:
        if spec_family(p) not in POLICY_NAMES:
            raise ValueError(f"unknown policy {p!r}; choose from {', '.join(POLICY_NAMES)} "
                             "(learned may be written learned:PATH)")
    if not scenarios or not policies or not seeds:
        raise ValueError("scenarios, policies and seeds must each be non-empty")
    return [Job(s, p.replace("{scenario}", s), int(seed), dict(overrides or {}), eps)
            for s in scenarios for p in policies for seed in seeds]


def run_benchmark(scenarios: Sequence[str], policies: Sequence[str] = DEFAULT_POLICIES,
                  seeds: Sequence[int] = range(5), *, out: str | Path | None = None,
                  overrides: dict | None = None, eps: float = 1e-2, backend: str = "batched",
                  workers: int | None = None, ray_address: str | None = None,
                  progress: bool = True) -> tuple[list[dict], list[dict]]:
    """Run the benchmark and (when ``out`` is given) write its CSV, table and plots.

    Writes ``episodes.csv`` (one row per episode), ``summary.csv`` and ``summary.md``
    (mean ± std over seeds), ``errors_<scenario>.png`` and ``reward_vs_messages.png``.

    Parameters
    ----------
    scenarios : sequence of str
        Scenario ids.
    policies : sequence of str
        Policy names (see the module docstring).
    seeds : sequence of int
        Seeds of every (scenario, policy).
    out : str or Path, optional
        Output directory (nothing is written without it).
    overrides : dict, optional
        Scenario overrides for every scenario.
    eps : float
        Threshold of ``steps_to_eps``.
    backend, workers, ray_address, progress
        As in :func:`execute` (default ``backend="batched"``).

    Returns
    -------
    results, rows
        Per-episode results and the aggregated rows.
    """
    jobs = make_jobs(scenarios, policies, seeds, overrides=overrides, eps=eps)
    results = execute(jobs, backend=backend, workers=workers, ray_address=ray_address,
                      progress=progress)
    rows = aggregate(results)
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        write_csv(results, out / "episodes.csv")
        with atomic_path(out / "summary.csv") as tmp, tmp.open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows({k: _fmt_csv(v) if isinstance(v, float) else v for k, v in r.items()}
                        for r in rows)
        write_atomic(out / "summary.md", markdown_table(rows, eps))
        for sc in dict.fromkeys(scenarios):
            plot_errors(results, out / f"errors_{sc}.png", sc)
        plot_reward_vs_messages(rows, out / "reward_vs_messages.png")
    return results, rows
