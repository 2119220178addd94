"""Running jobs: one episode (:func:`run_job`), batched seeds (:func:`run_batched`) and
the backends of :func:`execute` (batched, process, serial, ray).

:func:`run_job` stays module level here: worker processes and Ray tasks pickle it by
its module path (``netsense.benchmark.backends.run_job``).
"""

from __future__ import annotations

import numbers
import os
from collections.abc import Callable, Sequence
from dataclasses import asdict

import numpy as np

from netsense.benchmark.metrics import episode_metrics
from netsense.benchmark.records import EpisodeRecord, Job
from netsense.benchmark.rollouts import NotApplicable, rollout, rollout_oracle
from netsense.kernels.threads import spawn_environment, thread_env


def _result(job: Job, rec: EpisodeRecord) -> dict:
    """The result dict of ``job`` from its record (shared by every backend)."""
    rel = rec.relative_errors()
    return {"job": asdict(job), "metrics": episode_metrics(rec, job.eps),
            "curve": np.mean(rel, axis=1)}


def run_job(job: Job) -> dict | None:
    """Run one episode; returns ``{"job": ..., "metrics": ..., "curve": ...}``.

    ``curve`` is the mean-over-agents relative error per step (for the plots); None when
    the policy does not apply to the scenario. Module level so that worker processes and
    Ray tasks can import it.
    """
    try:
        if job.policy == "kf_oracle":
            rec = rollout_oracle(job.scenario, job.seed, job.overrides)
        else:
            rec = rollout(job.scenario, job.policy, job.seed, job.overrides)
    except NotApplicable:
        return None
    return _result(job, rec)


#: Memory budget (bytes) of the records of one batch of the batched backend; larger
#: groups of seeds run as several batches (e.g. 16 seeds of a 100-agent, 200-step
#: scenario, whose freshness indices alone take 16 MB per episode).
BATCH_BYTES = 256 * 2**20


def _members_per_batch(model) -> int:
    """Seeds per batch so that the records of one batch stay within :data:`BATCH_BYTES`."""
    N, K = model.plant.num_agents, int(model.horizon)
    per_member = (K + 1) * (8 * N * N + 8 * N + 8) + K * 9 * N  # indices, errors, ...
    return max(1, BATCH_BYTES // per_member)


def run_batched(jobs: Sequence[Job], *, runner: Callable[[Job], dict | None] = run_job,
                on_done: Callable[[int], object] | None = None) -> list[dict | None]:
    """Run ``jobs`` as batched simulations, one per (scenario, policy, overrides) group.

    The seeds of a group run as one :func:`netsense.benchmark.batched.rollout_seeds` batch (split
    into batches whose records fit :data:`BATCH_BYTES`), so a group costs about one
    episode of Python per step instead of one per seed. Policies outside
    :data:`netsense.benchmark.batched.BATCHABLE_POLICIES` (``learned``) run job by job through
    ``runner`` in this process. A group whose policy does not apply to the scenario
    (:class:`NotApplicable`) gives None for each of its jobs, as :func:`run_job` does.

    Parameters
    ----------
    jobs : sequence of Job
    runner : callable
        Per-job function for the policies that cannot batch.
    on_done : callable, optional
        Called with the number of jobs just finished (progress).

    Returns
    -------
    list of dict or None
        One entry per job, in job order, equal to ``[runner(job) for job in jobs]``
        (estimates up to the last bits of the matrix products).
    """
    from netsense.benchmark.batched import BATCHABLE_POLICIES, rollout_seeds
    from netsense.env.comm_policies import spec_family
    from netsense.env.vector import load_model

    jobs = list(jobs)
    done = on_done or (lambda count: None)
    results: list[dict | None] = [None] * len(jobs)
    groups: list[tuple[tuple, list[int]]] = []  # overrides are dicts: compared, not hashed
    for i, job in enumerate(jobs):
        key = (job.scenario, job.policy, job.overrides)
        for k, members in groups:
            if k == key:
                members.append(i)
                break
        else:
            groups.append((key, [i]))
    for (scenario, policy, overrides), idx in groups:
        if spec_family(policy) not in BATCHABLE_POLICIES:
            for i in idx:
                results[i] = runner(jobs[i])
                done(1)
            continue
        model, _ = load_model(scenario, **overrides)
        size = _members_per_batch(model)
        for start in range(0, len(idx), size):
            part = idx[start:start + size]
            try:
                recs = rollout_seeds(model, policy, [jobs[i].seed for i in part])
            except NotApplicable:
                done(len(idx) - start)  # the whole group is skipped
                break
            for i, rec in zip(part, recs, strict=True):
                results[i] = _result(jobs[i], rec)
            done(len(part))
    return results


def _progress(total: int, desc: str, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, disable=not enabled, unit="ep")


#: Backends of :func:`execute`.
BACKENDS = ("batched", "process", "serial", "ray")


def execute(jobs: Sequence[Job], *, backend: str = "batched", workers: int | None = None,
            ray_address: str | None = None, progress: bool = True,
            runner: Callable[[Job], dict | None] = run_job) -> list[dict]:
    """Run ``jobs`` and return their results in job order (skipping inapplicable ones).

    Parameters
    ----------
    jobs : sequence of Job
    backend : {"batched", "process", "serial", "ray"}
        ``batched``: the seeds of each (scenario, policy, overrides) as one batched run
        in this process (:func:`run_batched`; learned policies episode by episode);
        ``process``: one episode per job in worker processes; ``serial``: one episode per
        job in this process; ``ray``: one episode per job as Ray tasks. All return the
        same results (batched: estimates up to the last bits of the matrix products).
    workers : int, optional
        Process count of ``process`` (default ``min(len(jobs), os.cpu_count())``; 1 runs
        the jobs in this process). Only ``process`` takes it: the other backends raise a
        ValueError when it is given rather than ignore it.
    ray_address : str, optional
        ``ray.init(address=...)`` (e.g. ``"auto"`` or ``"ray://head:10001"``); default a
        local Ray instance.
    progress : bool
        Show a tqdm bar (per episode; per batch of seeds with ``batched``).
    runner : callable
        The per-job function (module level, picklable); with ``batched`` it runs only
        the jobs whose policy cannot batch.

    Returns
    -------
    list of dict
        ``{"job", "metrics", "curve"}`` per applicable job (see :func:`run_job`).
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(map(repr, BACKENDS))}, "
                         f"got {backend!r}")
    if workers is not None:
        if isinstance(workers, bool) or not isinstance(workers, numbers.Integral):
            raise ValueError(f"workers must be a positive integer, got {workers!r}")
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        if backend != "process":
            raise ValueError(f"workers sets the process count of backend='process'; "
                             f"backend {backend!r} does not take it (got workers={workers})")
    jobs = list(jobs)
    results: list[dict | None] = [None] * len(jobs)
    bar = _progress(len(jobs), f"benchmark ({backend})", progress)
    try:
        if backend == "batched":
            results = run_batched(jobs, runner=runner, on_done=bar.update)
        elif backend == "serial" or (backend == "process" and workers == 1):
            for i, job in enumerate(jobs):
                results[i] = runner(job)
                bar.update()
        elif backend == "process":
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor, as_completed

            n = workers or min(len(jobs), os.cpu_count() or 1)
            ctx = mp.get_context("spawn")
            with spawn_environment(thread_env(1)), ProcessPoolExecutor(
                    max_workers=max(n, 1), mp_context=ctx) as pool:
                futs = {pool.submit(runner, job): i for i, job in enumerate(jobs)}
                for fut in as_completed(futs):
                    results[futs[fut]] = fut.result()
                    bar.update()
        else:
            import ray

            if not ray.is_initialized():
                ray.init(address=ray_address, include_dashboard=False,
                         ignore_reinit_error=True, log_to_driver=False)
            remote = ray.remote(num_cpus=1)(runner)
            refs = {remote.remote(job): i for i, job in enumerate(jobs)}
            pending = list(refs)
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for ref in done:
                    results[refs[ref]] = ray.get(ref)
                    bar.update()
    finally:
        bar.close()
    return [r for r in results if r is not None]


