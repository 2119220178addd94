"""Training pipeline, stage *launch*: many runs (seeds x configurations) at once.

:func:`launch` trains a list of :class:`Run` (a :class:`PPOConfig`, an optional name and,
for the evolution strategy, an :class:`~netsense.rl.es.ESConfig`; :func:`make_runs` builds
seeds x configurations) with :func:`netsense.rl.ppo.train_ppo`, or
:func:`netsense.rl.es.train_es` for a run with ``es``,

* in this process, one run after another (``workers=1``, the default);
* in ``workers`` processes on this machine (spawned, not forked), each started with its
  thread pools sized to ``threads`` (:data:`~netsense.kernels.threads.THREAD_VARS`, read
  by OpenBLAS, MKL, OpenMP, numba and netsense's compiled passes when they load, so they
  are set in the environment the process starts with, before it imports numpy, numba or
  torch);
* or as Ray tasks (``ray_address``; each asks for ``resources``, one CPU by default, and
  starts with the same thread variables). A task trains into a temporary folder on the
  node that runs it and sends the run's files back with its result; this process writes
  them. So ``out`` need only exist where :func:`launch` runs: no shared filesystem.

Every way writes the same files: each run's folder ``OUT/seed_<s>`` (unnamed runs) or
``OUT/<name>/seed_<s>`` with what its trainer writes (``config.json``,
``log.csv``, checkpoints, ``policy.pt``, the run's ``summary.json``), and
``OUT/summary.json``: one entry per run, in the order given, with its status, and
``OUT/run.json`` (:mod:`netsense.rl.run_folder`): ``running`` while the runs train,
``finished`` when all of them have, ``failed`` when one failed. ``resume=True`` continues
an interrupted launch: finished runs are kept, unfinished ones resume from their last
checkpoint (a Ray task receives the files it resumes from); the evolution strategy keeps
no resume state, so an unfinished ES run starts again from its first generation. Seeded
training on the CPU is deterministic, so the weights and the log's non-timing columns
are the same too (``tests/test_rl_launch.py``). A run that raises is recorded
(``status: "failed"``, its error, traceback and config) and the others go on; one tqdm bar
counts finished runs (the runs' own bars only in this process).

Imports: :mod:`netsense.rl.config`, :mod:`netsense.rl.ppo` and :mod:`netsense.rl.es`; Ray
on demand.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from netsense.kernels.threads import THREAD_VARS, spawn_environment, thread_env
from netsense.rl.atomic import write_atomic, write_json
from netsense.rl.config import PPOConfig
from netsense.rl.es import ESConfig, train_es
from netsense.rl.ppo import train_ppo
from netsense.rl.resume import RESUME_FILE
from netsense.rl.run_folder import FINISHED, RUN_FILE, RUNNING, mark, run_status
from netsense.rl.runlog import read_log

__all__ = ["FINAL_COLUMNS", "THREAD_VARS", "Run", "launch", "make_runs", "spawn_environment",
           "thread_env"]

#: Last-row columns of a run's log copied into ``OUT/summary.json``.
FINAL_COLUMNS = ("eval_return", "eval_error", "eval_messages", "eval_sampled_return",
                 "eval_sampled_error", "eval_sampled_messages")
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")


@dataclass(frozen=True)
class Run:
    """One training run: ``config`` (its ``seed`` included), an optional ``name`` (the
    configuration's folder: letters, digits, ``_`` and ``-``, not ``seed_...``; or a
    path of such folders joined by ``/``, such as ``"<task>/<learner>"``, so that one
    launch trains the runs of several groups, one pool for all of them) and an
    optional ``es``: the run searches ``config``'s actor with the evolution strategy
    (:func:`~netsense.rl.es.train_es`) instead of training it with PPO."""

    config: PPOConfig
    name: str | None = None
    es: ESConfig | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.config, PPOConfig):
            raise TypeError(f"Run.config must be a PPOConfig, got {type(self.config).__name__}")
        if self.es is not None and not isinstance(self.es, ESConfig):
            raise TypeError(f"Run.es must be an ESConfig or None, got {type(self.es).__name__}")
        if self.name is not None and (
                not isinstance(self.name, str)
                or not all(_NAME.fullmatch(part) and not part.startswith("seed_")
                           for part in self.name.split("/"))):
            raise ValueError(f"Run.name must be letters, digits, '_' and '-' (a folder "
                             f"name, not starting with 'seed_'), or such names joined by "
                             f"'/', got {self.name!r}")

    @property
    def folder(self) -> str:
        """The run's folder relative to the launch's ``out``."""
        leaf = f"seed_{self.config.seed}"
        return leaf if self.name is None else f"{self.name}/{leaf}"


def make_runs(configs: PPOConfig | Mapping[str, PPOConfig], seeds: Sequence[int], *,
              es: ESConfig | None = None) -> list[Run]:
    """Seeds x configurations: one :class:`Run` per (configuration, seed), configurations
    outer. A single :class:`PPOConfig` gives unnamed runs (``OUT/seed_<s>``); a mapping
    ``{name: config}`` named ones (``OUT/<name>/seed_<s>``). The configs' own seeds are
    replaced. ``es``: every run searches with the evolution strategy (:class:`Run`)."""
    seeds = list(seeds)
    if not seeds:
        raise ValueError("make_runs: seeds must name at least one seed")
    if isinstance(configs, PPOConfig):
        return [Run(replace(configs, seed=s), es=es) for s in seeds]
    if not isinstance(configs, Mapping) or not configs:
        raise TypeError("make_runs: configs must be a PPOConfig or a non-empty mapping "
                        f"name -> PPOConfig, got {configs!r}")
    return [Run(replace(cfg, seed=s), name, es) for name, cfg in configs.items() for s in seeds]


def _final(entry: dict, rows: list[dict]) -> None:
    last = rows[-1] if rows else {}
    entry.update({k: last.get(k) for k in FINAL_COLUMNS})


def _train_one(run: Run, folder: str | None, progress: bool = False, resume: bool = False,
               given: dict[str, bytes] | None = None) -> dict:
    """Train ``run`` into ``folder``; ``None``: into a temporary folder whose files come
    back in the entry's ``files`` (relative path -> bytes), after ``given`` (the files a
    resumed run continues from) is written there. ``resume``: continue the run in the
    folder (:func:`train_ppo`'s ``resume``; an ES run starts again). Never raises for a
    failed run: the entry says ``status: "failed"`` with the error. Module level: worker
    processes and Ray tasks import it by name."""
    entry: dict = {"name": run.name, "seed": run.config.seed, "folder": run.folder,
                   "thread_env": {k: os.environ[k] for k in THREAD_VARS if k in os.environ}}
    tmp = tempfile.mkdtemp(prefix="netsense-run-") if folder is None else None
    target = Path(tmp if folder is None else folder)
    try:
        if given:
            _write_files(target, given)
        if run.es is not None:  # no resume state: an interrupted search starts again
            train_es(run.config, run.es, target, progress=progress, overwrite=resume)
            entry.update(_finished_entry(run, target, None))  # from its log and summary
        else:
            res = train_ppo(run.config, target, progress=progress, resume=resume)
            entry["status"] = "ok"
            _final(entry, res.rows)
            entry.update({"agent_steps": res.agent_steps, "wall_s": round(res.wall_s, 2),
                          "agent_steps_per_s": round(res.agent_steps_per_s, 1),
                          "mask_violations": res.mask_violations})
    except Exception as exc:  # noqa: BLE001 - a failed run is reported, the others go on
        entry.update({"status": "failed", "error": f"{type(exc).__name__}: {exc}",
                      "traceback": traceback.format_exc(),
                      "config": _as_json(run.config)})
    if tmp is not None:
        try:
            entry["files"] = {p.relative_to(target).as_posix(): p.read_bytes()
                              for p in sorted(target.rglob("*")) if p.is_file()}
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return entry


def _as_json(config: PPOConfig) -> dict:
    """``config`` as ``config.json`` holds it (tuples as lists)."""
    return json.loads(json.dumps(asdict(config), default=list))


def _died(run: Run, error: str) -> dict:
    """The entry of a run whose worker process died (no traceback of the run's own)."""
    return {"name": run.name, "seed": run.config.seed, "folder": run.folder,
            "status": "failed", "error": error, "config": _as_json(run.config)}


def _write_files(root: Path, files: dict[str, bytes]) -> None:
    """``files`` (relative path -> bytes) under ``root``, each whole or not at all, the
    run marker last (a run's folder is finished only once all its files are there)."""
    for rel in sorted(files, key=lambda r: Path(r).name == RUN_FILE):
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, files[rel])


#: The files a run continues from (:func:`train_ppo`'s ``resume``); its checkpoints stay.
RESUME_FILES = (RESUME_FILE, "log.csv", "config.json", RUN_FILE)


def _given(folder: Path) -> dict[str, bytes]:
    """The files of an unfinished run that a Ray task resumes it from."""
    return {n: (folder / n).read_bytes() for n in RESUME_FILES if (folder / n).is_file()}


def _finished_entry(run: Run, folder: Path, before: dict | None) -> dict:
    """The summary entry of a run that finished before a resumed launch: its entry in the
    launch's earlier ``summary.json``, else (``before=None``: also an ES run just trained)
    one rebuilt from the run's own files."""
    if before is not None and before.get("status") == "ok":
        return before
    meta = json.loads((folder / "summary.json").read_text()) \
        if (folder / "summary.json").is_file() else {}
    rows, _ = read_log(folder / "log.csv")
    entry = {"name": run.name, "seed": run.config.seed, "folder": run.folder, "status": "ok"}
    _final(entry, rows)
    entry.update({k: meta.get(k) for k in ("agent_steps", "wall_s", "agent_steps_per_s",
                                           "mask_violations")})
    return entry


def _positive_int(value, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{what} must be an integer >= 1, got {value!r}")
    return value


def launch(runs: Sequence[Run], out: str | Path, *, workers: int = 1,
           threads: int | None = 1, ray_address: str | None = None,
           resources: Mapping | None = None, progress: bool = True,
           resume: bool = False) -> list[dict]:
    """Train ``runs`` into ``out`` (see the module docstring for the files).

    Parameters
    ----------
    runs : sequence of Run
        Their folders must differ (a name and a seed each).
    out : path
        Output folder (created).
    workers : int
        Runs at once on this machine: 1 trains them in this process, one after another;
        more starts that many spawned processes. Not with ``ray_address``.
    threads : int or None
        Threads of each worker process or Ray task (:data:`THREAD_VARS`, default 1: K
        runs on K cores do not oversubscribe them); ``None`` leaves the environment as it
        is. The configs' ``torch_threads`` / ``numba_threads`` choose within it. Not
        used in this process (``workers=1``).
    ray_address : str, optional
        Run each as a Ray task, ``ray.init(address=ray_address)``: ``"local"`` starts a
        Ray instance on this machine, ``"auto"`` joins the cluster this machine belongs
        to (``ray start``), ``"HOST:6379"`` a cluster's head, ``"ray://HOST:10001"``
        connects a Ray client. Where this process has initialised Ray already, its
        instance is used whatever the address; otherwise :func:`launch` shuts Ray down at
        the end.
    resources : mapping, optional
        Ray resources of each task, ``.options(**resources)`` (default
        ``{"num_cpus": 1}``; e.g. ``{"num_cpus": 2, "num_gpus": 0.5}``).
    progress : bool
        One tqdm bar over runs (and, in this process, each run's own bar).
    resume : bool
        Continue a launch that was interrupted: a run whose folder holds a finished run
        is not trained again (its entry is kept), an unfinished one continues from its
        last checkpoint (:func:`train_ppo`'s ``resume``; an unfinished ES run starts
        again), one not started starts.

    Returns
    -------
    list of dict
        The entries of ``OUT/summary.json``, in the order of ``runs``: ``name``,
        ``seed``, ``folder``, ``thread_env`` (the :data:`THREAD_VARS` set in the process
        that trained it), ``status`` (``"ok"`` / ``"failed"``), the last row's
        :data:`FINAL_COLUMNS`, ``agent_steps``, ``wall_s``, ``agent_steps_per_s`` and
        ``mask_violations``; failed runs ``error``, ``traceback`` and ``config`` instead.
    """
    runs = list(runs)
    if not runs:
        raise ValueError("launch: runs is empty")
    for r in runs:
        if not isinstance(r, Run):
            raise TypeError(f"launch: runs must be Run objects (make_runs builds them), "
                            f"got {type(r).__name__}")
    folders = [r.folder for r in runs]
    dup = sorted({f for f in folders if folders.count(f) > 1})
    if dup:
        raise ValueError(f"launch: runs share output folders {dup} (give each "
                         "configuration a name and each of its runs its own seed)")
    workers = _positive_int(workers, "launch: workers")
    if threads is not None:
        _positive_int(threads, "launch: threads")
    if ray_address is not None:
        if not isinstance(ray_address, str) or not ray_address:
            raise ValueError(f"launch: ray_address must be 'local', 'auto' or a Ray "
                             f"address, got {ray_address!r}")
        if workers != 1:
            raise ValueError("launch: workers sets the processes on this machine; with "
                             "ray_address Ray places the runs (set resources instead)")
    if resources is not None:
        if ray_address is None:
            raise ValueError("launch: resources are Ray's; give ray_address too")
        resources = dict(resources)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    before: dict[str, dict] = {}
    if resume and (out / "summary.json").is_file():
        try:
            before = {e["folder"]: e for e in json.loads((out / "summary.json").read_text())
                      if isinstance(e, dict) and "folder" in e}
        except (ValueError, TypeError):
            before = {}
    mark(out, RUNNING, kind="launch", runs=folders)

    from tqdm.auto import tqdm

    entries: list[dict | None] = [None] * len(runs)
    bar = tqdm(total=len(runs), desc="runs", unit="run", disable=not progress)

    def write_summary() -> list[dict]:
        summary = [e for e in entries if e is not None]
        write_json(out / "summary.json", summary)
        return summary

    def done(i: int, entry: dict) -> None:
        files = entry.pop("files", None)
        if files is not None:
            _write_files(out / runs[i].folder, files)
            if RESUME_FILE not in files:  # the run finished where it ran
                (out / runs[i].folder / RESUME_FILE).unlink(missing_ok=True)
        entries[i] = entry
        write_summary()  # after every run: an interrupted sweep keeps what finished
        bar.update()
        failed = sum(e is not None and e["status"] == "failed" for e in entries)
        if failed:
            bar.set_postfix(failed=failed)

    todo = []
    for i, r in enumerate(runs):
        status = run_status(out / r.folder) if resume else None
        if status == FINISHED:  # trained before the interruption: kept as it is
            done(i, _finished_entry(r, out / r.folder, before.get(r.folder)))
        else:
            todo.append(i)
    again = {i: resume and run_status(out / runs[i].folder) is not None for i in todo}
    try:
        if ray_address is not None:
            _on_ray(runs, todo, again, out, ray_address, resources or {"num_cpus": 1},
                    threads, done)
        elif workers == 1:
            for i in todo:
                r = runs[i]
                done(i, _train_one(r, str(out / r.folder), progress, again[i]))
        else:
            _in_processes(runs, todo, again, out, workers, threads, done)
    finally:
        bar.close()
    summary = write_summary()
    ok = len(summary) == len(runs) and all(e["status"] == "ok" for e in summary)
    mark(out, FINISHED if ok else "failed", kind="launch", runs=folders)
    return summary


def _in_processes(runs: list[Run], todo: list[int], again: dict[int, bool], out: Path,
                  workers: int, threads: int | None,
                  done: Callable[[int, dict], None]) -> None:
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    ctx = mp.get_context("spawn")
    if not todo:
        return
    pool = ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=ctx)
    try:
        # the pool spawns its processes on submit (spawn context), inside the environment
        with spawn_environment(thread_env(threads)):
            futs = {pool.submit(_train_one, runs[i], str(out / runs[i].folder), False,
                                again[i]): i for i in todo}
        for fut in as_completed(futs):
            i = futs[fut]
            try:
                entry = fut.result()
            except BrokenProcessPool as exc:  # a worker died: every run not finished fails
                entry = _died(runs[i], f"{exc} (out of memory? A script that calls launch "
                                       "with workers > 1 needs its entry point under `if "
                                       "__name__ == '__main__':`: each worker imports it)")
            done(i, entry)
    except BaseException:  # interrupted: start no further run
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()


def _on_ray(runs: list[Run], todo: list[int], again: dict[int, bool], out: Path,
            address: str, resources: dict, threads: int | None,
            done: Callable[[int, dict], None]) -> None:
    if not todo:
        return
    import ray

    started = not ray.is_initialized()
    if started:
        try:
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
        except ConnectionError as exc:
            raise ConnectionError(
                f"{exc}; if the cluster uses token authentication, set RAY_AUTH_MODE=token "
                "here with the head's ~/.ray/auth_token (docs/rl.md, 'A Ray cluster')"
            ) from exc
    try:
        env = thread_env(threads)
        task = ray.remote(_train_one).options(
            **resources, max_retries=0,
            **({"runtime_env": {"env_vars": env}} if env else {}))
        refs = {task.remote(runs[i], None, False, again[i],
                            _given(out / runs[i].folder) if again[i] else None): i
                for i in todo}
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                i = refs[ref]
                try:
                    entry = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - the task's worker died
                    entry = _died(runs[i], f"{type(exc).__name__}: {exc}")
                done(i, entry)
    finally:
        if started:
            ray.shutdown()
