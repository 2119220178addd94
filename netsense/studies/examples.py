"""The paper's illustrative example (Section III, Figs. 1-2) as a reusable simulation.

Used by ``netsense demo`` and ``experiments/papers/freshness_fig2.py``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from netsense.graphs.processes import fig1_graphs
from netsense.observers import ConsensusObserver, FreshnessObserver
from netsense.systems.design import design_observer
from netsense.systems.plants import fig1_scalar

#: Observers compared in Fig. 2 (label -> constructor keyword arguments).
FIG2_OBSERVERS = {
    "consensus (uniform)": (ConsensusObserver, {"weights": "uniform"}),
    "consensus (tree)": (ConsensusObserver, {"weights": "tree"}),
    "freshness index": (FreshnessObserver, {}),
}


def run_fig2(steps: int = 30, a: float = 2.0, seed: int = 0) -> dict[str, np.ndarray]:
    """Simulate Fig. 2: the scalar plant ``x[k+1] = a x[k]`` on the graphs of Fig. 1.

    Node 1 measures ``x`` and uses the deadbeat gain, so (as in the paper) it has perfect
    information from ``k = 1`` on; nodes 2 and 3 start from random estimates.

    Returns
    -------
    dict
        ``"k"`` (steps ``0..steps``) and, per observer label, the ``(steps + 1, 3)`` array of
        absolute errors ``|x_hat_i[k] - x[k]|``; also ``"x"``, the true state.
    """
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    rng = np.random.default_rng(seed)
    plant = fig1_scalar(a)
    design = design_observer(plant, deadbeat=True)
    x0 = np.array([1.0])
    x0_hat = np.concatenate([[x0[0]], x0[0] + rng.uniform(-1, 1, size=2)])[:, None]
    graphs = fig1_graphs().sequence(steps)
    out: dict[str, np.ndarray] = {"k": np.arange(steps + 1)}
    xs = [x0]
    for _ in range(steps):
        xs.append(plant.step(xs[-1]))
    out["x"] = np.array(xs)[:, 0]
    for label, (cls, kwargs) in FIG2_OBSERVERS.items():
        obs = cls(design, **kwargs)
        obs.reset(x0_hat)
        errs = [obs.errors(xs[0])]
        for k in range(steps):
            obs.step(plant.measure(xs[k]), graphs[k])
            errs.append(obs.errors(xs[k + 1]))
        out[label] = np.array(errs)
    return out


def save_fig2(result: dict[str, np.ndarray], out_dir: str | Path, stem: str = "fig2") -> tuple[
        Path, Path]:
    """Write the Fig. 2 errors as CSV and a three-panel PNG; return both paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    labels = list(FIG2_OBSERVERS)
    header = ["k"] + [f"{lab} node {i + 1}" for lab in labels for i in range(3)]
    rows = np.column_stack([result["k"]] + [result[lab] for lab in labels])
    csv = out_dir / f"{stem}.csv"
    np.savetxt(csv, rows, delimiter=",", header=",".join(header), comments="", fmt="%.6g")
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4), sharey=True)
    for ax, lab in zip(axes, labels, strict=True):
        for i in range(3):
            ax.semilogy(result["k"], np.maximum(result[lab][:, i], 1e-16), marker=".",
                        label=f"node {i + 1}")
        ax.set_title(lab)
        ax.set_xlabel("k")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel(r"$|\hat x_i[k] - x[k]|$")
    axes[0].legend()
    fig.suptitle("Fig. 2 reproduction: scalar plant a = 2 on the switching graphs of Fig. 1")
    fig.tight_layout()
    png = out_dir / f"{stem}.png"
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return csv, png


def summarize_fig2(result: dict[str, np.ndarray]) -> str:
    """One line per observer: final worst error, its growth factor per step, a verdict.

    The growth factor is measured over the second half of the run on the error maxima over
    two-step windows (the tree weighting zeroes a node's error every other step).
    """
    lines = []
    K = int(result["k"][-1])
    for lab in FIG2_OBSERVERS:
        worst = result[lab].max(axis=1)
        final = float(worst[-2:].max())
        mid = float(worst[K // 2 - 1: K // 2 + 1].max())
        growth = (final / mid) ** (1.0 / (K - K // 2)) if mid > 0 and final > 0 else 0.0
        rel = final / float(np.abs(result["x"][-1]))
        verdict = "converges" if rel < 1e-9 else ("diverges" if growth > 1.01 else "bounded")
        lines.append(f"{lab:22s} worst error at k={K}: {final:.3g}, growth per step "
                     f"{growth:.3f}  ({verdict})")
    return "\n".join(lines)
