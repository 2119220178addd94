"""Training pipeline, stage *logging*: the run's log.

:class:`RunLog` writes ``log.csv`` (one row per iteration; the header is the union of the
rows' columns) and, when ``tensorboard`` or ``tensorboardX`` is installed, TensorBoard
events under ``tb/``.

Imports: numpy, matplotlib (on demand) and the standard library (torch only to find
TensorBoard).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from netsense.rl.atomic import save_figure, write_atomic

__all__ = ["RunLog", "plot_curve", "read_log"]


class RunLog:
    """``log.csv`` (rows of varying columns, header = union) + optional TensorBoard.

    Rows are appended and flushed one at a time; a row that brings new columns rewrites
    the file once with the wider header (atomically, :mod:`netsense.rl.atomic`). The
    rows themselves are not kept: memory stays flat however long the run.

    Parameters
    ----------
    out : path
        The run's folder.
    resume_at : int, optional
        Continue a run's log: keep the rows of iterations ``< resume_at`` (the rows a
        killed run wrote after its last checkpoint, a half-written last row among them,
        are dropped) and the TensorBoard events up to the agent-steps of those rows.
        ``None``: a new log.
    """

    def __init__(self, out: Path, resume_at: int | None = None) -> None:
        self.path = out / "log.csv"
        self.cols: list[str] = []
        #: the rows kept when resuming (values parsed), in order
        self.kept: list[dict] = []
        purge = None
        if resume_at is not None:
            self.kept, self.cols = read_log(self.path, below=resume_at)
            purge = (int(self.kept[-1]["agent_steps"]) + 1) if self.kept else 0
            self._rewrite(self.kept)
        else:
            self.path.unlink(missing_ok=True)  # an older run's rows are not this run's
        self.tb = None
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:
            try:
                from tensorboardX import SummaryWriter
            except ImportError:
                SummaryWriter = None  # noqa: N806
        if SummaryWriter is not None:
            self.tb = (SummaryWriter(str(out / "tb")) if purge is None else
                       SummaryWriter(str(out / "tb"), purge_step=purge))

    def _rewrite(self, rows: list[dict]) -> None:
        text = io.StringIO()
        w = csv.DictWriter(text, fieldnames=self.cols)
        w.writeheader()
        w.writerows(rows)
        write_atomic(self.path, text.getvalue())

    def add(self, row: dict) -> None:
        if self.tb is not None:
            for k, v in row.items():
                if k != "agent_steps" and isinstance(v, (int, float)) and np.isfinite(v):
                    self.tb.add_scalar(k, v, row["agent_steps"])
        new = [c for c in row if c not in self.cols]
        if new:  # a wider header: the file again, whole
            old, _ = read_log(self.path)
            self.cols += new
            self._rewrite([*old, row])
            return
        with self.path.open("a", newline="") as fh:
            csv.DictWriter(fh, fieldnames=self.cols).writerow(row)

    def close(self) -> None:
        if self.tb is not None:
            self.tb.close()


def _value(text: str):
    if text == "":
        return None
    try:
        return int(text)
    except ValueError:
        try:
            return float(text)
        except ValueError:
            return text


def read_log(path: Path, below: int | None = None) -> tuple[list[dict], list[str]]:
    """The complete rows of a ``log.csv`` (values as numbers; empty cells left out) and
    its header; ``below``: only the rows of iterations ``< below``. A last line without
    its newline, or with too few cells (a run killed while writing it), is dropped; a
    missing file has no rows."""
    if not path.is_file():
        return [], []
    text = path.read_text()
    if not text.endswith("\n"):
        text = text[:text.rfind("\n") + 1]  # the half-written last line
    reader = csv.reader(io.StringIO(text))
    header = next(reader, [])
    rows = []
    for cells in reader:
        if len(cells) != len(header):
            continue
        row = {k: _value(v) for k, v in zip(header, cells, strict=True) if v != ""}
        if below is not None and not (isinstance(row.get("iteration"), int)
                                      and row["iteration"] < below):
            continue
        rows.append(row)
    return rows, header


def plot_curve(rows: list[dict], path: Path, title: str,
               references: dict[str, float] | None = None) -> Path:
    """``training_curve.png``: the returns of the episodes that ended in each iteration
    (training, sampled actions, the run's reward option) and the periodic evaluations
    (most likely and sampled actions, the scenario's reward) against agent-steps;
    ``references`` draws scripted returns on the same evaluation as dashed lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 3.8))
    for key, label, style in (("train_return", "training episodes (sampled)", "-"),
                              ("eval_return", "evaluation (most likely action)", "o-"),
                              ("eval_sampled_return", "evaluation (sampled)", "s--")):
        pts = [(r["agent_steps"], r[key]) for r in rows if key in r]
        if pts:
            x, y = zip(*pts, strict=True)
            ax.plot(x, y, style, ms=3, lw=1.2, label=label)
    for i, (name, value) in enumerate((references or {}).items()):
        ax.axhline(value, ls=":", color=f"C{i + 3}", label=f"{name} (scripted)")
    ax.set_xlabel("agent-steps")
    ax.set_ylabel("episode return per agent")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    if ax.lines:
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path
