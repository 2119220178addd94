"""The benchmark suite's outputs: one table (CSV + Markdown), the per-episode returns, one
figure, and the leaderboard's tables (:mod:`netsense.benchmark.suite`).

``write_result(result, out)`` writes

* ``table.csv`` / ``table.md``: :data:`~netsense.benchmark.suite.TABLE_COLUMNS`, one row
  per task and policy and one aggregate row per policy;
* ``episodes.csv``: every return (``task, learner, kind, seed, episode_seed, return``);
* ``figure.png``: per task, each policy's normalised IQM with its 95 % interval, the best
  decentralised rule (black diamond), the best full-information reference (red triangle)
  and the bound (1, dotted) on the same scale; the aggregate over tasks; the performance
  profiles (rliable).

:func:`leaderboard_markdown` turns ``table.csv``'s rows into the leaderboard's tables
(``docs/leaderboard.md``): policies by task, normalised scores and IQM returns.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense.rl.atomic import atomic_path, save_figure, write_atomic

__all__ = ["AGGREGATE", "TABLE_COLUMNS", "leaderboard_markdown", "markdown_table",
           "plot_result", "read_table", "write_result"]

#: Columns of the suite's table (``SuiteResult.table``; docs/suite.md says what each means).
TABLE_COLUMNS = ("task", "learner", "seeds", "episodes", "iqm", "iqm_ci_low", "iqm_ci_high",
                 "best_decentralised", "best_decentralised_iqm", "p_improvement",
                 "score_episodes", "score", "score_ci_low", "score_ci_high",
                 "best_decentralised_score", "best_reference", "best_reference_score",
                 "upper_bound_mean", "upper_bound_ci_low", "upper_bound_ci_high",
                 "above_bound")
#: ``task`` of the aggregate rows.
AGGREGATE = "aggregate"


def _cell(v) -> str:
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.6g}"
    return str(v)


def _f(v, d: int = 1) -> str:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return "–"
    return "–" if not math.isfinite(v) else f"{v:.{d}f}"


def read_table(path: str | Path) -> list[dict]:
    """``table.csv`` back as rows (numbers as floats, empty cells NaN)."""
    with Path(path).open() as fh:
        rows = list(csv.DictReader(fh))
    text = {"task", "learner", "best_decentralised", "best_reference"}
    # a table written before a column existed reads it as NaN
    return [{c: (r.get(c, "") if c in text else (float(r[c]) if r.get(c, "") != ""
                                                  else math.nan))
             for c in TABLE_COLUMNS} for r in rows]


def markdown_table(rows: Sequence[dict]) -> str:
    """The suite's table as Markdown: IQM return [95 % CI], the best decentralised rule's
    IQM, the probability of improvement over it, the normalised score [95 % CI] and the
    references' normalised scores."""
    lines = ["| task | policy | seeds x episodes | IQM return [95 % CI] | best decentralised "
             "rule: IQM | P(policy > rule) | normalised score [95 % CI] | rule, normalised | "
             "best reference, normalised |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        agg = r["task"] == "aggregate"
        n = (f"{int(r['seeds'])} x {int(r['episodes'])}"
             if math.isfinite(float(r["seeds"])) else "–")
        ret = "" if agg else (f"{_f(r['iqm'])} [{_f(r['iqm_ci_low'])}, "
                              f"{_f(r['iqm_ci_high'])}]")
        rule = "" if agg else f"{_f(r['best_decentralised_iqm'])} (`{r['best_decentralised']}`)"
        poi = "" if agg else _f(r["p_improvement"], 2)
        score = (f"{_f(r['score'], 3)} [{_f(r['score_ci_low'], 3)}, "
                 f"{_f(r['score_ci_high'], 3)}]" if math.isfinite(float(r["score"]))
                 else "–" if agg else "– (no bound)")
        ref = _f(r["best_reference_score"], 3)
        if not agg and r["best_reference"]:
            ref += f" (`{r['best_reference']}`)"
        lines.append(f"| {'**aggregate**' if agg else r['task']} | {r['learner']} | {n} | "
                     f"{ret} | {rule} | {poi} | {score} | "
                     f"{_f(r['best_decentralised_score'], 3)} | {ref} |")
    return "\n".join(lines) + "\n"


def leaderboard_markdown(rows: Sequence[dict]) -> str:
    """The leaderboard's tables from ``table.csv``'s rows: one row per policy (and the best
    decentralised rule, the best full-information reference), one column per task and the
    aggregate; first the normalised scores (``never`` = 0, upper bound = 1), then the IQM
    returns."""
    tasks = list(dict.fromkeys(r["task"] for r in rows if r["task"] != "aggregate"))
    learners = list(dict.fromkeys(r["learner"] for r in rows))
    cell = {(r["task"], r["learner"]): r for r in rows}

    def first(task, key):
        for ln in learners:
            r = cell.get((task, ln))
            if r is not None:
                return r[key]
        return math.nan

    head = "| policy | " + " | ".join(f"`{t}`" for t in tasks)
    sep = "|---|" + "---|" * len(tasks)
    norm = [head + " | aggregate |", sep + "---|"]
    for name, key in (("best decentralised rule", "best_decentralised_score"),
                      ("best full-information reference", "best_reference_score")):
        norm.append(f"| *{name}* | " + " | ".join(_f(first(t, key), 3) for t in tasks)
                    + f" | {_f(first('aggregate', key), 3)} |")
    for ln in learners:
        cells = []
        for t in tasks + ["aggregate"]:
            r = cell.get((t, ln))
            cells.append("" if r is None else _f(r["score"], 3))
        norm.append(f"| {ln} | " + " | ".join(cells) + " |")
    ret = [head + " |", sep]
    ret.append("| *best decentralised rule* | " + " | ".join(
        f"{_f(first(t, 'best_decentralised_iqm'))} (`{first(t, 'best_decentralised')}`)"
        for t in tasks) + " |")
    for ln in learners:
        cells = []
        for t in tasks:
            r = cell.get((t, ln))
            cells.append("" if r is None else f"{_f(r['iqm'])}")
        ret.append(f"| {ln} | " + " | ".join(cells) + " |")
    return ("Normalised score (IQM over training seeds x episodes; `never` = 0, certified "
            "upper bound = 1; – where the task has no bound):\n\n" + "\n".join(norm)
            + "\n\nIQM return over training seeds x episodes:\n\n" + "\n".join(ret) + "\n")


def write_result(result, out: str | Path, figure: Sequence[str] | None = None
                 ) -> dict[str, Path]:
    """Write :class:`~netsense.benchmark.suite.SuiteResult`'s files (module docstring);
    ``figure``: the policies the figure shows (default: all)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"table.csv": out / "table.csv", "table.md": out / "table.md",
             "episodes.csv": out / "episodes.csv", "figure.png": out / "figure.png"}
    with atomic_path(paths["table.csv"]) as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(TABLE_COLUMNS)
        for r in result.table:
            w.writerow([_cell(r[c]) for c in TABLE_COLUMNS])
    write_atomic(paths["table.md"], markdown_table(result.table))
    cols = ("task", "learner", "kind", "seed", "episode_seed", "return")
    with atomic_path(paths["episodes.csv"]) as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in result.episodes:
            w.writerow([repr(r[c]) if c == "return" else r[c] for c in cols])
    plot_result(result, paths["figure.png"], figure)
    return paths


def plot_result(result, path: str | Path, learners: Sequence[str] | None = None) -> None:
    """The suite's figure (module docstring) of ``learners`` (default: every policy)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from netsense.benchmark.scores import performance_profile

    rows = [r for r in result.table if r["task"] != "aggregate"]
    tasks = result.tasks
    if learners is None:
        learners = result.learners
    unknown = [ln for ln in learners if ln not in result.learners]
    if unknown:
        raise ValueError(f"the figure's policies {unknown} are not in the result")
    fig = plt.figure(figsize=(13, max(6.0, 0.12 * len(tasks) * len(learners) + 3.0)))
    grid = fig.add_gridspec(2, 2, width_ratios=(1.4, 1), height_ratios=(2.2, 1))
    ax_t = fig.add_subplot(grid[:, 0])
    ax_a = fig.add_subplot(grid[0, 1])
    ax_p = fig.add_subplot(grid[1, 1])
    L = max(1, len(learners))
    for i, t in enumerate(tasks):
        y0 = len(tasks) - 1 - i
        for j, ln in enumerate(learners):
            r = next((r for r in rows if r["task"] == t and r["learner"] == ln), None)
            if r is None or not math.isfinite(r["score"]):
                continue
            y = y0 + 0.3 - 0.6 * j / max(1, L - 1) if L > 1 else y0
            ax_t.errorbar([r["score"]], [y], xerr=[[r["score"] - r["score_ci_low"]],
                                                   [r["score_ci_high"] - r["score"]]],
                          fmt="o", ms=4, color=f"C{j}", capsize=2,
                          label=ln if i == 0 else None)
        r = next((r for r in rows if r["task"] == t), None)
        if r is None or r["score_episodes"] == 0 or not any(
                math.isfinite(x["score"]) for x in rows if x["task"] == t):
            ax_t.text(0.5, y0, "no certified upper bound: not normalised", ha="center",
                      va="center", fontsize=7, color="0.4")
            continue
        ax_t.plot([r["best_decentralised_score"]], [y0], "D", color="k", ms=6, mfc="none",
                  label="best decentralised rule" if i == 0 else None)
        if math.isfinite(r["best_reference_score"]):
            ax_t.plot([r["best_reference_score"]], [y0], "^", color="C3", ms=7, mfc="none",
                      label="best full-information reference" if i == 0 else None)
    ax_t.axvline(0, color="0.5", ls="-.", lw=1)
    ax_t.axvline(1, color="C3", ls=":", lw=1.2)
    ax_t.set_yticks(range(len(tasks)), list(reversed(tasks)), fontsize=8)
    ax_t.set_xlabel("normalised score, IQM over seeds x episodes [95 % CI] "
                    "(never = 0, upper bound = 1)")
    ax_t.set_ylim(-0.7, len(tasks) - 0.3)
    ax_t.grid(alpha=0.3, axis="x")
    handles, labels = ax_t.get_legend_handles_labels()
    ax_t.legend(handles + [plt.Line2D([], [], color="C3", ls=":")], labels + ["upper bound"],
                fontsize=7, loc="lower left")
    agg = [r for r in result.table if r["task"] == "aggregate" and math.isfinite(r["score"])]
    for j, ln in enumerate(learners):
        r = next((r for r in agg if r["learner"] == ln), None)
        if r is not None:
            ax_a.errorbar([r["score"]], [L - 1 - j], xerr=[[r["score"] - r["score_ci_low"]],
                                                           [r["score_ci_high"] - r["score"]]],
                          fmt="o", color=f"C{j}", capsize=3)
    if agg:
        ax_a.axvline(agg[0]["best_decentralised_score"], color="k", ls="--", lw=1,
                     label="best decentralised rules")
        if math.isfinite(agg[0]["best_reference_score"]):
            ax_a.axvline(agg[0]["best_reference_score"], color="C3", ls="--", lw=1,
                         label="best references")
        ax_a.legend(fontsize=7)
    else:
        ax_a.text(0.5, 0.5, "no aggregate: a task lacks a certified upper bound",
                  ha="center", va="center", fontsize=8, color="0.4",
                  transform=ax_a.transAxes)
    ax_a.axvline(1, color="C3", ls=":", lw=1.2)
    ax_a.axvline(0, color="0.5", ls="-.", lw=1)
    ax_a.set_yticks(range(L), list(reversed(learners)), fontsize=8)
    ax_a.set_title(f"aggregate over {len(tasks)} tasks: IQM [95 % CI]", fontsize=9)
    if result.scores:
        taus = np.linspace(-0.25, 1.0, 51)
        prof, prof_ci = performance_profile(
            {k: v for k, v in result.scores.items() if k in learners}, taus)
        for j, ln in enumerate(learners):
            if ln in prof:
                ax_p.plot(taus, prof[ln], color=f"C{j}", lw=1.3)
                ax_p.fill_between(taus, prof_ci[ln][0], prof_ci[ln][1], color=f"C{j}",
                                  alpha=0.2)
        ax_p.set_xlabel(r"normalised score $\tau$")
        ax_p.set_ylabel(r"fraction of runs $> \tau$")
        ax_p.grid(alpha=0.3)
    else:
        ax_p.axis("off")
    ax_p.set_title("performance profile", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
