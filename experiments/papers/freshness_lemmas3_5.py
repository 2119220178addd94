"""Lemmas 3 and 5 of the freshness-index paper over many random graph sequences, batched.

Claims (under Assumption 1, joint strong connectivity over every window of ``T`` steps):

* Lemma 3, eq. (15): every freshness index is finite from step ``(N-1)T`` on;
* Lemma 5, eq. (17): every index is at most ``2(N-1)T`` from step ``(N-1)T`` on.

For each case (graph family, ``N``, ``T``) the environment's batched core
(:class:`netsense.engine.core.BatchedCore`) runs ``--batch`` independent members — each its
own graph sequence, seed ``seed + b`` — under the scripted freshness policy (transmit
always; this is the freshness observer, eqs. (8)-(14)), as **one array program**: there is
no Python loop over runs. Families with a guaranteed period ``T``
(:func:`netsense.graphs.families.guaranteed_period`): ``random_jsc`` (random jointly strongly
connected graphs, several extra-edge probabilities), ``ring`` and ``ring_backward``
(round-robin directed ring; the backward schedule is the slowest, where the bounds are
nearly tight).

Per member we record the step after which all indices stay finite
(:func:`netsense.graphs.aoi.trigger_step`) and the worst index over ``k >= (N-1)T``; a
violation is a member above a bound. Writes, into
``experiments/results/papers/freshness_lemmas3_5/``, ``lemma_checks_batched.csv`` (one row
per case) and ``lemma_checks_batched.png`` (measured maxima vs bounds).

Run: ``python experiments/papers/freshness_lemmas3_5.py`` (a few minutes on 2 shared cores;
``--smoke`` for seconds).
"""

# %%
from __future__ import annotations

import argparse
import csv
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from netsense.engine.core import BatchedCore, CoreModel
from netsense.env.policies import FreshnessPolicy
from netsense.graphs.aoi import trigger_step, worst_index
from netsense.graphs.bounds import lemma3_bound, lemma5_bound
from netsense.graphs.families import guaranteed_period, make_graph_process
from netsense.systems.design import design_observer
from netsense.systems.plants import random_structured

RESULTS = Path(__file__).resolve().parents[1] / "results" / "papers" / "freshness_lemmas3_5"


@dataclass(frozen=True)
class Case:
    """One family / size / period; ``param`` is the family parameter."""

    family: str
    N: int
    T: int
    param: float = 0.0


def default_cases(Ns: Sequence[int], Ts: Sequence[int]) -> list[Case]:
    cases = []
    for N in Ns:
        for T in Ts:
            for p in (0.0, 0.1, 0.3):
                cases.append(Case("random_jsc", N, T, p))
            cases.append(Case("ring", N, T))
            cases.append(Case("ring_backward", N, T))
    return cases


def case_model(case: Case, steps: int, n: int = 4, seed: int = 0) -> CoreModel:
    """Noiseless ``random_structured(n, N)`` plant (indices do not depend on it)."""
    plant = random_structured(n, case.N, rng=seed, spectral_radius=1.0)
    graphs = make_graph_process(case.family, case.N, case.T, case.param)
    if guaranteed_period(graphs) != case.T:
        raise ValueError(f"{case}: the family does not guarantee period T = {case.T}")
    return CoreModel(plant=plant, design=design_observer(plant, rho=0.5), graphs=graphs,
                     horizon=steps)


# %% One case, one batch
def run_case(case: Case, batch: int, seed: int = 0, extra: int = 10) -> dict:
    """Run ``batch`` members for ``2 (N-1) T + extra`` steps; one summary row.

    The index history ``(K + 1, B, N, N)`` is recorded from the core after each step.
    """
    N, T = case.N, case.T
    b3, b5 = lemma3_bound(N, T), lemma5_bound(N, T)
    steps = int(b5) + extra
    model = case_model(case, steps, seed=seed)
    t0 = time.perf_counter()
    core = BatchedCore(model, batch)
    obs, mask = core.reset(seed)
    pol = FreshnessPolicy(core.layout)
    tau = np.empty((steps + 1, batch, N, N), dtype=np.int64)
    tau[0] = core.tau
    for k in range(steps):
        out = core.step(pol.act(obs, mask))
        obs, mask = out.obs, out.action_mask
        tau[k + 1] = core.tau
    seconds = time.perf_counter() - t0
    trig = trigger_step(tau)
    worst = worst_index(tau, int(b3))
    return {"family": case.family, "N": N, "T": T, "param": case.param, "batch": batch,
            "steps": steps, "D": core.D,
            "bound_lemma3": b3, "trigger_max": int(trig.max()),
            "trigger_median": float(np.median(trig)),
            "never_triggered": int((trig < 0).sum()),
            "violations_lemma3": int(((trig < 0) | (trig > b3)).sum()),
            "bound_lemma5": b5, "worst_max": int(worst.max()),
            "worst_median": float(np.median(worst)),
            "violations_lemma5": int((worst > b5).sum()),
            "tightness_lemma3": float(trig.max() / b3),
            "tightness_lemma5": float(worst.max() / b5),
            "distinct_sequences": int(len({core_sig for core_sig in _signatures(tau)})),
            "seconds": seconds, "member_steps_per_s": batch * steps / seconds}


def _signatures(tau: np.ndarray) -> list[bytes]:
    """A fingerprint per member (its index history), to count distinct realisations."""
    return [tau[:, b].tobytes() for b in range(tau.shape[1])]


# %% Figure
def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.3))
    style = {"random_jsc": ("tab:green", "s"), "ring": ("tab:blue", "o"),
             "ring_backward": ("tab:purple", "v")}
    for ax, (bound, meas, title) in zip(axes, (
            ("bound_lemma3", "trigger_max", "Lemma 3: last step with an omega index"),
            ("bound_lemma5", "worst_max", "Lemma 5: worst index for k >= (N-1)T")),
            strict=True):
        for fam, (c, m) in style.items():
            rs = [r for r in rows if r["family"] == fam]
            if rs:
                ax.scatter([r[bound] for r in rs], [r[meas] for r in rs], color=c,
                           marker=m, label=fam, alpha=0.8)
        hi = max(r[bound] for r in rows) * 1.1
        ax.plot([0, hi], [0, hi], "k--", lw=0.8, label="bound")
        ax.set_xlabel("bound")
        ax.set_ylabel("max over the batch")
        ax.set_title(title, fontsize=10)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    B = rows[0]["batch"]
    fig.suptitle(f"{len(rows)} cases x {B} random graph sequences each (batched core, "
                 "freshness policy)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# %% Main
def main(argv: Sequence[str] | None = None) -> int:
    from tqdm import tqdm

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--batch", type=int, default=512, help="graph sequences per case")
    p.add_argument("--N", type=int, nargs="+", default=[4, 8, 12])
    p.add_argument("--T", type=int, nargs="+", default=[1, 2, 4])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--smoke", action="store_true", help="two tiny cases")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    if args.smoke:
        cases, batch, stem = [Case("random_jsc", 4, 2, 0.1), Case("ring_backward", 3, 2)], \
            8, "lemma_checks_batched_smoke"
    else:
        cases, batch, stem = default_cases(args.N, args.T), args.batch, "lemma_checks_batched"
    rows = [run_case(c, batch, args.seed)
            for c in tqdm(cases, desc="cases", disable=args.no_progress)]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / f"{stem}.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    plot(rows, out / f"{stem}.png")
    v3 = sum(r["violations_lemma3"] for r in rows)
    v5 = sum(r["violations_lemma5"] for r in rows)
    total = sum(r["batch"] for r in rows)
    print(f"{len(cases)} cases, {total} member runs: Lemma 3 violations {v3}, Lemma 5 "
          f"violations {v5}; max tightness (measured / bound): Lemma 3 "
          f"{max(r['tightness_lemma3'] for r in rows):.3f}, Lemma 5 "
          f"{max(r['tightness_lemma5'] for r in rows):.3f}")
    rate = sum(r["batch"] * r["steps"] for r in rows) / sum(r["seconds"] for r in rows)
    print(f"throughput: {rate:.0f} member-steps/s over all cases")
    print(f"wrote {out / stem}.csv and .png")
    return 0 if v3 == v5 == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
