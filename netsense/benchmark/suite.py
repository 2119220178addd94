"""The benchmark suite: score any policy on the nine communication tasks with one call.

:func:`score` takes policies (files any trainer can write, runs folders of ``netsense
train``, Python callables), runs each on every task of
:data:`~netsense.benchmark.references.SUITE_TASKS` on the protocol's held-out episodes
(seeds ``10^6 ..``, :func:`netsense.benchmark.protocol.eval_seeds`) through
:func:`netsense.benchmark.protocol.evaluate`, and returns a :class:`SuiteResult`: per task
and policy, the IQM of the return over training seeds x episodes with its 95 % stratified
bootstrap interval, the probability of improvement over the best decentralised rule on the
same episodes, and normalised scores, ``never`` = 0 and the certified upper bound = 1, with
the best decentralised rule and the best full-information reference on the same scale;
and the aggregate over the tasks (IQM of the normalised scores with its interval). The
statistics are :mod:`netsense.benchmark.scores`'; the reference points are
:mod:`netsense.benchmark.references`' (one package data file). ``netsense suite score``
is the command line (docs/suite.md).

Policies (:func:`score`'s ``policies``: a mapping of a name to one of these):

* a path to a policy file: ``.npz`` (:mod:`netsense.benchmark.mlp_policy`, any framework)
  or ``.pt`` (netsense's trainer); the file names its task;
* a path to a runs folder: ``DIR/<task>/[<learner>/]seed_<s>/`` holding ``netsense train``
  output (``policy.pt``, ``policy.zip`` or a ``policy.npz``); an unfinished run is
  refused by name (:func:`netsense.rl.run_folder.check_finished`);
* ``"rule:SPEC"``: a scripted communication rule (``rule:event:2``) on every task;
* a callable ``act(obs, mask) -> actions`` (arrays ``(B, N, ...)``), used on every task;
* :func:`builder` ``(fn)``: ``fn(core, seeds) -> act``, built on each task's
  :class:`~netsense.engine.core.BatchedCore` (a rule that needs the core's layout);
* a list of the above: one entry per training seed; a ``{task: ...}`` mapping: per task.

Every policy acts in the task's communication-only control mode (the references'
``control``); a learned policy trained in another mode is refused.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from netsense.benchmark.intervals import bootstrap_ci
from netsense.benchmark.references import (
    KNOWN_TASKS,
    SUITE_TASKS,
    TaskReferences,
    load_references,
)
from netsense.benchmark.suite_output import AGGREGATE, TABLE_COLUMNS

__all__ = ["AGGREGATE", "SUITE_TASKS", "TABLE_COLUMNS", "Builder", "SuiteResult", "builder",
           "read_episodes", "rescore", "resolve", "runs_folder", "score", "summarise",
           "task_layout"]

#: Final policy files of a run folder, in the order they are looked for.
POLICY_FILES = ("policy.npz", "policy.pt", "policy.zip")


@dataclass(frozen=True)
class Builder:
    """A policy built on the evaluated core: ``fn(core, seeds) -> act(obs, mask)``."""

    fn: Callable


def builder(fn: Callable) -> Builder:
    """Mark ``fn(core, seeds) -> act`` as a builder (a plain callable is ``act`` itself)."""
    if not callable(fn):
        raise ValueError(f"builder takes a callable, got {type(fn).__name__}")
    return Builder(fn)


@dataclass(frozen=True)
class _Run:
    """One trained policy of one task: what :func:`score` evaluates."""

    task: str
    seed: int
    kind: str  # "file" (.pt / .zip: protocol's learned:), "npz", "act", "builder", "rule"
    obj: object
    source: str


def task_layout(task: str) -> dict:
    """What a policy of ``task`` reads and writes in the suite: ``control`` (the
    communication-only mode it is scored in), ``n_agents``, ``obs_dim`` (one agent's flat
    observation, ``obs["observation"]`` of ``netsense.make(task, control={"mode":
    control})``) and ``nvec`` (choices per action entry; the flat action mask has
    ``sum(nvec)`` entries)."""
    from netsense.engine.core import BatchedCore
    from netsense.env.vector import load_model

    refs = load_references()
    if task not in refs:
        raise ValueError(f"{task!r} is not a suite task {tuple(refs)}")
    model, _ = load_model(task, **_overrides(refs[task]))
    core = BatchedCore(model, 1)
    return {"control": refs[task].control, "n_agents": int(core.N),
            "obs_dim": int(core.layout.size), "nvec": [int(v) for v in core.nvec]}


# ----------------------------------------------------------------------------- policies
def _file_task(path: Path) -> tuple[str, int | None, str]:
    """(task, training seed, control mode) a policy file names."""
    if path.suffix == ".npz":
        from netsense.benchmark.mlp_policy import read_mlp_policy

        pol = read_mlp_policy(path)
        return pol.task, pol.header.get("seed"), pol.control
    if path.suffix == ".pt":
        from netsense.rl.checkpoint import policy_config, policy_control, read_policy

        state = read_policy(path)
        cfg = policy_config(state, path)
        ctl = policy_control(state)
        mode = ctl.get("mode") if isinstance(ctl, dict) else ctl
        return cfg.scenario, cfg.seed, mode
    raise ValueError(f"{path}: a policy file is an .npz (docs/suite.md) or a .pt of "
                     "`netsense train --backend torchrl`; a MaskablePPO .zip is read in a "
                     "runs folder, whose folder names its task")


def _file_run(path: Path, task: str | None, seed: int | None,
              refs: Mapping[str, TaskReferences]) -> _Run | None:
    """The run of a policy file; ``None`` for a suite task that is not scored now."""
    if path.suffix == ".zip":
        if task is None:
            raise ValueError(f"{path}: a .zip does not name its task: put it in a runs "
                             "folder (DIR/<task>/seed_<s>/policy.zip) or map a task to it")
        from netsense.rl.sb3_policy import read_sb3_policy

        read_sb3_policy(path)
        return _Run(task, 0 if seed is None else seed, "file", path, str(path))
    ftask, fseed, mode = _file_task(path)
    if task is not None and ftask != task:
        raise ValueError(f"{path}: a policy of {ftask}, given for {task}")
    if ftask not in refs:
        if ftask in KNOWN_TASKS:
            return None  # a task left out of this scoring (``tasks``)
        raise ValueError(f"{path}: a policy of {ftask}, which is not a suite task "
                         f"{KNOWN_TASKS}")
    if mode is not None and mode != refs[ftask].control:
        raise ValueError(f"{path}: acts in control mode {mode!r}; the suite scores "
                         f"{ftask} in {refs[ftask].control!r}")
    s = fseed if fseed is not None else (0 if seed is None else seed)
    return _Run(ftask, int(s), "npz" if path.suffix == ".npz" else "file", path, str(path))


def runs_folder(path: str | Path, tasks: Sequence[str] | None = None
                ) -> dict[str, dict[str, list[tuple[int, Path]]]]:
    """The finished runs of a runs folder: ``{learner: {task: [(seed, policy file)]}}``.

    Layout: ``DIR/<task>/[<learner>/...]/seed_<s>/`` (``netsense train --out
    DIR/<task>``; ``experiments/rl/learners.py`` adds the learner's folder); the learner is
    the path between the task's folder and the seed's ('' without one). The policy file is
    the first of :data:`POLICY_FILES` the run folder holds.

    Raises
    ------
    ValueError
        The folder holds no task folder; a run folder is unfinished (named) or holds no
        final policy.
    """
    from netsense.rl.run_folder import check_finished, is_run_folder

    root = Path(path)
    if not root.is_dir():
        raise ValueError(f"{root}: not a folder")
    wanted = SUITE_TASKS if tasks is None else tuple(tasks)
    out: dict[str, dict[str, list]] = {}
    found = [d for d in sorted(root.iterdir()) if d.is_dir() and d.name in KNOWN_TASKS]
    if not found:
        raise ValueError(f"{root}: no task folder; a runs folder holds DIR/<task>/[<learner>/]"
                         f"seed_<s>/ for tasks among {KNOWN_TASKS}")
    for tdir in found:
        if tdir.name not in wanted:
            continue
        for run in sorted(tdir.rglob("seed_*")):
            if not run.is_dir() or not (is_run_folder(run) or any(
                    (run / f).is_file() for f in POLICY_FILES)):
                continue
            check_finished(run)
            policy = next((run / f for f in POLICY_FILES if (run / f).is_file()), None)
            if policy is None:
                raise ValueError(f"{run}: an unfinished run (no final policy, one of "
                                 f"{POLICY_FILES})")
            try:
                seed = int(run.name.removeprefix("seed_"))
            except ValueError:
                raise ValueError(f"{run}: a run folder is named seed_<integer>") from None
            learner = "/".join(run.parent.relative_to(tdir).parts)
            out.setdefault(learner, {}).setdefault(tdir.name, []).append((seed, policy))
    if not out:
        raise ValueError(f"{root}: no finished run of the tasks {wanted} under it")
    return out


def _expand(name: str, spec, refs: Mapping[str, TaskReferences]
            ) -> dict[str, dict[str, list[_Run]]]:
    """``{learner: {task: [runs]}}`` of one entry of :func:`score`'s ``policies``."""
    tasks = list(refs)

    def per_task(spec, task, seed) -> list[_Run]:
        if isinstance(spec, Builder):
            return [_Run(task, seed, "builder", spec.fn, f"builder {name}")]
        if isinstance(spec, str) and spec.startswith("rule:"):
            return [_Run(task, seed, "rule", spec.removeprefix("rule:"), spec)]
        if isinstance(spec, (str, Path)):
            p = Path(spec)
            if p.is_dir():
                raise ValueError(f"{p}: a runs folder is given for all tasks, not per task")
            run = _file_run(p, task, seed, refs)
            return [] if run is None else [run]
        if callable(spec):
            return [_Run(task, seed, "act", spec, f"callable {name}")]
        raise ValueError(f"policy {name!r}: {type(spec).__name__} is no policy (a path, "
                         "'rule:SPEC', a callable, builder(fn), a list or a {task: ...} "
                         "mapping)")

    if isinstance(spec, Mapping):
        unknown = sorted(set(spec) - set(KNOWN_TASKS))
        if unknown:
            raise ValueError(f"policy {name!r}: {unknown} are not suite tasks")
        out: dict[str, list[_Run]] = {}
        for task, s in spec.items():
            if task not in refs:
                continue
            seeds = list(s) if isinstance(s, (list, tuple)) else [s]
            out[task] = [r for i, x in enumerate(seeds) for r in per_task(x, task, i)]
        return {name: out}
    if isinstance(spec, (str, Path)) and Path(spec).is_dir():
        found = runs_folder(spec, tasks)
        many = len(found) > 1
        res = {}
        for learner, by_task in found.items():
            label = (f"{name}/{learner}" if many and learner else name) if name else (
                learner or Path(spec).name)
            res[label] = {t: [_file_run(p, t, s, refs) for s, p in runs]
                          for t, runs in by_task.items() if t in refs}
        return res
    items = list(spec) if isinstance(spec, (list, tuple)) else [spec]
    out = {}
    for i, x in enumerate(items):
        if isinstance(x, (str, Path)) and not str(x).startswith("rule:"):
            r = _file_run(Path(x), None, i, refs)
            if r is not None:
                out.setdefault(r.task, []).append(r)
        else:
            for task in tasks:
                out.setdefault(task, []).extend(per_task(x, task, i))
    return {name: out}


def resolve(policies: Mapping[str, object], references: Mapping[str, TaskReferences]
            ) -> dict[str, dict[str, list[_Run]]]:
    """``{learner: {task: [runs]}}`` of :func:`score`'s ``policies``, every file read and
    checked first (before any evaluation)."""
    if not isinstance(policies, Mapping) or not policies:
        raise ValueError("policies must be a non-empty mapping of name -> policy")
    out: dict[str, dict[str, list]] = {}
    for name, spec in policies.items():
        for label, by_task in _expand(str(name), spec, references).items():
            if label in out:
                raise ValueError(f"two policies are named {label!r}")
            for task, runs in by_task.items():
                seeds = [r.seed for r in runs]
                if len(set(seeds)) != len(seeds):
                    raise ValueError(f"{label} on {task}: training seeds {seeds} repeat")
            out[label] = by_task
    if not any(out.values()):
        raise ValueError("no policy of the scored tasks was given")
    return out


# ----------------------------------------------------------------------------- scoring
def _overrides(ref: TaskReferences) -> dict:
    from netsense.benchmark.protocol import frontier_overrides
    from netsense.env.registry import control_overrides

    return control_overrides(ref.task, ref.control, frontier_overrides(ref.task))


def _returns(run: _Run, ref: TaskReferences, seeds: list[int]) -> np.ndarray:
    from netsense.benchmark.protocol import evaluate

    over = _overrides(ref)
    if run.kind == "file":
        spec = f"learned:{run.obj}"
        return evaluate(run.task, spec, seeds,
                        over if Path(str(run.obj)).suffix == ".zip" else None)["reward"]
    if run.kind == "rule":
        return evaluate(run.task, str(run.obj), seeds, over)["reward"]
    if run.kind == "npz":
        from netsense.benchmark.mlp_policy import read_mlp_policy

        pol = read_mlp_policy(run.obj)

        def make(core, _seeds):
            pol.check_core(core)
            return pol.act
        return evaluate(run.task, run.source, seeds, over, actor=make)["reward"]
    if run.kind == "act":
        return evaluate(run.task, run.source, seeds, over,
                        actor=lambda core, _s: run.obj)["reward"]
    return evaluate(run.task, run.source, seeds, over, actor=run.obj)["reward"]


def score(policies: Mapping[str, object], tasks: Sequence[str] | None = None,
          episodes: int = 100, *, references: str | Path | None = None,
          progress: bool = True) -> SuiteResult:
    """Score policies on the suite's tasks.

    Parameters
    ----------
    policies : mapping of str to policy
        Name -> policy (module docstring: a file, a runs folder, ``"rule:SPEC"``, a
        callable ``act(obs, mask)``, :func:`builder` ``(fn)``, a list of those (training
        seeds) or a ``{task: ...}`` mapping).
    tasks : sequence of str, optional
        Tasks to score (default: the nine communication tasks of
        :data:`~netsense.benchmark.references.SUITE_TASKS` the references hold; a task at
        scale, :data:`~netsense.benchmark.references.SCALE_TASKS`, only by name).
    episodes : int
        Evaluation episodes, the protocol's first ``episodes`` seeds (at most the
        references' 100).
    references : path, optional
        A references file (default: the package's,
        :func:`netsense.benchmark.references.load_references`).
    progress : bool
        A tqdm bar over the evaluations.

    Returns
    -------
    SuiteResult

    Raises
    ------
    ValueError
        An unknown task, too many episodes, a policy that is refused (the message names
        it), references that no longer match the simulation (the best decentralised rule
        returns other values now: rebuild them with ``experiments/rl/suite_references.py``).
    """
    from tqdm.auto import tqdm

    from netsense.benchmark.protocol import eval_seeds

    refs = load_references(references)
    if tasks is not None:
        tasks = list(dict.fromkeys(tasks))
        unknown = [t for t in tasks if t not in refs]
        if unknown:
            raise ValueError(f"tasks {unknown} are not in the suite's references "
                             f"{tuple(refs)}")
        refs = {t: refs[t] for t in tasks}
    else:
        refs = {t: r for t, r in refs.items() if t in SUITE_TASKS}
        if not refs:
            raise ValueError("the references hold none of the suite's nine tasks; name the "
                             "tasks to score (tasks=)")
    n_ref = min(len(r.never.seeds) for r in refs.values())
    if isinstance(episodes, bool) or int(episodes) != episodes or not 1 <= episodes <= n_ref:
        raise ValueError(f"episodes must be an integer in 1..{n_ref} (the references' "
                         f"episodes), got {episodes!r}")
    seeds = eval_seeds(int(episodes))
    learners = resolve(policies, refs)
    jobs = [("reference", t, None) for t in refs]
    jobs += [(ln, t, r) for ln, by_task in learners.items() for t in refs
             for r in by_task.get(t, [])]
    rows = []
    for who, task, run in tqdm(jobs, desc="suite", disable=not progress):
        ref = refs[task]
        if run is None:
            dec = _returns(_Run(task, 0, "rule", ref.best_decentralised, ""), ref, seeds)
            stored = ref.best_decentralised_returns.on(seeds)
            if not np.allclose(dec, stored, rtol=1e-6, atol=1e-9):
                raise ValueError(f"{task}: {ref.best_decentralised} returns other values "
                                 "than the suite's references hold (largest difference "
                                 f"{np.abs(dec - stored).max():.3g}): the simulation changed "
                                 "since they were built; rebuild them with "
                                 "experiments/rl/suite_references.py")
            rows += _rows(task, "best decentralised", "best_decentralised", "", seeds, dec)
            rows += _rows(task, "never", "never", "", seeds, ref.never.on(seeds))
            if ref.best_reference_returns is not None:
                rs = [s for s in seeds if s in set(ref.best_reference_returns.seeds)]
                if rs:
                    rows += _rows(task, "best reference", "best_reference", "", rs,
                                  ref.best_reference_returns.on(rs))
            continue
        rows += _rows(task, who, "policy", run.seed, seeds, _returns(run, ref, seeds))
    return summarise(rows, refs)


def _rows(task, learner, kind, seed, seeds, values) -> list[dict]:
    return [{"task": task, "learner": learner, "kind": kind, "seed": seed,
             "episode_seed": int(s), "return": float(v)}
            for s, v in zip(seeds, values, strict=True)]


# ----------------------------------------------------------------------------- summary


@dataclass
class SuiteResult:
    """What :func:`score` returns.

    Attributes
    ----------
    table : list of dict
        One row per task and policy, then one ``task = "aggregate"`` row per policy
        (:data:`TABLE_COLUMNS`).
    episodes : list of dict
        Every return: ``task, learner, kind, seed, episode_seed, return`` (``kind``:
        ``policy``, or the references ``never``, ``best_decentralised``,
        ``best_reference``).
    scores : dict
        ``{learner: (runs, tasks) array}`` of normalised scores on the episodes the
        aggregate uses (for performance profiles).
    tasks : list of str
    learners : list of str
    """

    table: list[dict]
    episodes: list[dict]
    scores: dict = field(default_factory=dict)
    tasks: list = field(default_factory=list)
    learners: list = field(default_factory=list)

    def write(self, out: str | Path, figure: Sequence[str] | None = None
              ) -> dict[str, Path]:
        """``table.csv``, ``table.md``, ``episodes.csv`` and ``figure.png`` into ``out``
        (:mod:`netsense.benchmark.suite_output`); ``figure``: the policies the figure
        shows (default: all)."""
        from netsense.benchmark.suite_output import write_result

        return write_result(self, out, figure)

    def markdown(self) -> str:
        """The table as Markdown."""
        from netsense.benchmark.suite_output import markdown_table

        return markdown_table(self.table)


def _score_on(values_by_seed: np.ndarray, seeds: list[int], ref: TaskReferences
              ) -> tuple[np.ndarray, list[int]]:
    """Normalised scores ``(S, E')`` on the evaluated seeds with a bound (a bound equal to
    never's return dropped) and those seeds."""
    from netsense.benchmark.scores import normalise

    if ref.upper_bound is None:
        return np.empty((values_by_seed.shape[0], 0)), []
    bset = set(ref.upper_bound.seeds)
    keep = [i for i, s in enumerate(seeds) if s in bset]
    es = [seeds[i] for i in keep]
    if not es:
        return np.empty((values_by_seed.shape[0], 0)), []
    s = normalise(values_by_seed[:, keep], ref.never.on(es), ref.upper_bound.on(es))
    ok = np.isfinite(s).all(0)
    return s[:, ok], [e for e, k in zip(es, ok, strict=True) if k]


def summarise(rows: Sequence[dict], references: Mapping[str, TaskReferences]) -> SuiteResult:
    """The :class:`SuiteResult` of per-episode returns (:attr:`SuiteResult.episodes`'s
    rows, e.g. read back from ``episodes.csv``): the statistics without evaluating again.

    Per task and learner: IQM [95 % CI] of the returns over seeds x episodes, probability
    of improvement over the best decentralised rule on the same episodes, normalised
    score (IQM [CI] over seeds x the episodes with a bound) with the best decentralised
    rule's and the best reference's on the same scale. Aggregate: the IQM [CI] of the
    normalised scores over tasks x seeds x episodes, on the episodes every task has a
    bound on and the training seeds every task has (the first ones in order); only for a
    learner scored on every task with a bound.
    """
    from netsense.benchmark.scores import iqm, iqm_interval, probability_of_improvement

    tasks = [t for t in references if any(r["task"] == t for r in rows)]
    learners = list(dict.fromkeys(r["learner"] for r in rows if r["kind"] == "policy"))
    by: dict = {}  # (task, learner) of the policies, (task, kind) of the references
    for r in rows:
        key = r["learner"] if r["kind"] == "policy" else ("reference", r["kind"])
        by.setdefault((r["task"], key), []).append(r)
    table, per_task_scores = [], {}
    for task in tasks:
        ref = references[task]
        dec_rows = by.get((task, ("reference", "best_decentralised")), [])
        if not dec_rows:
            raise ValueError(f"{task}: the rows hold no best decentralised returns")
        dec = np.array([r["return"] for r in dec_rows])
        dec_seeds = [int(r["episode_seed"]) for r in dec_rows]
        dec_score, _ = _score_on(dec[None], dec_seeds, ref)
        ref_rows = by.get((task, ("reference", "best_reference")), [])
        ref_score = np.empty((1, 0))
        if ref_rows:
            ref_score, _ = _score_on(np.array([[r["return"] for r in ref_rows]]),
                                     [int(r["episode_seed"]) for r in ref_rows], ref)
        for learner in learners:
            rs = by.get((task, learner), [])
            if not rs:
                continue
            run_seeds = list(dict.fromkeys(r["seed"] for r in rs))
            ep = [int(r["episode_seed"]) for r in rs if r["seed"] == run_seeds[0]]
            for s in run_seeds:
                if [int(r["episode_seed"]) for r in rs if r["seed"] == s] != dec_seeds:
                    raise ValueError(f"{task}, {learner}, seed {s}: evaluated on other "
                                     "episodes than the best decentralised rule")
            mat = np.array([[r["return"] for r in rs if r["seed"] == s] for s in run_seeds])
            point, lo, hi = iqm_interval(mat.ravel())
            s_mat, s_seeds = _score_on(mat, ep, ref)
            above, bound = 0, (math.nan, math.nan, math.nan)
            if ref.upper_bound is not None:
                common = [i for i, e in enumerate(ep) if e in set(ref.upper_bound.seeds)]
                if common:
                    ub = ref.upper_bound.on([ep[i] for i in common])
                    above = int((mat[:, common] > ub + 1e-9 * np.abs(ub)).sum())
                    bound = bootstrap_ci(ub)
            if above:
                warnings.warn(f"{learner} on {task}: {above} returns above the certified "
                              "upper bound: the bound or the evaluation is wrong",
                              stacklevel=2)
            row = {"task": task, "learner": learner, "seeds": len(run_seeds),
                   "episodes": len(ep), "iqm": point, "iqm_ci_low": lo, "iqm_ci_high": hi,
                   "best_decentralised": ref.best_decentralised,
                   "best_decentralised_iqm": iqm(dec),
                   "p_improvement": probability_of_improvement(mat.ravel(), dec),
                   "score_episodes": len(s_seeds), "score": math.nan,
                   "score_ci_low": math.nan, "score_ci_high": math.nan,
                   "best_decentralised_score": iqm(dec_score) if dec_score.size else math.nan,
                   "best_reference": ref.best_reference or "",
                   "best_reference_score": iqm(ref_score) if ref_score.size else math.nan,
                   "upper_bound_mean": bound[0], "upper_bound_ci_low": bound[1],
                   "upper_bound_ci_high": bound[2], "above_bound": above}
            if s_seeds:
                row["score"], row["score_ci_low"], row["score_ci_high"] = iqm_interval(
                    s_mat.ravel())
                per_task_scores[(task, learner)] = (s_mat, s_seeds)
            table.append(row)
    agg_scores = {}
    for learner in learners:
        have = [t for t in tasks if (t, learner) in per_task_scores]
        row = {c: math.nan for c in TABLE_COLUMNS}
        row.update({"task": AGGREGATE, "learner": learner, "best_decentralised": "",
                    "best_reference": "", "above_bound": sum(
                        r["above_bound"] for r in table if r["learner"] == learner)})
        if tasks and len(have) == len(tasks):
            common = set.intersection(*(set(per_task_scores[(t, learner)][1]) for t in tasks))
            eps = sorted(common)
            n_seeds = min(per_task_scores[(t, learner)][0].shape[0] for t in tasks)
            if eps:
                cols = []
                for t in tasks:
                    m, es = per_task_scores[(t, learner)]
                    idx = [es.index(e) for e in eps]
                    cols.append(m[:n_seeds][:, idx].ravel())
                M = np.stack(cols, 1)  # (seeds x episodes, tasks)
                agg_scores[learner] = M
                row["score"], row["score_ci_low"], row["score_ci_high"] = iqm_interval(M)
                row.update({"seeds": n_seeds, "episodes": len(eps),
                            "score_episodes": len(eps)})
                row["best_decentralised_score"] = _reference_aggregate(
                    rows, references, tasks, "best_decentralised", eps)
                row["best_reference_score"] = _reference_aggregate(
                    rows, references, tasks, "best_reference", eps)
        table.append(row)
    return SuiteResult(table, list(rows), agg_scores, tasks, learners)


def _reference_aggregate(rows, references, tasks, kind: str, eps: list[int]) -> float:
    """IQM over tasks x episodes of a reference's normalised scores, on the episodes of
    ``eps`` every task has it on (NaN where there are none)."""
    from netsense.benchmark.scores import iqm, normalise

    got_by = {t: {int(r["episode_seed"]): r["return"] for r in rows
                  if r["task"] == t and r["kind"] == kind} for t in tasks}
    # a reference run on fewer episodes (the lookahead's first ones): those of them
    eps = sorted(set(eps).intersection(*(set(g) for g in got_by.values())))
    if not eps:
        return math.nan
    vals = []
    for t in tasks:
        got = got_by[t]
        ref = references[t]
        vals.append(normalise(np.array([got[e] for e in eps]), ref.never.on(eps),
                              ref.upper_bound.on(eps)))
    return iqm(np.concatenate(vals))


def reference_rows(references: Mapping[str, TaskReferences], seeds: Sequence[int]
                   ) -> list[dict]:
    """The references' per-episode returns on ``seeds`` as :attr:`SuiteResult.episodes`
    rows (the stored values; :func:`score` runs the best decentralised rule again)."""
    rows = []
    for task, ref in references.items():
        rows += _rows(task, "best decentralised", "best_decentralised", "", seeds,
                      ref.best_decentralised_returns.on(seeds))
        rows += _rows(task, "never", "never", "", seeds, ref.never.on(seeds))
        if ref.best_reference_returns is not None:
            rs = [s for s in seeds if s in set(ref.best_reference_returns.seeds)]
            if rs:
                rows += _rows(task, "best reference", "best_reference", "", rs,
                              ref.best_reference_returns.on(rs))
    return rows


def read_episodes(path: str | Path) -> list[dict]:
    """``episodes.csv`` of :meth:`SuiteResult.write` back as rows."""
    import csv

    with Path(path).open() as fh:
        rows = list(csv.DictReader(fh))
    missing = {"task", "learner", "kind", "seed", "episode_seed", "return"} - set(
        rows[0] if rows else {})
    if not rows or missing:
        raise ValueError(f"{path}: not a suite episodes file (columns {sorted(missing)} "
                         "missing, or no rows)")
    return [{"task": r["task"], "learner": r["learner"], "kind": r["kind"],
             "seed": int(r["seed"]) if r["seed"] != "" else "",
             "episode_seed": int(r["episode_seed"]), "return": float(r["return"])}
            for r in rows]


def rescore(path: str | Path, references: str | Path | None = None,
            order: Sequence[str] = ()) -> SuiteResult:
    """The :class:`SuiteResult` of a written ``episodes.csv`` under the current references,
    without evaluating a policy again: the policies' returns from the file, the
    references' from the references file (rebuilt references, a new upper bound, change
    the scores, not the returns). ``order``: policies to list first, in that order (the
    others follow in the file's order)."""
    refs = load_references(references)
    rows = [r for r in read_episodes(path) if r["kind"] == "policy"]
    rank = {name: i for i, name in enumerate(order)}
    rows.sort(key=lambda r: rank.get(r["learner"], len(rank)))  # stable: file order else
    unknown = sorted({r["task"] for r in rows} - set(refs))
    if unknown:
        raise ValueError(f"{path}: tasks {unknown} are not in the references")
    refs = {t: refs[t] for t in refs if any(r["task"] == t for r in rows)}
    seeds = sorted({r["episode_seed"] for r in rows})
    return summarise(reference_rows(refs, seeds) + rows, refs)
