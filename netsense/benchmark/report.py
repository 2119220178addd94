"""Reports of benchmark results: aggregation over seeds, CSV, Markdown table and plots."""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from netsense.benchmark.metrics import METRICS
from netsense.env.policies import SCRIPTED_POLICIES
from netsense.rl.atomic import atomic_path, save_figure


def aggregate(results: Iterable[dict]) -> list[dict]:
    """Mean and standard deviation over seeds per (scenario, policy), in first-seen order,
    with the protocol's 95 % bootstrap interval of the mean (``<metric>_ci_low``,
    ``<metric>_ci_high``; :func:`netsense.benchmark.protocol.bootstrap_ci`, over the
    finite values)."""
    from netsense.benchmark.protocol import bootstrap_ci

    groups: dict[tuple[str, str], list[dict]] = {}
    for r in results:
        groups.setdefault((r["job"]["scenario"], _label(r["job"]["policy"])), []).append(r)
    rows = []
    for (scenario, policy), rs in groups.items():
        row: dict = {"scenario": scenario, "policy": policy, "seeds": len(rs)}
        for m in METRICS:
            vals = np.array([r["metrics"][m] for r in rs], dtype=float)
            fin = vals[np.isfinite(vals)]
            row[f"{m}_mean"] = float(fin.mean()) if fin.size else float("nan")
            row[f"{m}_std"] = float(fin.std()) if fin.size > 1 else 0.0 if fin.size else \
                float("nan")
            _, row[f"{m}_ci_low"], row[f"{m}_ci_high"] = bootstrap_ci(fin)
            if m == "steps_to_eps":
                row["reached_eps"] = int(fin.size)
        rows.append(row)
    return rows


def _label(policy: str) -> str:
    if policy.startswith("learned_sampled"):
        return "learned (sampled)"
    return "learned" if policy.startswith("learned") else policy


def _color(label: str) -> str:
    """The same colour for a policy in every plot and panel."""
    order = ("learned",) + SCRIPTED_POLICIES + ("kf_oracle",)
    return f"C{order.index(label) % 10}" if label in order else "k"


def write_csv(results: Sequence[dict], path: str | Path) -> Path:
    """One row per episode: scenario, policy, seed and every metric."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["scenario", "policy", "seed", *METRICS])
        for r in results:
            j = r["job"]
            w.writerow([j["scenario"], _label(j["policy"]), j["seed"],
                        *[_fmt_csv(r["metrics"][m]) for m in METRICS]])
    return path


def _fmt_csv(v: float) -> str:
    return "nan" if not math.isfinite(v) else f"{v:.6g}"


def _fmt(mean: float, std: float, digits: int = 3) -> str:
    if not math.isfinite(mean):
        return "–"
    s = f"{mean:.{digits}g}"
    if not math.isfinite(std) or std <= 1e-9 * abs(mean):  # identical up to rounding
        return s
    return f"{s} ± {std:.2g}"


def markdown_table(rows: Sequence[dict], eps: float = 1e-2) -> str:
    """The aggregated table in Markdown (mean ± std over seeds).

    ``steps to eps`` averages the seeds that reached ``eps`` (their count in brackets);
    AoI cells read ``ω`` when no index ever became finite, ``–`` when not tracked.
    """
    head = ("| scenario | policy | mean rel. error | final rel. error | "
            f"steps to {eps:g} (reached) | msgs / agent-step | mean AoI | max AoI | reward |")
    lines = [head, "|" + "---|" * 9]
    for r in rows:
        reach = f"{_fmt(r['steps_to_eps_mean'], r['steps_to_eps_std'])} " \
                f"({r['reached_eps']}/{r['seeds']})"
        cells = [r["scenario"], r["policy"],
                 _fmt(r["mean_rel_error_mean"], r["mean_rel_error_std"]),
                 _fmt(r["final_rel_error_mean"], r["final_rel_error_std"]), reach,
                 _fmt(r["msgs_per_agent_step_mean"], r["msgs_per_agent_step_std"]),
                 _aoi(r, "aoi_mean"), _aoi(r, "aoi_max"),
                 _fmt(r["reward_mean"], r["reward_std"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _aoi(row: dict, key: str) -> str:
    """AoI cell; ``ω`` when every index stayed omega (e.g. uniform averages, whose age is
    the stalest contributor's), ``–`` when AoI is not tracked (the oracle)."""
    if not math.isfinite(row[f"{key}_mean"]) and row.get("aoi_omega_frac_mean", 0) == 1:
        return "ω"
    return _fmt(row[f"{key}_mean"], row[f"{key}_std"])


def plot_errors(results: Sequence[dict], path: str | Path, scenario: str) -> Path:
    """Error vs time per policy for one scenario: median over seeds, inter-quartile band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    curves: dict[str, list[np.ndarray]] = {}
    for r in results:
        if r["job"]["scenario"] == scenario:
            curves.setdefault(_label(r["job"]["policy"]), []).append(np.asarray(r["curve"]))
    for label, cs in curves.items():
        c = np.vstack(cs)
        c = np.maximum(c, 1e-16)  # exact zeros (deadbeat) drawn at the bottom of the log axis
        k = np.arange(c.shape[1])
        med = np.median(c, axis=0)
        ax.plot(k, med, label=label, color=_color(label))
        if c.shape[0] > 1:
            ax.fill_between(k, np.percentile(c, 25, axis=0), np.percentile(c, 75, axis=0),
                            alpha=0.2, color=_color(label))
    ax.set_yscale("log")
    ax.set_xlabel("step k")
    ax.set_ylabel("relative error (mean over agents)")
    ax.set_title(scenario)
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_reward_vs_messages(rows: Sequence[dict], path: str | Path) -> Path:
    """Scenario reward against messages per agent-step, one panel per scenario."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenarios = list(dict.fromkeys(r["scenario"] for r in rows))
    fig, axes = plt.subplots(1, len(scenarios), figsize=(4.2 * len(scenarios), 3.6),
                             squeeze=False)
    for ax, sc in zip(axes[0], scenarios, strict=True):
        for r in rows:
            if r["scenario"] != sc or not math.isfinite(r["reward_mean"]):
                continue
            ax.errorbar(r["msgs_per_agent_step_mean"], r["reward_mean"],
                        xerr=r["msgs_per_agent_step_std"], yerr=r["reward_std"], fmt="o",
                        label=r["policy"], capsize=3, color=_color(r["policy"]))
        ax.set_xlabel("messages per agent-step")
        ax.set_ylabel("episode reward (mean over agents)")
        ax.set_title(sc, fontsize=9)
        ax.legend(fontsize=7)
    return _save(fig, path)


def _save(fig, path: str | Path) -> Path:
    """Write ``fig`` as a PNG at ``path`` (directories created) and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path)
    plt.close(fig)
    return path
