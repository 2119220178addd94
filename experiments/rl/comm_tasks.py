"""The communication tasks' scripted frontier with every decentralised family, the rules
that read the newer tasks' extra fields, and what that information is worth.

``python experiments/rl/comm_tasks.py --workers 2`` (all tasks, 100 protocol episodes;
``--scenarios``/``--episodes`` shrink it) writes into
``experiments/results/rl/comm_tasks/``:

1. **Frontier** of each scenario (:func:`netsense.benchmark.protocol.run_frontier`: every
   family of :data:`netsense.benchmark.protocol.FAMILIES` at each knob, ``always`` and
   ``never``, and over each base rule of :data:`netsense.benchmark.protocol.INFORMED_BASES`
   the rules that use a task's extra information; seeds ``10^6 .. 10^6 + episodes - 1``):
   ``frontier_<scenario>.csv/.png``, ``frontier.csv``, ``frontier.md``. Those rules:

   * *informed* (kind ``decentralised``; :mod:`netsense.env.comm_informed`), reading only
     the agent's own observation history: ``gated`` (``comm_announced``: transmit only when
     the announced next graph gives the agent an out-neighbour, field ``next_out``),
     ``acked`` (``comm_fading``: stay silent while the last transmission that had
     out-links was lost, probe every 6 steps; field ``acks``), ``phased``
     (``comm_schedule``: remember, per phase ``k mod P`` of the schedule, whether the last
     transmission at that phase had out-links; field ``acks``), on every task whose
     observation carries the field;
   * *privileged* (kind ``privileged``; :mod:`netsense.env.comm_privileged`), reading what
     no agent can: ``oracle`` gates on whether the next message reaches anyone (the
     out-links of ``G[k+1]`` and the arrivals of step ``k + 1``), on every task;
     ``oracle_channel`` on the arrivals alone (the sender's fading state at ``k + 1``),
     where messages can be dropped.

2. **Summary** (``summary.csv``, ``summary.md``) per scenario: the best decentralised
   point (of every decentralised row, informed rules included), the best of the older
   families and of the families added with the newer tasks, the best informed rule with
   the paired 95 % bootstrap interval of its gain over the best uninformed decentralised
   point (per-seed differences), the best privileged rule with its gain over the best
   decentralised point, and the best centralised scheduler.
"""

# %%
from __future__ import annotations

import argparse
import csv
import math
import pickle
from pathlib import Path

from netsense.benchmark.intervals import bootstrap_ci
from netsense.benchmark.kinds import INFORMED_FAMILIES
from netsense.benchmark.protocol import DEFAULT_EPISODES, run_frontier

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments/results/rl/comm_tasks"
OLD_TASKS = ("comm_process_noise-v0", "comm_substates-v0", "comm_channel_k2-v0",
             "message_cost-v0", "message_cost-v1")
NEW_TASKS = ("comm_announced-v0", "comm_fading-v0", "comm_schedule-v0", "comm_schedule-v1")
#: Families of the frontier before these tasks (the others were added with them).
OLD_FAMILIES = ("always", "never", "periodic", "bernoulli", "sources", "event")


# %% summary
def _best(rows, keep) -> dict | None:
    rows = [r for r in rows if keep(r)]
    return max(rows, key=lambda r: r["reward_mean"]) if rows else None


def summarise(scenario: str, rows: list[dict]) -> list[dict]:
    """Best decentralised point (every decentralised row; the older families; the added
    families), best informed rule, best privileged rule, best centralised scheduler; the
    informed and privileged rules with the paired interval of their gain (per-seed
    differences of the frontier rows' returns)."""
    def dec(r):
        return r["kind"] == "decentralised"

    best = _best(rows, dec)
    uninformed = _best(rows, lambda r: dec(r) and r["family"] not in INFORMED_FAMILIES)
    picks = [("best decentralised", best, None),
             ("best older family", _best(rows, lambda r: r["family"] in OLD_FAMILIES), None),
             ("best added family", _best(rows, lambda r: dec(r) and r["family"] not in
                                         OLD_FAMILIES and r["family"] not in
                                         INFORMED_FAMILIES), None),
             ("best informed", _best(rows, lambda r: r["family"] in INFORMED_FAMILIES),
              uninformed),
             ("best privileged", _best(rows, lambda r: r["kind"] == "privileged"), best),
             ("best centralised", _best(rows, lambda r: r["kind"] == "centralised"), None)]
    out = []
    for what, r, ref in picks:
        if r is None:
            continue
        row = {"scenario": scenario, "what": what, "kind": r["kind"], "policy": r["policy"],
               "reward_mean": r["reward_mean"], "reward_ci_low": r["reward_ci_low"],
               "reward_ci_high": r["reward_ci_high"], "error": r["mean_rel_error_mean"],
               "msgs": r["msgs_per_agent_step_mean"], "gain_over": "", "gain": "",
               "gain_ci_low": "", "gain_ci_high": "", "gain_pct": ""}
        if ref is not None:
            gain, glo, ghi = bootstrap_ci(r["values"]["reward"] - ref["values"]["reward"])
            row.update(gain_over=ref["policy"], gain=gain, gain_ci_low=glo, gain_ci_high=ghi,
                       gain_pct=100 * gain / abs(ref["reward_mean"]))
        out.append(row)
    return out


def _fmt(v, digits=4) -> str:
    if isinstance(v, float):
        return "nan" if not math.isfinite(v) else f"{v:.{digits}g}"
    return str(v)


def write_summary(summary: list[dict], out: Path) -> None:
    cols = list(summary[0])
    with (out / "summary.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in summary:
            w.writerow([_fmt(r[c], 6) for c in cols])
    lines = ["| scenario | what | kind | policy | return [95 % CI] | error | "
             "msgs / agent-step | gain [paired 95 % CI] over |",
             "|---|---|---|---|---|---|---|---|"]
    for r in summary:
        gain = ("" if r["gain"] == "" else f"{r['gain']:+.1f} [{r['gain_ci_low']:+.1f}, "
                f"{r['gain_ci_high']:+.1f}] ({r['gain_pct']:+.1f} %) over "
                f"`{r['gain_over']}`")
        lines.append(f"| {r['scenario']} | {r['what']} | {r['kind']} | `{r['policy']}` | "
                     f"{r['reward_mean']:.1f} [{r['reward_ci_low']:.1f}, "
                     f"{r['reward_ci_high']:.1f}] | {r['error']:.3f} | {r['msgs']:.3f} | "
                     f"{gain} |")
    (out / "summary.md").write_text("\n".join(lines) + "\n")


# %%
def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=list(OLD_TASKS + NEW_TASKS))
    ap.add_argument("--episodes", type=int, default=DEFAULT_EPISODES)
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--horizon", type=int, default=None,
                    help="override the scenarios' horizon (smoke runs)")
    ap.add_argument("--workers", type=int, default=1,
                    help="run the scenarios in this many processes")
    ap.add_argument("--save-rows", type=Path, default=None, metavar="FILE",
                    help="also pickle the frontier rows (with their per-episode values) into "
                         "FILE, for experiments/rl/comm_bounds.py --frontier-rows")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    over = {} if args.horizon is None else {"horizon": args.horizon}
    rows = run_frontier(args.scenarios, args.out, episodes=args.episodes, overrides=over,
                        progress=not args.no_progress, workers=args.workers)
    if args.save_rows is not None:
        with args.save_rows.open("wb") as fh:
            pickle.dump(rows, fh)
    summary = []
    for sc in dict.fromkeys(args.scenarios):
        summary += summarise(sc, [r for r in rows if r["scenario"] == sc])
    write_summary(summary, args.out)
    print((args.out / "summary.md").read_text())
    return summary


if __name__ == "__main__":
    main()
