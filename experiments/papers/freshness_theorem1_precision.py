"""Theorem 1's noise-free floor in two precisions: is it rounding times the noise gain?

``experiments/papers/freshness_theorem1_numerics.py`` measures, with Theorem 1's gains and the plant
simulated in ``x`` coordinates, a relative error floor ``max_i ||e_i[k]|| / ||x[k]||`` over
steps 240-360 that is above 1e-12 on some plants and never above ``24 eps G`` (``G``: the
observer's noise gain, relative error per unit relative process noise). If the floor is
rounding amplified by ``G``, it must scale with the unit roundoff; an implementation defect
(a wrong index, a term left out, a model mismatch of fixed size) would not. This script:

1. **Reference.** :func:`reference_step` is the freshness observer's update (eqs. (7)-(14);
   ``netsense/observers/freshness.py`` and ``netsense/kernels``) in plain numpy, generic in
   the floating dtype: freshest strictly-fresher transmitting in-neighbour (ties to the
   smallest node id), indices ``tau_src + 1`` (sources keep 0), propagation with
   ``A_bar``'s block diagonal on the chosen estimates plus its strictly lower blocks on the
   agent's own ones (exact zeros above), and the source's correction
   ``L_j (y_j - C_bar_j z_j)`` on its own block. In float64 it is checked against
   :class:`~netsense.observers.freshness.FreshnessObserver` on the same measurements: the
   same choices and indices at every step, one step from the package's state within a few
   eps, and over a whole run a difference far below the floor.
2. **Precision.** On the plants with the highest float64 floor (and a few below 1e-12) the
   plant and the observer run in ``np.longdouble`` (x87 80-bit on x86-64, eps 1.08e-19,
   2048 times smaller than float64's). Variants (``plant / observer``):

   * ``f64``       -- the package's plant ``A``, ``C`` and design, float64 throughout
     (freshness_theorem1_numerics' setting).
   * ``ld``        -- longdouble throughout, on the plant *defined* by the design:
     ``A = T A_bar T^T``, ``C_i = C_bar_i T^T`` with ``T`` re-orthogonalised in
     longdouble (it differs from the package's ``A`` by ``~residual_A ||A||``, 1e-16
     relative): Lemma 1's structure is exact to longdouble rounding.
   * ``ld_cast``   -- longdouble throughout, the package's ``A``, ``C``, ``T`` merely cast:
     the decomposition's float64 residual ``T^T A T - A_bar`` (``residual_A ~ eps``)
     stays in as a model mismatch.
   * ``f64/ld``    -- the package's float64 plant, the observer in longdouble.
   * ``ld/f64``    -- the ``ld`` plant, the observer in float64 (measurements rounded to
     float64).

   The error is always measured in longdouble. ``G`` is freshness_theorem1_numerics'
   ``noise_gain`` (process noise ``1e-9 ||x||``, float64); the floor is compared with
   ``eps G`` of each precision.
3. **Deadbeat.** The same on freshness_theorem1_numerics' deadbeat plants (Corollary 1's gains),
   the floor being the relative error over the 50 steps after the bound
   ``n + 2N(N-1)T``.

Run: ``python experiments/papers/freshness_theorem1_precision.py`` (about 2 minutes on 2 shared
cores; ``--worst 10 --below 3`` plants of each kind). Writes, into
``experiments/results/papers/freshness_theorem1_precision/``, ``theorem1_precision.csv`` and
``theorem1_precision.png`` (its printout is ``theorem1_precision.txt``).
``tests/test_theorem1_numerics.py`` checks the reference against the package and the
longdouble floor on one plant.
"""

# %%
from __future__ import annotations

import argparse
import csv
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import freshness_theorem1_numerics as num  # noqa: E402  (a sibling script, not a package)

from netsense.graphs.bounds import corollary1_bound  # noqa: E402
from netsense.observers.freshness import FreshnessObserver  # noqa: E402
from netsense.systems.design import ObserverDesign  # noqa: E402

LD = np.longdouble
EPS64 = float(np.finfo(np.float64).eps)
EPS_LD = float(np.finfo(LD).eps)
RESULTS = (Path(__file__).resolve().parents[1] / "results" / "papers"
           / "freshness_theorem1_precision")
STEPS, START = 360, 240  # freshness_theorem1_numerics.measure_floor: steps 240-360


# ------------------------------------------------------------------------ reference
@dataclass(frozen=True)
class RefData:
    """The design's data in one dtype: what the reference observer needs."""

    A_diag: np.ndarray  # (n, n) block diagonal of A_bar
    A_lower: np.ndarray  # (n, n) strictly lower blocks of A_bar (exact zeros above)
    C_bar: tuple[np.ndarray, ...]  # C_i T, zero right of block i
    gains: tuple[np.ndarray, ...]  # L_j, (n_j, r_j)
    blocks: tuple[slice, ...]
    block_of: np.ndarray

    @classmethod
    def of(cls, design: ObserverDesign, dtype) -> RefData:
        d = design.decomposition
        return cls(d.A_diag.astype(dtype), d.A_lower.astype(dtype),
                   tuple(C.astype(dtype) for C in d.C_bar),
                   tuple(L.astype(dtype) for L in design.gains),
                   tuple(d.block(j) for j in range(d.num_agents)), d.block_of)


def freshness_sources(tau: np.ndarray, adj: np.ndarray) -> np.ndarray:
    """``src[i, j]``: whose estimate of substate ``j`` agent ``i`` propagates (eqs. (8)-(13)).

    Among the in-neighbours ``l`` (``adj[i, l]``, every agent transmits) with a finite
    index, the smallest ``tau_l^{(j)}`` (ties: smallest ``l``) is adopted iff it is
    strictly smaller than ``tau_i^{(j)}`` (omega counts as infinite).
    """
    N = tau.shape[0]
    key = np.where(tau < 0, np.inf, tau.astype(float))
    src = np.tile(np.arange(N)[:, None], (1, N))
    for i in range(N):
        nbrs = np.flatnonzero(adj[i])  # ascending node order
        if nbrs.size == 0:
            continue
        cand = key[nbrs]  # (deg, N)
        best = cand.argmin(0)  # first of equal keys: smallest node id
        adopt = cand[best, np.arange(N)] < key[i]
        src[i, adopt] = nbrs[best[adopt]]
    return src


def advance(tau: np.ndarray, src: np.ndarray) -> np.ndarray:
    """``tau_i^{(j)}[k+1] = tau_src^{(j)}[k] + 1`` (omega stays), ``tau_i^{(i)} = 0``."""
    N = tau.shape[0]
    t = tau[src, np.arange(N)[None, :]]
    out = np.where(t < 0, t, t + 1)
    out[np.arange(N), np.arange(N)] = 0
    return out


def reference_step(Z: np.ndarray, tau: np.ndarray, y: np.ndarray, adj: np.ndarray,
                   data: RefData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One step of the freshness observer in ``Z.dtype``: ``(Z[k+1], tau[k+1], src)``.

    ``Z (N, n)`` estimates in Lemma 1's coordinates, ``tau (N, N)`` int (``-1`` omega),
    ``y (N, r_max)`` padded measurements (cast to ``Z.dtype``), ``adj (N, N)`` bool.
    """
    src = freshness_sources(tau, adj)
    Z_sel = Z[src[:, data.block_of], np.arange(Z.shape[1])[None, :]]
    Z_next = Z_sel @ data.A_diag.T + Z @ data.A_lower.T  # eqs. (7), (10), (12)
    y = y.astype(Z.dtype)
    for j, (L, Cb, b) in enumerate(zip(data.gains, data.C_bar, data.blocks, strict=True)):
        if L.size:  # source j's correction, eq. (7), from its estimate at k
            Z_next[j, b] += L @ (y[j, : Cb.shape[0]] - Cb @ Z[j])
    return Z_next, advance(tau, src), src


# ---------------------------------------------------------------------------- plants
def orthogonalise(T: np.ndarray, dtype=LD, iters: int = 4) -> np.ndarray:
    """``T`` (orthogonal to float64 rounding) made orthogonal in ``dtype`` by Newton's
    polar iteration ``X <- X (3 I - X^T X) / 2`` (quadratic; numpy has no longdouble QR)."""
    X = T.astype(dtype)
    eye = np.eye(T.shape[0], dtype=dtype)
    for _ in range(iters):
        X = X @ (3 * eye - X.T @ X) / 2
    return X


@dataclass(frozen=True)
class Sim:
    """A plant in one dtype and the ``T`` that measures the error in ``z``."""

    A: np.ndarray
    C_pad: np.ndarray  # (N, r_max, n)
    T: np.ndarray  # longdouble

    def measure(self, x: np.ndarray) -> np.ndarray:
        return np.einsum("irn,n->ir", self.C_pad, x)


def package_sim(design: ObserverDesign, plant, dtype) -> Sim:
    """The package's ``A``, ``C`` (and ``T``), cast to ``dtype``."""
    return Sim(plant.A.astype(dtype), plant.C_padded.astype(dtype),
               design.decomposition.T.astype(LD))


def structured_sim(design: ObserverDesign, dtype) -> Sim:
    """The plant defined by the design: ``A = T A_bar T^T``, ``C_i = C_bar_i T^T``, with
    ``T`` orthogonal in longdouble, computed in longdouble and rounded to ``dtype``."""
    d = design.decomposition
    T = orthogonalise(d.T)
    A = T @ d.A_bar.astype(LD) @ T.T
    r_max = max([C.shape[0] for C in d.C_bar] + [1])
    C = np.zeros((d.num_agents, r_max, d.n), dtype=LD)
    for i, Cb in enumerate(d.C_bar):
        C[i, : Cb.shape[0]] = Cb.astype(LD) @ T.T
    return Sim(A.astype(dtype), C.astype(dtype), T)


def simulate(design: ObserverDesign, sim: Sim, graphs: np.ndarray, seed: int,
             obs_dtype) -> np.ndarray:
    """``max_i ||z_hat_i[k] - T^T x[k]|| / ||x[k]||``, ``k = 0..K``, in longdouble.

    The plant ``x[k+1] = A x[k]`` runs in ``sim``'s dtype, the reference observer in
    ``obs_dtype``; ``z[0]`` as freshness_theorem1_numerics draws it (``x[0] = T z[0]``),
    estimates 0.
    """
    rng = np.random.default_rng(seed)
    z0 = rng.standard_normal(design.n)
    x = (sim.T @ z0.astype(LD)).astype(sim.A.dtype)
    data = RefData.of(design, obs_dtype)
    N = design.num_agents
    Z = np.zeros((N, design.n), dtype=obs_dtype)
    tau = np.full((N, N), -1, dtype=np.int64)
    tau[np.arange(N), np.arange(N)] = 0
    K = graphs.shape[0]
    out = np.empty(K + 1, dtype=LD)
    for k in range(K + 1):
        xl = x.astype(LD)
        e = Z.astype(LD) - xl @ sim.T
        out[k] = np.sqrt((e * e).sum(-1)).max() / np.sqrt(xl @ xl)
        if k == K:
            break
        Z, tau, _ = reference_step(Z, tau, sim.measure(x), graphs[k], data)
        x = sim.A @ x
    return out


# ---------------------------------------------------------------- agreement (float64)
def _term_size(Z: np.ndarray, y: np.ndarray, data: RefData) -> float:
    """Largest size of the terms one step adds up: ``||A_bar|| ||z_i||`` and, for a source,
    ``||L_j|| (||y_j|| + ||C_bar_j|| ||z_j||)`` (rounding is relative to these, not to the
    result: the innovation ``y_j - C_bar_j z_j`` is a difference of near-equal numbers)."""
    A = np.linalg.norm(data.A_diag + data.A_lower, 2)
    size = A * float(np.linalg.norm(Z, axis=-1).max())
    for j, (L, Cb) in enumerate(zip(data.gains, data.C_bar, strict=True)):
        if L.size:
            size = max(size, float(np.linalg.norm(L, 2)) * (
                float(np.linalg.norm(y[j, : Cb.shape[0]]))
                + float(np.linalg.norm(Cb, 2) * np.linalg.norm(Z[j]))))
    return max(size, 1e-300)


def agreement(case: num.Case, *, steps: int = STEPS) -> dict:
    """The reference against ``FreshnessObserver`` in float64 on one run of the case.

    Both see the same measurements of the package's plant. ``one_step``: largest
    entry of ``reference_step(package state) - package step`` over the largest term of
    the step (:func:`_term_size`), in eps;
    ``choices_equal``: the same sources and indices at every step; ``run``: largest
    ``max_i ||z_hat_i^ref - z_hat_i^pkg|| / ||x||`` when each runs on its own.
    """
    plant, des = case.plant(), num.design(case, rho=0.5)
    graphs = case.graphs(steps)
    data = RefData.of(des, np.float64)
    rng = np.random.default_rng(case.seed)
    x = des.decomposition.to_x(rng.standard_normal(plant.n))
    obs = FreshnessObserver(des)
    Z = np.zeros((plant.num_agents, plant.n))
    tau = obs.indices
    one, run, same = 0.0, 0.0, True
    for k in range(steps):
        y = plant.measure(x)
        Zp, taup = obs.z_estimates, obs.indices
        Z1, tau1, src1 = reference_step(Zp, taup, y, graphs[k], data)
        Z, tau, _ = reference_step(Z, tau, y, graphs[k], data)
        obs.step(y, graphs[k])
        same &= bool(np.array_equal(tau1, obs.indices) and np.array_equal(src1, obs.last_source[0]))
        one = max(one, float(np.abs(Z1 - obs.z_estimates).max()) / _term_size(Zp, y, data))
        x = plant.step(x)
        run = max(run, float(np.linalg.norm(Z - obs.z_estimates, axis=-1).max()
                             / np.linalg.norm(x)))
    return {"one_step_eps": one / EPS64, "choices_equal": same, "run": run}


# ------------------------------------------------------------------------------ main
VARIANTS = {  # name: (plant: "package" | "structured", plant dtype, observer dtype)
    "f64": ("package", np.float64, np.float64),
    "ld": ("structured", LD, LD),
    "ld_cast": ("package", LD, LD),
    "f64/ld": ("package", np.float64, LD),
    "ld/f64": ("structured", LD, np.float64),
}


def floors(case: num.Case, variants=VARIANTS, *, deadbeat: bool = False) -> dict[str, float]:
    """The floor of each variant: the largest relative error over steps 240-360 with
    Theorem 1's gains, or with ``deadbeat`` gains over the 50 steps after Corollary 1's
    bound ``n + 2N(N-1)T`` (freshness_theorem1_numerics.measure_deadbeat's window); ``_late``: over
    the last 60 or 25 steps only (equal when the floor is flat)."""
    plant = case.plant()
    if deadbeat:
        des = num.design(case)
        start = int(corollary1_bound(plant.n, plant.num_agents, case.T))
        steps, late = start + 50, start + 25
    else:
        des, steps, start, late = num.design(case, rho=0.5), STEPS, START, 300
    graphs = case.graphs(steps)
    out = {}
    for name, (kind, pdt, odt) in variants.items():
        sim = package_sim(des, plant, pdt) if kind == "package" else structured_sim(des, pdt)
        rel = simulate(des, sim, graphs, case.seed, odt)
        out[name] = float(rel[start:].max())
        out[name + "_late"] = float(rel[late:].max())
    return out


def scan(count: int = 200, *, deadbeat: bool = False) -> list[tuple[num.Case, dict]]:
    """freshness_theorem1_numerics' measurement (package observer, float64) on its plants:
    ``(case, {"floor", "gain"})``; Theorem 1's floor plants, or the deadbeat plants with
    the relative error after Corollary 1's bound as the floor."""
    if not deadbeat:
        chosen, _ = num.cases(count, radius=(0.9, 1.1), offset=20_000, rho=0.5)
        return [(c, num.measure_floor(c)) for c in chosen]
    chosen, _ = num.cases(count, radius=(0.7, 1.1), offset=10_000)
    out = []
    for c in chosen:
        r = num.measure_deadbeat(c)
        out.append((c, {"floor": r["after_bound"], "gain": r["gain"]}))
    return out


def _progress(it, **kw):
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        return it
    return tqdm(it, **kw)


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.2, 4.0))
    g = np.array([r["G"] for r in rows])
    for gains, mark in (("theorem1", "o"), ("deadbeat", "^")):
        sel = np.array([r["gains"] == gains for r in rows])
        for key, eps, color, label in (("floor_f64", EPS64, "C0", "float64"),
                                       ("floor_ld", EPS_LD, "C1", "longdouble")):
            ax.loglog(eps * g[sel], [r[key] for r, s in zip(rows, sel, strict=True) if s],
                      mark, color=color, mfc="none", label=f"{label}, {gains} gains")
    lo = min(EPS_LD * g.min(), 1e-20)
    hi = max(EPS64 * g.max(), 1e-9)
    ref = np.array([lo, hi])
    ax.loglog(ref, ref, "k-", lw=0.8, label="floor = eps G")
    ax.loglog(ref, 24 * ref, "k:", lw=0.8, label="24 eps G")
    ax.axhline(1e-12, color="r", lw=0.6, ls="--", label="1e-12")
    ax.set_xlabel("eps x G (G: noise gain, theorem1_numerics)")
    ax.set_ylabel("floor: max relative error (steps 240-360 / after the bound)", fontsize=8)
    ax.set_title("Floor vs unit roundoff x noise gain, float64 and longdouble", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def study(args, *, deadbeat: bool) -> list[dict]:
    """Scan, pick the worst and a few sub-1e-12 plants, check the reference on four of
    them, and measure every variant's floor."""
    gains = "deadbeat" if deadbeat else "theorem1"
    scanned = scan(args.cases, deadbeat=deadbeat)
    order = sorted(scanned, key=lambda cr: -cr[1]["floor"])
    worst = order[: args.worst]
    under = [cr for cr in order if cr[1]["floor"] < 1e-12]
    pick = [under[round(i * (len(under) - 1) / max(args.below - 1, 1))]
            for i in range(args.below)] if args.below else []
    print(f"{gains} scan ({len(scanned)} plants, package observer, float64): floor above "
          f"1e-12 on {sum(r['floor'] > 1e-12 for _, r in scanned)}; max "
          f"{order[0][1]['floor']:.2e}")
    if not deadbeat:
        agree = [agreement(c) for c, _ in _progress(worst[:3] + pick[:1], desc="agreement")]
        print("reference vs FreshnessObserver (float64, same measurements): same choices "
              f"and indices at every step: {all(a['choices_equal'] for a in agree)}; one "
              f"step from the package's state: max "
              f"{max(a['one_step_eps'] for a in agree):.2f} eps (of the largest term); whole "
              "run: max ||z_ref - z_pkg|| / ||x|| = "
              + ", ".join(f"{a['run']:.1e}" for a in agree)
              + " (floors " + ", ".join(f"{r['floor']:.1e}" for _, r in worst[:3] + pick[:1])
              + ")")
    rows = []
    for case, r in _progress(worst + pick, desc=gains):
        f = floors(case, deadbeat=deadbeat)
        rows.append({"gains": gains, "seed": case.seed, "n": case.n, "N": case.N,
                     "T": case.T, "sources": case.sources,
                     "outputs": case.outputs or "ceil(n_j/4)",
                     "spectral_radius": round(case.spectral_radius, 4),
                     "G": r["gain"], "floor_pkg": r["floor"],
                     **{f"floor_{k.replace('/', '_')}": v for k, v in f.items()}})
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worst", type=int, default=10)
    parser.add_argument("--below", type=int, default=3)
    parser.add_argument("--cases", type=int, default=200)
    args = parser.parse_args(argv)

    rows = study(args, deadbeat=False) + study(args, deadbeat=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / "theorem1_precision.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for row in rows:
            w.writerow({k: (f"{v:.3e}" if isinstance(v, float) else v) for k, v in row.items()})
    plot(rows, RESULTS / "theorem1_precision.png")

    print(f"eps: float64 {EPS64:.3e}, longdouble {EPS_LD:.3e} (ratio {EPS64 / EPS_LD:.0f}); "
          "floors: f64 = the package's plant, float64; ld = longdouble throughout (exact "
          "structure); ld_cast = longdouble, the package's A and T cast; pl64/obsld = "
          "float64 plant, longdouble observer; plld/obs64 = longdouble plant, float64 "
          "observer")
    head = (f"{'gains':>8} {'seed':>6} {'n':>3} {'N':>3} {'T':>2} {'src':>3} {'G':>8} "
            f"{'eps64 G':>8} {'f64':>8} {'ld':>8} {'f64/ld':>7} {'eps_ld G':>8} "
            f"{'ld_cast':>8} {'pl64/obsld':>10} {'plld/obs64':>10}")
    print(head)
    for r in rows:
        print(f"{r['gains']:>8} {r['seed']:>6} {r['n']:>3} {r['N']:>3} {r['T']:>2} "
              f"{r['sources']:>3} {r['G']:8.1e} {EPS64 * r['G']:8.1e} {r['floor_f64']:8.1e} "
              f"{r['floor_ld']:8.1e} {r['floor_f64'] / r['floor_ld']:7.0f} "
              f"{EPS_LD * r['G']:8.1e} {r['floor_ld_cast']:8.1e} {r['floor_f64_ld']:10.1e} "
              f"{r['floor_ld_f64']:10.1e}")
    print(f"wrote {path} and {path.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
