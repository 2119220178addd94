"""Headroom: how far the best scripted point of a task is from its lookahead bounds.

For a bound row of :func:`netsense.benchmark.protocol.frontier` (run on the first ``E``
evaluation seeds) and a reference row (the scripted point of highest mean return of a
kind, chosen on all of its episodes), the headroom is the mean per-seed difference of the
episode returns on the ``E`` common seeds,

.. math::

    \\Delta = \\frac{1}{E} \\sum_{e=1}^{E} \\big(R^{\\text{bound}}_e - R^{\\text{ref}}_e\\big),
    \\qquad \\Delta_{\\%} = 100\\, \\frac{\\Delta}{|\\bar R^{\\text{ref}}|},

with 95 % percentile bootstrap intervals that resample seeds, keeping each seed's pair
together (``scipy.stats.bootstrap`` with ``paired=True``, 9999 resamples, generator seeded
with 0, as every interval of the protocol). The reference kind is named in every row
(``decentralised``: what an agent could run; ``centralised``: a scheduler that reads every
agent's state), so "the bound beats the frontier by ..." always says which frontier.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense.benchmark.intervals import bootstrap_ci, paired_percent
from netsense.benchmark.kinds import RANDOM_FAMILIES

__all__ = ["HEADROOM_COLUMNS", "best_scripted", "headroom", "markdown_headroom",
           "write_headroom"]

HEADROOM_COLUMNS = ("scenario", "bound", "continuation", "reference_kind", "reference",
                    "episodes", "seed_first", "seed_last", "bound_reward",
                    "reference_reward", "headroom_mean", "headroom_ci_low",
                    "headroom_ci_high", "headroom_pct", "headroom_pct_ci_low",
                    "headroom_pct_ci_high", "bound_seconds_per_episode",
                    "lane_steps_per_decision")


def best_scripted(rows: Sequence[dict], kind: str | None = None,
                  deterministic: bool = False) -> dict:
    """The scripted row of highest mean reward (of ``kind``, one of
    :data:`~netsense.benchmark.kinds.KINDS`, if given; ``deterministic``: not a point of a
    family that draws random bits,
    :data:`~netsense.benchmark.kinds.RANDOM_FAMILIES`)."""
    pick = [r for r in rows if r["kind"] in ("decentralised", "centralised")
            and (kind is None or r["kind"] == kind)
            and not (deterministic and r["family"] in RANDOM_FAMILIES)]
    if not pick:
        raise ValueError(f"no scripted {kind or ''} point among the rows")
    return max(pick, key=lambda r: r["reward_mean"])


def headroom(rows: Sequence[dict], kinds: Sequence[str] = ("decentralised", "centralised")
             ) -> list[dict]:
    """One row per scenario, bound and reference kind (:data:`HEADROOM_COLUMNS`).

    ``rows``: frontier rows with their per-episode ``values`` (as
    :func:`~netsense.benchmark.protocol.frontier` returns them). A kind without a scripted
    point in a scenario is skipped.
    """
    out = []
    for scenario in dict.fromkeys(r["scenario"] for r in rows):
        mine = [r for r in rows if r["scenario"] == scenario]
        for b in (r for r in mine if r["kind"] == "bound"):
            E = int(b["episodes"])
            got = np.asarray(b["values"]["reward"], float)
            for kind in kinds:
                try:
                    ref = best_scripted(mine, kind)
                except ValueError:
                    continue
                if int(ref["seed_first"]) != int(b["seed_first"]) or ref["episodes"] < E:
                    raise ValueError(f"{scenario}: the bound's seeds {b['seed_first']}.. are "
                                     f"not the first seeds of {ref['policy']}")
                base = np.asarray(ref["values"]["reward"], float)[:E]
                d, lo, hi = bootstrap_ci(got - base)
                pct, plo, phi = paired_percent(got, base)
                cost = b.get("cost", {})
                out.append({
                    "scenario": scenario, "bound": b["policy"], "continuation": b["knob"],
                    "reference_kind": kind, "reference": ref["policy"], "episodes": E,
                    "seed_first": b["seed_first"], "seed_last": b["seed_last"],
                    "bound_reward": float(got.mean()), "reference_reward": float(base.mean()),
                    "headroom_mean": d, "headroom_ci_low": lo, "headroom_ci_high": hi,
                    "headroom_pct": pct, "headroom_pct_ci_low": plo,
                    "headroom_pct_ci_high": phi,
                    "bound_seconds_per_episode": float(b["seconds"]) / E,
                    "lane_steps_per_decision": float(cost.get("lane_steps_per_decision",
                                                              math.nan))})
    return out


def _fmt(v: float, digits: int = 3) -> str:
    return "nan" if not math.isfinite(v) else f"{v:.{digits}g}"


def markdown_headroom(rows: Sequence[dict]) -> str:
    """The headroom rows as a Markdown table (mean [95 % paired CI])."""
    lines = ["| scenario | bound | reference (kind) | episodes | bound return | "
             "reference return | headroom | headroom % of reference | s / episode |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['scenario']} | {r['bound']} | {r['reference']} ({r['reference_kind']}) | "
            f"{r['episodes']} | {_fmt(r['bound_reward'], 4)} | "
            f"{_fmt(r['reference_reward'], 4)} | {_fmt(r['headroom_mean'])} "
            f"[{_fmt(r['headroom_ci_low'])}, {_fmt(r['headroom_ci_high'])}] | "
            f"{_fmt(r['headroom_pct'])} % [{_fmt(r['headroom_pct_ci_low'])}, "
            f"{_fmt(r['headroom_pct_ci_high'])}] | {_fmt(r['bound_seconds_per_episode'])} |")
    return "\n".join(lines) + "\n"


def write_headroom(rows: Sequence[dict], out: str | Path) -> tuple[Path, Path]:
    """``headroom.csv`` and ``headroom.md`` into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path_csv, path_md = out / "headroom.csv", out / "headroom.md"
    with path_csv.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(HEADROOM_COLUMNS)
        for r in rows:
            w.writerow([f"{r[c]:.6g}" if isinstance(r[c], float) else r[c]
                        for c in HEADROOM_COLUMNS])
    path_md.write_text(markdown_headroom(rows))
    return path_csv, path_md
