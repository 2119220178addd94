"""Run folders: is a training run's folder finished, and may a new run write into it?

A run (``netsense train``, :func:`netsense.rl.ppo.train_ppo`, the SB3 ``train``, and
the launcher's folder of many runs, :func:`netsense.rl.launch.launch`) writes
``run.json`` (:data:`RUN_FILE`) into its folder first, with ``"status": "running"``, and
rewrites it with ``"status": "finished"`` as its very last write, after the final policy
(both atomically, :mod:`netsense.rl.atomic`). A folder whose run was killed therefore
says ``running`` for good; every reader of learned policies asks :func:`check_finished`
first (:func:`netsense.rl.checkpoint.read_policy` and
:func:`netsense.rl.sb3_policy.read_sb3_policy` do, so ``netsense benchmark --policies
learned:...`` and ``netsense policy check`` refuse such a folder by name).

A folder without ``run.json`` was written by a netsense before the marker existed: it is
finished when it holds a final policy (``policy.pt`` or ``policy.zip``, written last by
those versions too), unfinished when it holds other run files only (a killed run's
``config.json``, checkpoints or ``log.csv``), and not a run folder otherwise.

:func:`claim` is the check before a run writes into a folder: a folder holding another
run is refused, with the flags that resume (``--resume``) or overwrite (``--overwrite``)
it named.

Imports: the standard library and :mod:`netsense.rl.atomic`.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from netsense.rl.atomic import write_json

__all__ = ["FINISHED", "RUN_FILE", "RUNNING", "check_finished", "claim", "is_finished",
           "is_run_folder", "mark", "run_status"]

#: The marker file of a run folder.
RUN_FILE = "run.json"
#: ``status`` values of :data:`RUN_FILE`.
RUNNING, FINISHED = "running", "finished"
#: Final policies, written last by runs of any netsense version.
FINAL_POLICIES = ("policy.pt", "policy.zip")
#: Files and folders runs write (besides :data:`RUN_FILE`): their presence makes a folder
#: a run folder; :func:`claim` with ``overwrite`` removes them and nothing else.
RUN_FILES = ("config.json", "log.csv", "summary.json", "training_curve.png",
             "training_curve.csv", "train_config.json", *FINAL_POLICIES)
RUN_PATTERNS = ("checkpoint_*.pt", "seed_*", "tb", ".*.part")


def _items(folder: Path) -> list[Path]:
    found = [folder / RUN_FILE] + [folder / n for n in RUN_FILES]
    found = [p for p in found if p.exists()]
    for pattern in RUN_PATTERNS:
        found += sorted(folder.glob(pattern))
    return found


def _read(folder: Path) -> dict | None:
    path = folder / RUN_FILE
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable run marker ({exc}); the folder {folder} "
                         "holds a damaged run: resume it with --resume or replace it with "
                         "--overwrite") from None
    if not isinstance(data, dict) or not isinstance(data.get("status"), str):
        raise ValueError(f"{path}: a run marker must be a JSON object with a 'status' "
                         f"string, got {data!r}")
    return data


def run_status(folder: str | Path) -> str | None:
    """``"finished"``, ``"running"`` (a run is writing it, or was killed: unfinished), or
    another status a launcher recorded (``"failed"``); ``None`` for a folder that holds no
    run. Folders without ``run.json`` are judged by their files (module docstring).

    Raises
    ------
    ValueError
        ``run.json`` exists but is not a JSON object with a ``status`` string.
    """
    folder = Path(folder)
    data = _read(folder)
    if data is not None:
        return data["status"]
    if any((folder / n).is_file() for n in FINAL_POLICIES):
        return FINISHED
    return RUNNING if folder.is_dir() and _items(folder) else None


def is_run_folder(folder: str | Path) -> bool:
    """Whether ``folder`` holds a run's files (finished or not)."""
    folder = Path(folder)
    return folder.is_dir() and bool(_items(folder))


def is_finished(folder: str | Path) -> bool:
    """Whether ``folder`` holds a finished run (:func:`run_status` is ``"finished"``)."""
    return run_status(folder) == FINISHED


def check_finished(folder: str | Path) -> None:
    """Return quietly when ``folder`` holds a finished run, or holds no run at all (a
    plain folder of policy files); raise otherwise.

    Raises
    ------
    ValueError
        Naming the folder: it holds an unfinished run (killed or still training; resume
        it with ``netsense train ... --resume``), or one that failed.
    """
    status = run_status(folder)
    if status is None or status == FINISHED:
        return
    if status == RUNNING:
        raise ValueError(f"{folder} is an unfinished training run (killed, or still "
                         "training): its files are not final; resume it with the same "
                         "`netsense train ... --out` command and --resume")
    raise ValueError(f"{folder} holds a training run with status {status!r}, not a "
                     "finished one; resume it with the same `netsense train ... --out` "
                     "command and --resume")


def mark(folder: str | Path, status: str, **info) -> Path:
    """Write ``folder/run.json`` atomically: ``{"status": status, **info}``."""
    if not isinstance(status, str) or not status:
        raise ValueError(f"mark: status must be a non-empty string, got {status!r}")
    return write_json(Path(folder) / RUN_FILE, {"status": status, **info}, default=list)


def claim(folder: str | Path, *, resume: bool = False, overwrite: bool = False) -> str:
    """Check that a run may write into ``folder``, before anything is written.

    Parameters
    ----------
    folder : path
        The run's output folder (``--out``).
    resume : bool
        Continue the run the folder holds (``--resume``); a folder without a run is
        started afresh.
    overwrite : bool
        Remove the run files the folder holds (:data:`RUN_FILES`, checkpoints, run
        subfolders ``seed_*``, ``tb/``), then start afresh (``--overwrite``). Other files
        are kept.

    Returns
    -------
    str
        ``"new"`` (nothing to resume: start), ``"resume"`` (a run to continue) or
        ``"finished"`` (``resume`` of a finished run: nothing to do).

    Raises
    ------
    ValueError
        ``resume`` and ``overwrite`` both given; or the folder holds a run and neither is
        given (the message names the folder and both flags); or ``folder`` is a file.
    """
    folder = Path(folder)
    if resume and overwrite:
        raise ValueError("give --resume (continue the run in the folder) or --overwrite "
                         "(replace it), not both")
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"--out {folder} is a file, not a folder")
    if not is_run_folder(folder):
        return "new"
    if overwrite:
        for p in _items(folder):
            if p.is_dir():
                shutil.rmtree(p)
            else:
                p.unlink()
        return "new"
    if not resume:
        status = run_status(folder)
        raise ValueError(f"--out {folder} already holds a training run ({status}); "
                         "continue it with --resume, replace it with --overwrite, or "
                         "choose another --out")
    return "finished" if run_status(folder) == FINISHED else "resume"
