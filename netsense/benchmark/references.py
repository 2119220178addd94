"""The reference points of the benchmark suite, defined once: a package data file.

``netsense/benchmark/data/suite_references.json`` (written by
``experiments/rl/suite_references.py`` from the committed results) lists, per
communication task of :data:`SUITE_TASKS`, on the protocol's evaluation episodes
(:func:`netsense.benchmark.protocol.eval_seeds`):

* ``control``: the communication-only control mode the task is scored in (the frontier's:
  :func:`netsense.benchmark.protocol.frontier_overrides`);
* ``never``: the per-episode returns of ``never`` (no agent ever sends): score 0;
* ``best_decentralised``: the spec of the best decentralised rule of the scripted frontier
  (mean return), and its per-episode returns; the suite runs it again on the same seeds
  (it is deterministic given the seeds) and refuses stale references;
* ``best_reference``: the best full-information reference scheduler (a lookahead search
  on a fork of the simulation, not deployable), its per-episode returns and their seeds,
  or ``null`` where none was evaluated;
* ``upper_bound``: the certified upper bound per episode (no policy's return can exceed
  it on that episode) and its seeds: score 1; ``null`` where no bound exists, and then
  the suite does not normalise that task.

The file may also hold the tasks at scale of :data:`SCALE_TASKS` (``N = 50``): the suite
scores them when asked by name (``tasks=``), never in its default nine-task aggregate.
The bound's linear program does not scale to them, so they have no ``upper_bound``; their
``best_reference`` is the best centralised scheduler of their frontier (``oldest:K``), a
rule that sees every agent's state, not a lookahead.

Every table and plot of :mod:`netsense.benchmark.suite` reads the references from
:func:`load_references`. The file is data: it is parsed as JSON and checked, never run.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

__all__ = ["FORMAT", "FORMAT_VERSION", "KNOWN_TASKS", "REFERENCES_FILE", "SCALE_TASKS",
           "SUITE_TASKS", "EpisodeValues", "TaskReferences", "load_references",
           "references_json"]

#: The communication tasks of the suite, in the order of its tables.
SUITE_TASKS = ("comm_process_noise-v0", "comm_substates-v0", "comm_channel_k2-v0",
               "message_cost-v0", "message_cost-v1", "comm_announced-v0", "comm_fading-v0",
               "comm_schedule-v0", "comm_schedule-v1")
#: Tasks at scale the suite scores on request (``tasks=``), outside its default nine; no
#: upper bound (module docstring).
SCALE_TASKS = ("comm_channel_kofn_n50-v0", "comm_spatial_n50-v0")
#: Every task a references file may hold, in table order.
KNOWN_TASKS = SUITE_TASKS + SCALE_TASKS
FORMAT = "netsense-suite-references"
FORMAT_VERSION = 1
#: The package data file (inside ``netsense/benchmark``).
REFERENCES_FILE = "data/suite_references.json"


@dataclass(frozen=True)
class EpisodeValues:
    """Per-episode values of one reference: ``values[e]`` on seed ``seeds[e]``.

    Attributes
    ----------
    seeds : tuple of int
        Evaluation seeds, increasing.
    values : numpy.ndarray
        One float per seed.
    """

    seeds: tuple[int, ...]
    values: np.ndarray

    def on(self, seeds: Sequence[int]) -> np.ndarray:
        """The values on ``seeds`` (each must be among :attr:`seeds`)."""
        index = {s: i for i, s in enumerate(self.seeds)}
        missing = [s for s in seeds if s not in index]
        if missing:
            raise ValueError(f"no value on seeds {missing[:5]} (it holds {len(self.seeds)} "
                             f"seeds from {self.seeds[0]})")
        return self.values[[index[int(s)] for s in seeds]]


@dataclass(frozen=True)
class TaskReferences:
    """The reference points of one task (module docstring).

    Attributes
    ----------
    task : str
    control : str
        The communication-only control mode the task is scored in.
    never : EpisodeValues
        ``never``'s returns (score 0).
    best_decentralised : str
        Spec of the best decentralised rule (``event:2``, ...).
    best_decentralised_returns : EpisodeValues
        Its returns when the references were built.
    best_reference : str or None
        Name of the best full-information reference (``None``: none evaluated).
    best_reference_returns : EpisodeValues or None
    upper_bound : EpisodeValues or None
        The certified upper bound per episode (score 1); ``None``: no bound.
    """

    task: str
    control: str
    never: EpisodeValues
    best_decentralised: str
    best_decentralised_returns: EpisodeValues
    best_reference: str | None
    best_reference_returns: EpisodeValues | None
    upper_bound: EpisodeValues | None


def _values(entry, where: str, key: str = "returns") -> EpisodeValues:
    if not isinstance(entry, Mapping):
        raise ValueError(f"{where}: must be an object with 'seeds' and '{key}', got "
                         f"{type(entry).__name__}")
    seeds, vals = entry.get("seeds"), entry.get(key)
    if not isinstance(seeds, list) or not all(
            isinstance(s, int) and not isinstance(s, bool) for s in seeds) or not seeds:
        raise ValueError(f"{where}.seeds: must be a non-empty list of integers")
    if any(b <= a for a, b in zip(seeds, seeds[1:], strict=False)):
        raise ValueError(f"{where}.seeds: must be increasing")
    if not isinstance(vals, list) or len(vals) != len(seeds) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            for v in vals):
        raise ValueError(f"{where}.{key}: must be a list of {len(seeds)} finite numbers, "
                         "one per seed")
    return EpisodeValues(tuple(seeds), np.asarray(vals, dtype=float))


def _task(task: str, d, where: str) -> TaskReferences:
    if not isinstance(d, Mapping):
        raise ValueError(f"{where}: must be an object, got {type(d).__name__}")
    known = {"control", "never", "best_decentralised", "best_reference", "upper_bound",
             "sources"}
    unknown = sorted(set(d) - known)
    if unknown:
        raise ValueError(f"{where}: unknown keys {unknown}")
    control = d.get("control")
    if not isinstance(control, str):
        raise ValueError(f"{where}.control: must be a control mode name")
    never = _values(d.get("never"), f"{where}.never")
    dec = d.get("best_decentralised")
    if not isinstance(dec, Mapping) or not isinstance(dec.get("spec"), str):
        raise ValueError(f"{where}.best_decentralised: must be an object with a 'spec' string")
    dec_returns = _values(dec, f"{where}.best_decentralised")
    ref = d.get("best_reference")
    ref_name, ref_returns = None, None
    if ref is not None:
        if not isinstance(ref, Mapping) or not isinstance(ref.get("name"), str):
            raise ValueError(f"{where}.best_reference: must be null or an object with a "
                             "'name' string")
        ref_name, ref_returns = ref["name"], _values(ref, f"{where}.best_reference")
    ub = d.get("upper_bound")
    bound = None if ub is None else _values(ub, f"{where}.upper_bound", "values")
    if bound is not None:
        common = [s for s in bound.seeds if s in set(never.seeds)]
        below = bound.on(common) < never.on(common) - 1e-9 * np.abs(never.on(common))
        if below.any():
            s = common[int(np.argmax(below))]
            raise ValueError(f"{where}.upper_bound: below never's return on seed {s}; a "
                             "bound no policy can exceed cannot be below one")
    return TaskReferences(task, control, never, dec["spec"], dec_returns, ref_name,
                          ref_returns, bound)


def references_json(data) -> dict[str, TaskReferences]:
    """Check the parsed JSON of a references file and return ``{task: TaskReferences}``.

    Raises
    ------
    ValueError
        Naming the entry that is wrong: format or version, a task that is no suite task,
        seeds and values of different lengths, non-finite values, an upper bound below
        ``never``'s return.
    """
    if not isinstance(data, Mapping):
        raise ValueError(f"a references file holds a JSON object, got {type(data).__name__}")
    fmt, version = data.get("format"), data.get("format_version")
    if fmt != FORMAT or version != FORMAT_VERSION:
        raise ValueError(f"format {fmt!r} version {version!r}; this netsense reads "
                         f"{FORMAT!r} version {FORMAT_VERSION}")
    tasks = data.get("tasks")
    if not isinstance(tasks, Mapping) or not tasks:
        raise ValueError("'tasks' must be a non-empty object of task -> references")
    out = {}
    for task, d in tasks.items():
        if task not in KNOWN_TASKS:
            raise ValueError(f"tasks: {task!r} is not a suite task {KNOWN_TASKS}")
        out[task] = _task(task, d, f"tasks.{task}")
    return {t: out[t] for t in KNOWN_TASKS if t in out}


def load_references(path: str | Path | None = None) -> dict[str, TaskReferences]:
    """The suite's references: the package data file (:data:`REFERENCES_FILE`), or
    ``path``; parsed as JSON and checked by :func:`references_json`.

    Raises
    ------
    ValueError
        The file is missing, not JSON, or fails a check (the message names the file).
    """
    if path is None:
        src = resources.files("netsense.benchmark").joinpath(REFERENCES_FILE)
        where = f"netsense/benchmark/{REFERENCES_FILE}"
    else:
        src, where = Path(path), str(path)
    try:
        text = src.read_text()
    except OSError as exc:
        raise ValueError(f"{where}: cannot read the suite's references ({exc}); build them "
                         "with experiments/rl/suite_references.py") from None
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise ValueError(f"{where}: not JSON ({exc})") from None
    try:
        return references_json(data)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
