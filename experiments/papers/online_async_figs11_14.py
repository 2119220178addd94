"""Section VII of the asynchronous paper: OASE vs an asynchronous WLS on the IEEE 37 feeder.

State: the 6B = 210 delta power injections of the feeder (B = 35 buses; our own data,
``netsense/grid/data/ieee37.json``). Every second each injection changes by a truncated
Gaussian relative step of standard deviation 0.0068 (relative to its current value, so
loads keep their sign). Smart meters (|v|, p, q; hourly; 0.5 % max error) sit on every bus
except a few PMU buses (Re v, Im v, |v|, p, q; every minute; 0.05 %); every meter has its
own random report phase. Measurements follow the linear model (eq. (44)) with the known
zero-load offset handled as Remark 1's ``b``.

Estimators, both started from the flat estimate x_hat(0) = 0:

* OASE, eqs. (47)-(48), for several inertia parameters gamma;
* WLS adapted to asynchronous data: every meter's latest reading is held and, at each
  report, the weighted least-squares fit of all held readings is recomputed (minimum-norm,
  singular values below 1e-9 of the largest cut, while some meters have not reported).

Outputs: analogues of Fig. 11 (OASE power-injection error for several gamma), Fig. 12
(power-injection error, WLS vs OASE), Fig. 13 (voltage error, WLS vs OASE) and Fig. 14
(one injection over time). The paper's text on the comparison is truncated and its
figures give no numbers, so only the qualitative claim (OASE beats WLS) can be compared.

Run: ``python experiments/papers/online_async_figs11_14.py`` (``--runs 5 --hours 1.5`` for a
quick look).
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

from netsense.estimators.online import ose_step  # noqa: E402
from netsense.grid import linearize, load_ieee37  # noqa: E402
from netsense.grid.meters import PMU, SMART_METER, GridMetering, truncated_normal  # noqa: E402

RESULTS = Path(__file__).resolve().parents[1] / "results" / "papers" / "online_async_figs11_14"

PMU_BUSES = ("701", "702", "703", "709", "734", "711")
REL_STEP = 0.0068
GAMMAS = (1e2, 1e3, 1e4, 1e5, 1e6)


# %% setup
def build(seed: int):
    f = load_ieee37()
    lp = linearize(f)
    x_nom = f.nominal_injections()
    rng = np.random.default_rng(seed)
    meters, phases = [], []
    for i, bus in enumerate(f.buses):
        spec = PMU if bus in PMU_BUSES else SMART_METER
        meters.append((i, spec))
        phases.append(int(rng.integers(0, spec.period_s)))
    gm = GridMetering(lp, tuple(meters), tuple(phases), x_ref=x_nom)
    return f, lp, x_nom, gm


class HeldWLS:
    """WLS on every meter's latest reading (weights from the meters' variances)."""

    def __init__(self, gm: GridMetering, R: int) -> None:
        self.sens = gm.sensing()
        self.A = self.sens.A_full
        self.b = self.sens.b_full
        self.w = 1.0 / np.sqrt(np.diag(self.sens.Q_full))
        self.y = np.zeros((R, self.A.shape[0]))
        self.seen = np.zeros(len(self.sens.sensors), dtype=bool)
        self.K = None

    def update(self, reported: np.ndarray, y_rep: np.ndarray) -> np.ndarray:
        rows = self.sens.row_mask(reported)
        self.y[:, rows] = y_rep
        if self.K is None or (reported & ~self.seen).any():
            # the weighted pseudo-inverse only changes when a meter reports for the first
            # time; singular values below 1e-9 of the largest are cut (minimum-norm fit
            # while some meters are still silent; the default cutoff keeps round-off
            # directions and blows up)
            self.seen |= reported
            self.r = self.sens.row_mask(self.seen)
            Aw = self.A[self.r] * self.w[self.r, None]
            self.K = np.linalg.pinv(Aw, rcond=1e-9) * self.w[self.r]
        return (self.y[:, self.r] - self.b[self.r]) @ self.K.T


# %% simulation
def run(args):
    f, lp, x_nom, gm = build(args.seed)
    sens = gm.sensing()
    R, T = args.runs, int(args.hours * 3600)
    pattern = gm.arrivals.schedule(T + 1)
    rng = np.random.default_rng(args.seed + 1)
    x = np.tile(x_nom, (R, 1))
    xh = np.zeros((len(GAMMAS), R, x.shape[1]))
    wls = HeldWLS(gm, R)
    xw = np.zeros_like(x)
    every = args.record_every
    rec_t, e_p, e_v, trace = [], [], [], []
    track = 3 * f.buses.index("701") + 2                # p_ca at bus 701
    cache = {}
    for t in tqdm(range(1, T + 1), desc="seconds", leave=False):
        x = x * (1.0 + REL_STEP * truncated_normal(rng, x.shape))
        rep = pattern[t]
        if rep.any():
            ids = np.flatnonzero(rep)
            key = tuple(ids)
            if key not in cache:
                A, Q, b = sens.stack(rep)
                cache[key] = (A, np.diag(Q).copy(), b)
            A, q, b = cache[key]
            y = gm.measure(x, ids, rng)
            for g, gamma in enumerate(GAMMAS):
                xh[g] = ose_step(xh[g], y, A, gamma, q, b)
            xw = wls.update(rep, y)
        if t % every == 0:
            est = np.concatenate([xh, xw[None]])                   # (G+1, R, N)
            ep = np.linalg.norm(est - x, axis=2) / np.linalg.norm(x, axis=1)
            v_true = lp.voltages(x)
            ev = np.abs(lp.voltages(est) - v_true).mean(axis=2)    # mean over nodes
            rec_t.append(t)
            e_p.append(ep.mean(axis=1))
            e_v.append(ev.mean(axis=1))
            trace.append(np.concatenate([[x[0, track]], est[:, 0, track]]))
    return (f, np.array(rec_t), np.array(e_p), np.array(e_v), np.array(trace),
            int(pattern.sum()))


# %% main
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=20, help="Monte Carlo runs")
    p.add_argument("--hours", type=float, default=4.0, help="simulated time (1 step = 1 s)")
    p.add_argument("--record-every", type=int, default=10, help="seconds between records")
    p.add_argument("--seed", type=int, default=37)
    p.add_argument("--out", type=Path, default=RESULTS)
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    f, tt, e_p, e_v, trace, n_reports = run(args)
    names = [f"oase_gamma_{g:g}" for g in GAMMAS] + ["wls_held"]

    # %% write CSV
    for fname, data, what in (("grid_power_error.csv", e_p, "rel_power_err"),
                              ("grid_voltage_error.csv", e_v, "mean_abs_v_err_pu")):
        with open(args.out / fname, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["t_s"] + [f"{what}_{n}" for n in names])
            for t, row in zip(tt, data, strict=True):
                w.writerow([int(t)] + [f"{v:.6g}" for v in row])

    # %% figures
    hrs = tt / 3600.0
    last = tt > tt[-1] - 3600                            # final hour
    ss_p, ss_v = e_p[last].mean(axis=0), e_v[last].mean(axis=0)
    best = int(np.argmin(ss_p[:-1]))
    fig, ax = plt.subplots(2, 2, figsize=(12, 8))
    for g in range(len(GAMMAS)):
        ax[0, 0].semilogy(hrs, e_p[:, g], label=f"OASE γ={GAMMAS[g]:g}")
    ax[0, 0].set(title="Fig. 11 analogue: OASE power-injection error", xlabel="time [h]",
                 ylabel="mean ‖x̂−x‖/‖x‖")
    ax[0, 0].legend(fontsize=8)
    ax[0, 1].semilogy(hrs, e_p[:, -1], label="WLS (held readings)")
    ax[0, 1].semilogy(hrs, e_p[:, best], label=f"OASE γ={GAMMAS[best]:g}")
    ax[0, 1].set(title="Fig. 12 analogue: power-injection error", xlabel="time [h]",
                 ylabel="mean ‖x̂−x‖/‖x‖")
    ax[0, 1].legend()
    ax[1, 0].semilogy(hrs, e_v[:, -1], label="WLS (held readings)")
    ax[1, 0].semilogy(hrs, e_v[:, best], label=f"OASE γ={GAMMAS[best]:g}")
    ax[1, 0].set(title="Fig. 13 analogue: voltage error", xlabel="time [h]",
                 ylabel="mean |v̂−v| [pu]")
    ax[1, 0].legend()
    S = f.s_base_kva
    ax[1, 1].plot(hrs, -trace[:, 0] * S, "k", lw=2, label="true")
    ax[1, 1].plot(hrs, -trace[:, 1 + best] * S, label=f"OASE γ={GAMMAS[best]:g}")
    ax[1, 1].plot(hrs, -trace[:, -1] * S, label="WLS")
    ax[1, 1].set(title="Fig. 14 analogue: load P_ca at bus 701, run 0", xlabel="time [h]",
                 ylabel="kW")
    ax[1, 1].legend()
    fig.tight_layout()
    fig.savefig(args.out / "grid_oase_vs_wls.png", dpi=120)
    plt.close(fig)

    # %% summary
    print(f"IEEE 37: {f.B} buses, {6 * f.B} states; {len(PMU_BUSES)} PMUs (60 s), "
          f"{f.B - len(PMU_BUSES)} smart meters (3600 s); {n_reports} reports in "
          f"{args.hours:g} h; {args.runs} runs")
    print("final-hour averages: relative power-injection error, mean |v error| [pu]")
    for n, a, b in zip(names, ss_p, ss_v, strict=True):
        print(f"  {n:<22s} {a:.4f}  {b:.2e}")
    print(f"best OASE gamma = {GAMMAS[best]:g}: power error {ss_p[best]:.4f} vs WLS "
          f"{ss_p[-1]:.4f} (ratio {ss_p[-1] / ss_p[best]:.2f}); voltage error "
          f"{ss_v[best]:.2e} vs {ss_v[-1]:.2e} pu (ratio {ss_v[-1] / ss_v[best]:.2f})")
    print("paper: OASE below WLS in Figs. 12-13 (no numbers given)")
    print(f"wrote {args.out}/grid_*.csv/png in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
