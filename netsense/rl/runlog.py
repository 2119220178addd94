"""Training pipeline, stage *logging*: the run's log.

:class:`RunLog` writes ``log.csv`` (one row per iteration; the header is the union of the
rows' columns) and, when ``tensorboard`` or ``tensorboardX`` is installed, TensorBoard
events under ``tb/``.

Imports: numpy and the standard library (torch only to find TensorBoard).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

__all__ = ["RunLog"]


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
