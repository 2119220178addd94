"""Headroom: how far the best scripted point of a task is from its full-information
reference schedulers.

For a reference row of :func:`netsense.benchmark.protocol.frontier` (a lookahead of
:mod:`netsense.benchmark.lookahead`, run on the first ``E`` evaluation seeds) and the best
scripted row of a kind (the scripted point of highest mean return of that kind, chosen on
all of its episodes), the headroom is the mean per-seed difference of the episode returns
on the ``E`` common seeds,

.. math::

    \\Delta = \\frac{1}{E} \\sum_{e=1}^{E} \\big(R^{\\text{reference}}_e - R^{\\text{best}}_e\\big),
    \\qquad \\Delta_{\\%} = 100\\, \\frac{\\Delta}{|\\bar R^{\\text{best}}|},

with 95 % percentile bootstrap intervals that resample seeds, keeping each seed's pair
together (``scipy.stats.bootstrap`` with ``paired=True``, 9999 resamples, generator seeded
with 0, as every interval of the protocol). The kind is named in every row
(``decentralised``: what an agent could run, the best of *every* decentralised row on the
same episodes, informed rules included; ``centralised``: a scheduler that reads every
agent's state; privileged rules are never compared), so "the reference beats the frontier
by ..." always says which frontier. The references are achieved returns, not bounds: a
negative headroom means a rule beat the reference.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense.benchmark.intervals import bootstrap_ci, paired_percent
from netsense.benchmark.kinds import RANDOM_FAMILIES, reference_label, spec_family
from netsense.rl.atomic import atomic_path, write_atomic

__all__ = ["HEADROOM_COLUMNS", "best_scripted", "headroom", "markdown_headroom",
           "write_headroom"]

HEADROOM_COLUMNS = ("scenario", "reference", "reference_label", "continuation", "best_kind",
                    "best", "episodes", "seed_first", "seed_last", "reference_reward",
                    "best_reward", "headroom_mean", "headroom_ci_low", "headroom_ci_high",
                    "headroom_pct", "headroom_pct_ci_low", "headroom_pct_ci_high",
                    "reference_seconds_per_episode", "lane_steps_per_decision")


def _random(row: dict) -> bool:
    """Whether a scripted row draws random bits (its family, or a wrapped rule's base)."""
    return (row["family"] in RANDOM_FAMILIES
            or ("(" in str(row["policy"]) and spec_family(str(row["knob"])) in RANDOM_FAMILIES))


def best_scripted(rows: Sequence[dict], kind: str | None = None,
                  deterministic: bool = False) -> dict:
    """The scripted row of highest mean reward among the decentralised and centralised
    rows (of ``kind``, one of them, if given; ``deterministic``: not a rule that draws
    random bits, :data:`~netsense.benchmark.kinds.RANDOM_FAMILIES`). Every decentralised
    row competes (informed rules included); privileged rows never do."""
    pick = [r for r in rows if r["kind"] in ("decentralised", "centralised")
            and (kind is None or r["kind"] == kind)
            and not (deterministic and _random(r))]
    if not pick:
        raise ValueError(f"no scripted {kind or ''} point among the rows")
    return max(pick, key=lambda r: r["reward_mean"])


def headroom(rows: Sequence[dict], kinds: Sequence[str] = ("decentralised", "centralised")
             ) -> list[dict]:
    """One row per scenario, reference and kind of the best point (:data:`HEADROOM_COLUMNS`).

    ``rows``: frontier rows with their per-episode ``values`` (as
    :func:`~netsense.benchmark.protocol.frontier` returns them). A kind without a scripted
    point in a scenario is skipped.
    """
    out = []
    for scenario in dict.fromkeys(r["scenario"] for r in rows):
        mine = [r for r in rows if r["scenario"] == scenario]
        for b in (r for r in mine if r["kind"] == "reference"):
            E = int(b["episodes"])
            got = np.asarray(b["values"]["reward"], float)
            for kind in kinds:
                try:
                    best = best_scripted(mine, kind)
                except ValueError:
                    continue
                if int(best["seed_first"]) != int(b["seed_first"]) or best["episodes"] < E:
                    raise ValueError(f"{scenario}: the reference's seeds {b['seed_first']}.. "
                                     f"are not the first seeds of {best['policy']}")
                base = np.asarray(best["values"]["reward"], float)[:E]
                d, lo, hi = bootstrap_ci(got - base)
                pct, plo, phi = paired_percent(got, base)
                cost = b.get("cost", {})
                out.append({
                    "scenario": scenario, "reference": b["policy"],
                    "reference_label": reference_label(b["policy"]),
                    "continuation": b["knob"], "best_kind": kind, "best": best["policy"],
                    "episodes": E, "seed_first": b["seed_first"], "seed_last": b["seed_last"],
                    "reference_reward": float(got.mean()), "best_reward": float(base.mean()),
                    "headroom_mean": d, "headroom_ci_low": lo, "headroom_ci_high": hi,
                    "headroom_pct": pct, "headroom_pct_ci_low": plo,
                    "headroom_pct_ci_high": phi,
                    "reference_seconds_per_episode": float(b["seconds"]) / E,
                    "lane_steps_per_decision": float(cost.get("lane_steps_per_decision",
                                                              math.nan))})
    return out


def _fmt(v: float, digits: int = 3) -> str:
    return "nan" if not math.isfinite(v) else f"{v:.{digits}g}"


def markdown_headroom(rows: Sequence[dict]) -> str:
    """The headroom rows as a Markdown table (mean [95 % paired CI])."""
    lines = ["| scenario | full-information reference | best scripted (kind) | episodes | "
             "reference return | best return | headroom | headroom % of best | "
             "s / episode |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['scenario']} | {r['reference_label']} | {r['best']} ({r['best_kind']}) | "
            f"{r['episodes']} | {_fmt(r['reference_reward'], 4)} | "
            f"{_fmt(r['best_reward'], 4)} | {_fmt(r['headroom_mean'])} "
            f"[{_fmt(r['headroom_ci_low'])}, {_fmt(r['headroom_ci_high'])}] | "
            f"{_fmt(r['headroom_pct'])} % [{_fmt(r['headroom_pct_ci_low'])}, "
            f"{_fmt(r['headroom_pct_ci_high'])}] | {_fmt(r['reference_seconds_per_episode'])} |")
    return "\n".join(lines) + "\n"


def write_headroom(rows: Sequence[dict], out: str | Path) -> tuple[Path, Path]:
    """``headroom.csv`` and ``headroom.md`` into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path_csv, path_md = out / "headroom.csv", out / "headroom.md"
    with atomic_path(path_csv) as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(HEADROOM_COLUMNS)
        for r in rows:
            w.writerow([f"{r[c]:.6g}" if isinstance(r[c], float) else r[c]
                        for c in HEADROOM_COLUMNS])
    write_atomic(path_md, markdown_headroom(rows))
    return path_csv, path_md
