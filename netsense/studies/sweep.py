"""Topology sweeps: the freshness observer run over graph families, seeds and sizes.

One :class:`SweepCase` is a family (:data:`netsense.graphs.families.FAMILIES`), its size
``N`` and period ``T``, a plant size ``n`` and a batch of seeds; :func:`run_case` runs it
with both gain designs (deadbeat, Corollary 1; rate-ordered, Theorem 1) on the same graphs
and returns one row per seed with the measured trigger step, worst index, steps to
tolerance, messages, adoptions and ages beside the paper's bounds
(:mod:`netsense.graphs.bounds`). :func:`run_sweep` runs many cases in worker processes with
a progress bar; :func:`summarize` and :func:`write_csv` reduce and store the rows. Behind
``netsense sweep`` and ``experiments/studies/topology_sweep.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from netsense.graphs.aoi import aoi_stats, trigger_step, worst_index
from netsense.graphs.bounds import (
    corollary1_bound,
    lemma3_bound,
    lemma5_bound,
    sharp_index_bound,
    theorem1_onset,
)
from netsense.graphs.families import FAMILIES, guaranteed_period, make_graph_process
from netsense.graphs.processes import GraphProcess, check_joint_connectivity, smallest_period
from netsense.kernels import checks
from netsense.observers.run import relative_error, run_observer, steps_to_tolerance

__all__ = ["SweepCase", "run_case", "run_sweep", "sample_graphs", "summarize", "write_csv"]


# ----------------------------------------------------------------------------- sweep case
@dataclass(frozen=True)
class SweepCase:
    """One point of a topology sweep: a family, its size and a batch of seeds.

    Attributes
    ----------
    family : str
        A key of :data:`FAMILIES`.
    N : int
        Number of agents.
    T : int
        Period for the families that have one (``ring``, ``ring_backward``,
        ``random_jsc``); ignored otherwise (their ``T`` is measured on the realised
        sequence with :func:`netsense.graphs.processes.smallest_period`).
    n : int
        Plant dimension (``random_structured(n, N)`` with ``spectral_radius``).
    param : float
        Family parameter (see :data:`FAMILIES`).
    seeds : int
        Batch size ``B``: graph sequences and initial states per case.
    steps : int
        Horizon ``K``.
    seed : int
        Master seed (plant, graphs, initial states).
    eps : float
        Relative-error tolerance of :func:`steps_to_tolerance`.
    rho : float
        Theorem 1 rate for the rho-ordered gains.
    spectral_radius : float
        Largest eigenvalue modulus of the plant.
    """

    family: str
    N: int
    T: int = 1
    n: int = 4
    param: float = 0.0
    seeds: int = 8
    steps: int = 200
    seed: int = 0
    eps: float = 1e-6
    rho: float = 0.5
    spectral_radius: float = 1.05

    def __post_init__(self) -> None:
        if self.family not in FAMILIES:
            raise ValueError(f"family must be one of {sorted(FAMILIES)}, got {self.family!r}")
        for name, low in (("N", 2), ("T", 1), ("n", 1), ("seeds", 1), ("steps", 1)):
            checks.integer(name, getattr(self, name))
            if getattr(self, name) < low:
                raise ValueError(f"{name} must be >= {low}, got {getattr(self, name)}")
        checks.number("rho", self.rho)
        checks.number("eps", self.eps)
        checks.number("param", self.param)
        if not 0 < self.rho < 1:
            raise ValueError(f"rho must be in (0, 1), got {self.rho}")
        if self.eps <= 0:
            raise ValueError(f"eps must be > 0, got {self.eps}")


def sample_graphs(process: GraphProcess, batch: int, steps: int,
                  rng: np.random.Generator) -> np.ndarray:
    """``(B, K, N, N)``: ``batch`` independent sequences, each from a child generator."""
    children = rng.spawn(batch)
    return np.stack([process.sequence(steps, c) for c in children])


def run_case(case: SweepCase) -> list[dict]:
    """Run one sweep case with the batched freshness observer; one result row per seed.

    Both gain designs (deadbeat, Corollary 1; rho-ordered, Theorem 1) see the same plant,
    graph sequences and initial states. Row fields: the case fields, ``batch`` (seed
    index), ``T_used`` (the guaranteed period, else the smallest ``T <= steps / 4`` for
    which Assumption 1 holds on the realised sequence, NaN if there is none),
    ``assumption1``, ``trigger`` / ``bound_lemma3``,
    ``worst_index`` (over ``k >= trigger``) / ``bound_lemma5``, ``worst_after_lemma3``
    (over ``k >= (N-1)T``), ``steps_deadbeat`` / ``bound_corollary1``, ``steps_rho`` /
    ``onset_theorem1``, ``messages_per_step``, ``adoptions_per_step``, ``aoi_mean``,
    ``aoi_peak``, ``aoi_max`` (over non-source pairs after the trigger step).
    """
    from netsense.observers.freshness import FreshnessObserver
    from netsense.systems.decomposition import decompose
    from netsense.systems.design import design_observer
    from netsense.systems.plants import random_structured

    rng = np.random.default_rng(case.seed)
    plant = random_structured(case.n, case.N, rng=rng, spectral_radius=case.spectral_radius)
    process = make_graph_process(case.family, case.N, case.T, case.param)
    graphs = sample_graphs(process, case.seeds, case.steps, rng)
    x0 = rng.standard_normal((case.seeds, case.n))
    trajs = {}
    dec = decompose(plant.A, plant.C)  # one Lemma 1 decomposition serves both designs
    for label, kw in (("deadbeat", {"deadbeat": True}), ("rho", {"rho": case.rho})):
        design = design_observer(plant, decomposition=dec, **kw)
        obs = FreshnessObserver(design, batch_size=case.seeds)
        trajs[label] = run_observer(obs, plant, graphs, x0)
    tr = trajs["deadbeat"]
    trig = trigger_step(tr.tau)
    worst = worst_index(tr.tau, trig)
    steps_db = steps_to_tolerance(relative_error(tr), case.eps)
    steps_rho = steps_to_tolerance(relative_error(trajs["rho"]), case.eps)
    T_guar = guaranteed_period(process)
    offdiag = ~np.eye(case.N, dtype=bool)
    rows = []
    for b in range(case.seeds):
        if T_guar is not None:
            T_used, holds = T_guar, True
        else:
            # at least four complete windows, so "Assumption 1 holds" says something
            T_emp = smallest_period(graphs[b], max_period=max(case.steps // 4, 1))
            holds = T_emp is not None
            T_used = T_emp if holds else float("nan")
        if holds and T_guar is None:
            holds = check_joint_connectivity(graphs[b], int(T_used)).holds
        start3 = int(lemma3_bound(case.N, T_used)) if holds else -1
        t0 = int(trig[b]) if trig[b] >= 0 else case.steps + 1
        st = aoi_stats(tr.tau[:, b:b + 1], min(t0, case.steps))
        rows.append({
            "family": case.family, "N": case.N, "T": case.T, "n": case.n,
            "param": case.param, "seed": case.seed, "batch": b, "steps": case.steps,
            "T_used": T_used, "assumption1": holds,
            "trigger": int(trig[b]), "bound_lemma3": lemma3_bound(case.N, T_used),
            "worst_index": int(worst[b]), "bound_lemma5": lemma5_bound(case.N, T_used),
            "bound_index_sharp": sharp_index_bound(case.N, T_used),
            "worst_after_lemma3": int(worst_index(tr.tau[:, b:b + 1], start3)[0])
            if 0 <= start3 <= case.steps else -1,
            "steps_deadbeat": int(steps_db[b]),
            "bound_corollary1": corollary1_bound(case.n, case.N, T_used),
            "steps_rho": int(steps_rho[b]), "onset_theorem1": theorem1_onset(case.N, T_used),
            "messages_per_step": float(tr.messages[:, b].mean()),
            "adoptions_per_step": float(tr.adoptions[:, b].mean()),
            "aoi_mean": float(np.nanmean(st["mean"][0][offdiag]))
            if trig[b] >= 0 else float("nan"),
            "aoi_peak": float(np.nanmean(st["peak"][0][offdiag]))
            if trig[b] >= 0 else float("nan"),
            "aoi_max": float(st["max"][0][offdiag].max()) if trig[b] >= 0 else float("nan"),
        })
    return rows


def run_sweep(cases: list[SweepCase], *, workers: int = 1, progress: bool = True
              ) -> list[dict]:
    """Run :func:`run_case` for every case, in ``workers`` processes, with a progress bar.

    Rows come back in the order of ``cases`` (results do not depend on ``workers``).
    """
    from tqdm import tqdm

    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    rows: list[dict] = []
    bar = tqdm(total=len(cases), disable=not progress, desc="sweep", unit="case")
    if workers == 1:
        for c in cases:
            rows.extend(run_case(c))
            bar.update()
    else:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=workers) as pool:
            for r in pool.map(run_case, cases):
                rows.extend(r)
                bar.update()
    bar.close()
    return rows


def summarize(rows: list[dict]) -> list[dict]:
    """Per case (family, N, T, n, param): medians over seeds and measured/bound ratios.

    ``*_ratio`` is the median over seeds of measured / bound (1 = the bound is attained);
    runs where a quantity was not reached in the horizon (``-1``) or Assumption 1 failed
    are left out of the ratios and counted in ``not_reached`` / ``assumption1_frac``.
    """
    keys = ("family", "N", "T", "n", "param")
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    out = []
    pairs = (("trigger", "bound_lemma3", "trigger_ratio"),
             ("worst_after_lemma3", "bound_lemma5", "worst_after_lemma3_ratio"),
             ("worst_after_lemma3", "bound_index_sharp", "worst_sharp_ratio"),
             ("steps_deadbeat", "bound_corollary1", "steps_deadbeat_ratio"),
             ("steps_rho", "onset_theorem1", "steps_rho_ratio"))
    for key, rs in groups.items():
        s = dict(zip(keys, key, strict=True))
        s["runs"] = len(rs)
        s["assumption1_frac"] = float(np.mean([r["assumption1"] for r in rs]))
        s["T_used_median"] = float(np.nanmedian([r["T_used"] for r in rs])) \
            if any(np.isfinite(r["T_used"]) for r in rs) else float("nan")
        for q, b, ratio in pairs:
            ok = [r for r in rs if r[q] >= 0 and r["assumption1"]]
            vals = [r[q] for r in rs if r[q] >= 0]
            s[f"{q}_median"] = float(np.median(vals)) if vals else float("nan")
            s[f"{q}_max"] = float(np.max(vals)) if vals else float("nan")
            s[f"{b}_median"] = float(np.nanmedian([r[b] for r in rs])) \
                if any(np.isfinite(r[b]) for r in rs) else float("nan")
            s[ratio] = float(np.median([r[q] / r[b] for r in ok])) if ok \
                else float("nan")
            s[f"{q}_not_reached"] = sum(r[q] < 0 for r in rs)
        for q in ("worst_index", "messages_per_step", "adoptions_per_step", "aoi_mean",
                  "aoi_peak", "aoi_max"):
            vals = [r[q] for r in rs if np.isfinite(r[q]) and r[q] >= 0]
            s[q] = float(np.median(vals)) if vals else float("nan")
        out.append(s)
    return out


def write_csv(rows: list[dict], path) -> None:
    """Write dict rows (same keys) as CSV; floats with 6 significant digits."""
    import csv

    if not rows:
        raise ValueError("rows is empty")
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
