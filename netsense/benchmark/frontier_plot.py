"""The Pareto plot of a communication task: one marker and legend group per kind.

:func:`plot_frontier` draws the rows of :func:`netsense.benchmark.protocol.frontier`:
error vs messages (left, log scale) and return vs messages (right), every point with its
95 % intervals on both axes. The kinds (:data:`netsense.benchmark.protocol.KINDS`) never
share a look:

==================  ============================================================
kind                drawn as
==================  ============================================================
decentralised       a curve per family through its knob settings (solid line,
                    hollow marker of the family's own shape, knob values written
                    beside the points; an informed rule's curve runs through its
                    base rules, dash-dotted); ``always`` and ``never`` as black
                    hollow square and cross
privileged          a dotted grey curve per rule through its base rules, filled
                    small markers ("reads what no agent observes")
centralised         a dashed curve per scheduler, hollow triangles
reference           a large filled diamond per full-information reference
                    scheduler, and on the return panel a dotted horizontal line at
                    its mean return ("achieved, not deployable")
upper_bound         a large filled upward triangle per bound, and on the return
                    panel a solid horizontal line at its mean return
learned             a star per run and evaluation, each run its own colour
                    (greedy filled, sampled hollow)
==================  ============================================================

Hollow markers of distinct shapes keep coinciding points visible (``always`` and a curve
through the same point, two learned runs at the same place). The legend is built from the
exact marker, colour, fill and line of every series and grouped by kind, below the axes.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense.benchmark.kinds import INFORMED_FAMILIES, family_kind, reference_label
from netsense.rl.atomic import save_figure

__all__ = ["plot_frontier"]

#: Hollow marker shapes of the decentralised families, in order of appearance.
_SHAPES = ("o", "v", "<", ">", "p", "h", "8", "P", "d", "H")
_GROUPS = (("decentralised", "decentralised policies"),
           ("privileged", "privileged rules (read what no agent observes)"),
           ("centralised", "centralised schedulers"),
           ("reference", "full-information reference schedulers (achieved, not deployable)"),
           ("upper_bound", "upper bounds (certified)"),
           ("learned", "learned policies"))
_REFERENCE_COLOURS = {"reference:causal": "#b2182b", "reference:clairvoyant": "#762a83"}
#: Colours of the decentralised curves (none of the references' reds and purples, the
#: centralised teals, the privileged greys or the learned oranges).
_DECENTRALISED = ("#1f77b4", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
                  "#393b79", "#637939", "#843c39", "#7b4173")


def _series(rows: Sequence[dict]) -> list[tuple[str, str, list[dict]]]:
    """``(kind, legend label, rows)`` per series: a family's knob curve, an endpoint, a
    reference or bound, or one learned run under one evaluation."""
    out: dict[tuple[str, str], list[dict]] = {}
    seen: dict[str, int] = {}
    for r in rows:
        kind = r.get("kind") or family_kind(r["family"])  # (rows of older CSV files)
        if kind == "learned":
            run = r.get("label") or Path(str(r["knob"])).parent.name or "learned"
            label = f"{run} ({r['evaluation']})"
            n = seen[label] = seen.get(label, 0) + 1
            label = label if n == 1 else f"{run} #{n} ({r['evaluation']})"
        elif kind == "reference":
            label = reference_label(r["policy"])
            label = f"{label} (continues {r['knob']})" if r["knob"] else label
        elif kind == "upper_bound":
            label = str(r["policy"])
        else:
            label = r["family"]
        out.setdefault((kind, label), []).append(r)
    return [(kind, label, rs) for (kind, label), rs in out.items()]


def _style(kind: str, label: str, rs: list[dict], index: dict[str, int]) -> dict:
    """The matplotlib style of a series (also used for its legend entry)."""
    if kind == "decentralised":
        if label == "always":
            return dict(color="k", marker="s", mfc="none", ms=7, ls="none")
        if label == "never":
            return dict(color="k", marker="x", ms=7, ls="none")
        i = index["decentralised"] = index.get("decentralised", -1) + 1
        return dict(color=_DECENTRALISED[i % len(_DECENTRALISED)],
                    marker=_SHAPES[i % len(_SHAPES)], mfc="none", ms=6,
                    ls="-." if label in INFORMED_FAMILIES else "-")
    if kind == "privileged":
        i = index["privileged"] = index.get("privileged", -1) + 1
        return dict(color=("#525252", "#969696", "#252525")[i % 3],
                    marker=("X", "P", "*")[i % 3], ms=6, ls=":")
    if kind == "centralised":
        i = index["centralised"] = index.get("centralised", -1) + 1
        return dict(color=("#01665e", "#35978f", "#003c30")[i % 3],
                    marker="^" if i % 2 == 0 else "v", mfc="none", ms=7, ls="--")
    if kind == "reference":
        return dict(color=_REFERENCE_COLOURS.get(rs[0]["policy"], "#444444"), marker="D",
                    ms=9, ls="none")
    if kind == "upper_bound":
        return dict(color="#000000", marker="^", ms=10, ls="none")
    run = label.rsplit(" (", 1)[0]
    i = index.setdefault(f"run:{run}", len([k for k in index if k.startswith("run:")]))
    sampled = rs[0]["evaluation"] == "sampled"
    return dict(color=("#e08214", "#8c510a", "#b35806", "#fdb863", "#7f3b08")[i % 5],
                marker="*", ms=13, ls="none", mfc="none" if sampled else None)


def plot_frontier(rows: Sequence[dict], path: str | Path) -> Path:
    """Draw the rows of one scenario's frontier into ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    rows = list(rows)
    per_sub = any(r["control"] == "substates" for r in rows if r["family"] != "learned")
    xm = "load_per_agent_step" if per_sub else "msgs_per_agent_step"
    series = _series(rows)
    index: dict[str, int] = {}
    styles = [_style(kind, label, rs, index) for kind, label, rs in series]
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.2))
    for ax, ym, ylabel in ((axes[0], "mean_rel_error", "mean relative error"),
                           (axes[1], "reward", "episode return (mean over agents)")):
        for (kind, _, rs), st in zip(series, styles, strict=True):
            rs = sorted(rs, key=lambda r: r[f"{xm}_mean"])
            x = np.array([r[f"{xm}_mean"] for r in rs])
            y = np.array([r[f"{ym}_mean"] for r in rs])
            xerr = np.abs(np.array([[r[f"{xm}_ci_low"], r[f"{xm}_ci_high"]] for r in rs]).T
                          - x)
            yerr = np.abs(np.array([[r[f"{ym}_ci_low"], r[f"{ym}_ci_high"]] for r in rs]).T
                          - y)
            z = {"upper_bound": 6, "reference": 5, "learned": 4, "centralised": 3}.get(kind, 2)
            ax.errorbar(x, y, xerr=xerr, yerr=yerr, lw=1.2, capsize=2, elinewidth=0.8,
                        zorder=z, **st)
            if kind in ("reference", "upper_bound") and ym == "reward":
                ax.axhline(y[0], color=st["color"], ls=":" if kind == "reference" else "-",
                           lw=1.0, zorder=1)
            if kind in ("decentralised", "privileged", "centralised") and st["ls"] != "none":
                for r, xi, yi in zip(rs, x, y, strict=True):
                    ax.annotate(str(r["knob"]), (xi, yi), fontsize=6, xytext=(2, 2),
                                textcoords="offset points", color=st["color"])
        ax.set_xlabel("substate messages per agent-step / M" if per_sub
                      else "messages per agent-step")
        ax.set_ylabel(ylabel)
        if ym == "mean_rel_error":
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
    handles = []
    for kind, title in _GROUPS:
        members = [(label, st) for (k, label, _), st in zip(series, styles, strict=True)
                   if k == kind]
        if not members:
            continue
        handles.append(Line2D([], [], ls="none", marker="", label=f"{title}:"))
        for label, st in members:
            handles.append(Line2D([], [], label=label, lw=1.2, **st))
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=7, frameon=False)
    r0 = next((r for r in rows if r.get("kind") not in ("reference", "upper_bound")), rows[0])
    note = "".join(f"; {r['policy']}: {r['episodes']} episodes" for r in rows
                   if r.get("kind") in ("reference", "upper_bound"))
    fig.suptitle(f"{r0['scenario']} ({r0['control']} control): {r0['episodes']} episodes, "
                 f"seeds from {r0['seed_first']}{note}; 95 % bootstrap CI", fontsize=10)
    rows_needed = int(np.ceil(len(handles) / 4))
    fig.tight_layout(rect=(0, min(0.45, 0.035 * rows_needed + 0.02), 1, 0.96))
    save_figure(fig, path)
    plt.close(fig)
    return Path(path)
