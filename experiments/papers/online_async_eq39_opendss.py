"""Validate the linear power-flow model (eq. (39)) of the IEEE 37-node feeder against OpenDSS.

The feeder data are ours (``netsense/grid/data/ieee37.json``); the OpenDSS script is
generated from them (``netsense.grid.opendss``) and solved with ``opendssdirect.py``. For a
range of load levels (multiples of the nominal spot loads) and random load profiles we
report the linear model's voltage error against OpenDSS, and the agreement of our own
nonlinear solver with OpenDSS (a check of the admittance matrix and of the script).

Run: ``python experiments/papers/online_async_eq39_opendss.py`` (needs
``pip install netsense[grid]``).
"""

# %% imports
from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from netsense.grid import linearize, load_ieee37, solve_power_flow  # noqa: E402
from netsense.grid.opendss import solve_opendss  # noqa: E402

RESULTS = Path(__file__).resolve().parents[1] / "results" / "papers" / "online_async_eq39_opendss"


# %% main
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=50, help="random load profiles")
    p.add_argument("--seed", type=int, default=37)
    p.add_argument("--out", type=Path, default=RESULTS)
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    f = load_ieee37()
    lp = linearize(f)
    x_nom = f.nominal_injections()
    rows = []
    levels = [0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5]
    for a in levels:
        x = a * x_nom
        v_dss = solve_opendss(f, x)
        v_own = solve_power_flow(f, x)
        v_lin = lp.voltages(x)
        rows.append(["scaled", a, float(np.abs(v_dss).min()),
                     float(np.abs(v_lin - v_dss).max()),
                     float(np.abs(np.abs(v_lin) - np.abs(v_dss)).max()),
                     float(np.abs(np.abs(lp.w) + lp.K @ x - np.abs(v_dss)).max()),
                     float(np.abs(v_lin - v_dss).mean()),
                     float(np.abs(v_own - v_dss).max())])
    rng = np.random.default_rng(args.seed)
    for _ in tqdm(range(args.runs), desc="random profiles", leave=False):
        x = x_nom * rng.uniform(0.5, 1.5, x_nom.shape)
        v_dss = solve_opendss(f, x)
        v_own = solve_power_flow(f, x)
        v_lin = lp.voltages(x)
        rows.append(["random", 1.0, float(np.abs(v_dss).min()),
                     float(np.abs(v_lin - v_dss).max()),
                     float(np.abs(np.abs(v_lin) - np.abs(v_dss)).max()),
                     float(np.abs(np.abs(lp.w) + lp.K @ x - np.abs(v_dss)).max()),
                     float(np.abs(v_lin - v_dss).mean()),
                     float(np.abs(v_own - v_dss).max())])
    header = ["profile", "load_scale", "min_abs_v_dss_pu", "max_abs_complex_err_pu",
              "max_abs_mag_of_linear_v_err_pu", "max_abs_K_mag_err_pu",
              "mean_abs_complex_err_pu", "own_nonlinear_vs_dss_max_pu"]
    with open(args.out / "grid_linear_validation.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for r in rows:
            w.writerow([r[0]] + [f"{v:.6g}" for v in r[1:]])

    # %% figure: per-node voltage magnitudes at nominal load
    v_dss = solve_opendss(f, x_nom)
    v_lin = lp.voltages(x_nom)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    ax[0].plot(np.abs(v_dss), "o", ms=4, label="OpenDSS (nonlinear)")
    ax[0].plot(np.abs(lp.w) + lp.K @ x_nom, "x", ms=4, label="linear |w| + K x")
    ax[0].set(xlabel="node (bus x phase)", ylabel="|v| [pu]",
              title="IEEE 37, nominal load, no regulator")
    ax[0].legend()
    sc = [r[1] for r in rows if r[0] == "scaled"]
    ax[1].loglog(sc[1:], [r[3] for r in rows if r[0] == "scaled"][1:], "o-",
                 label="max |v_lin - v_dss|")
    ax[1].loglog(sc[1:], [r[5] for r in rows if r[0] == "scaled"][1:], "s-",
                 label="max ||w|+Kx - |v_dss||")
    ax[1].set(xlabel="load scale (x nominal)", ylabel="error [pu]",
              title="linear model error vs loading")
    ax[1].legend()
    fig.tight_layout()
    fig.savefig(args.out / "grid_linear_validation.png", dpi=120)
    plt.close(fig)

    # %% summary
    nom = rows[levels.index(1.0)]
    rnd = np.array([r[3] for r in rows if r[0] == "random"])
    print(f"IEEE 37 (B = {f.B} buses, 6B = {6 * f.B} states); zero-load profile |w| in "
          f"[{np.abs(lp.w).min():.6f}, {np.abs(lp.w).max():.6f}] pu")
    print(f"zero load: max |w - v_dss| = {rows[0][3]:.2e} pu")
    print(f"nominal load: min |v| = {nom[2]:.4f} pu, linear model max complex error "
          f"{nom[3]:.2e} pu, max magnitude error (K) {nom[5]:.2e} pu, mean {nom[6]:.2e} pu; "
          f"own nonlinear solver vs OpenDSS {nom[7]:.1e} pu")
    for r in rows:
        if r[0] == "scaled":
            print(f"  scale {r[1]:4.2f}: min|v|={r[2]:.4f}  max|dv|={r[3]:.2e}  "
                  f"max|d|v||={r[5]:.2e}")
    print(f"random profiles (0.5-1.5 x nominal per phase, {args.runs}): max complex error "
          f"median {np.median(rnd):.2e}, worst {rnd.max():.2e} pu")
    print("paper: no voltage error of the linear model is reported (it cites ref. [26])")
    print(f"wrote {args.out}/grid_linear_validation.* in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
