"""Training pipeline, stage *logging*: the run's log.

:class:`RunLog` writes ``log.csv`` (one row per iteration; the header is the union of the
rows' columns) and, when ``tensorboard`` or ``tensorboardX`` is installed, TensorBoard
events under ``tb/``.

Imports: numpy, matplotlib (on demand) and the standard library (torch only to find
TensorBoard).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

__all__ = ["RunLog", "plot_curve"]


class RunLog:
    """``log.csv`` (rows of varying columns, header = union) + optional TensorBoard."""

    def __init__(self, out: Path) -> None:
        self.path = out / "log.csv"
        self.rows: list[dict] = []
        self.tb = None
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:
            try:
                from tensorboardX import SummaryWriter
            except ImportError:
                SummaryWriter = None  # noqa: N806
        if SummaryWriter is not None:
            self.tb = SummaryWriter(str(out / "tb"))

    def add(self, row: dict) -> None:
        self.rows.append(row)
        if self.tb is not None:
            for k, v in row.items():
                if k != "agent_steps" and isinstance(v, (int, float)) and np.isfinite(v):
                    self.tb.add_scalar(k, v, row["agent_steps"])
        cols: list[str] = []
        for r in self.rows:
            cols += [c for c in r if c not in cols]
        with self.path.open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=cols)
            w.writeheader()
            w.writerows(self.rows)

    def close(self) -> None:
        if self.tb is not None:
            self.tb.close()


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
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
