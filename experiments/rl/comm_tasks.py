"""The communication tasks' scripted frontier with every decentralised family, and what the
new tasks' extra information is worth.

``python experiments/rl/comm_tasks.py`` (all tasks, 100 protocol episodes; 10 minutes
measured on one core with the other busy; ``--scenarios``/``--episodes`` shrink it) writes
into ``experiments/results/rl/comm_tasks/``:

1. **Frontier** of each scenario (:func:`netsense.benchmark.protocol.run_frontier`: every
   family of :data:`netsense.benchmark.protocol.FAMILIES` at each knob, ``always`` and
   ``never``; seeds ``10^6 .. 10^6 + episodes - 1``): ``frontier_<scenario>.csv/.png``,
   ``frontier.csv``, ``frontier.md``.
2. **Rules that use a task's extra information** (the new tasks only), on the same seeds
   with the same metrics, each over the base rules :data:`BASES`:

   * *informed* -- decentralised, reading only the agent's own observation history, but
     written for the task (so not part of the frontier): ``gated`` (``comm_announced``:
     transmit only when the announced next graph gives the agent an out-neighbour,
     field ``next_out``), ``acked`` (``comm_fading``: stay silent while the last
     transmission that had out-links was lost, probe every :data:`PROBE` steps; field
     ``acks``), ``phased`` (``comm_schedule``: remember, per phase ``k mod P`` of the
     schedule, whether the last transmission at that phase had out-links; field ``acks``);
   * *privileged* -- reads what no agent can: ``oracle`` gates on whether the next message
     reaches anyone (the out-links of ``G[k+1]`` and, with link drops, the arrivals of
     step ``k + 1``), ``oracle_channel`` on the arrivals alone (the sender's fading
     state at ``k + 1``).

   It shows that the information is worth something; the calibration of a task is the
   gap between the causal bound and the best decentralised frontier point.
3. **Summary** (``summary.csv``, ``summary.md``) per scenario: the best decentralised
   point of the frontier (and whether a family added with these tasks is the best, by how
   much over the best of the older families), the centralised schedulers, and for the
   new tasks the best informed and privileged rule with the paired 95 % bootstrap
   interval of its gain over the best decentralised point (per-seed differences).
"""

# %%
from __future__ import annotations

import argparse
import copy
import csv
import math
from pathlib import Path

import numpy as np

from netsense.benchmark.protocol import (
    DEFAULT_EPISODES,
    bootstrap_ci,
    eval_seeds,
    evaluate,
    frontier_overrides,
    run_frontier,
)
from netsense.env.comm_policies import CENTRALISED, make_comm_policy

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments/results/rl/comm_tasks"
OLD_TASKS = ("comm_process_noise-v0", "comm_substates-v0", "comm_channel_k2-v0",
             "message_cost-v0", "message_cost-v1")
NEW_TASKS = ("comm_announced-v0", "comm_fading-v0", "comm_schedule-v0", "comm_schedule-v1")
#: Families of the frontier before these tasks (the others were added with them).
OLD_FAMILIES = ("always", "never", "periodic", "bernoulli", "sources", "event")
#: Base rules the informed and privileged rules gate.
BASES = ("always", "sources:0", "event:1", "event:2", "event:3", "event:4", "until:40")
#: Steps after which ``acked`` probes a channel it believes bad.
PROBE = 6
#: Informed (decentralised) rule of each new task; ``oracle`` rules run on all of them.
INFORMED = {"comm_announced-v0": "gated", "comm_fading-v0": "acked",
            "comm_schedule-v0": "phased", "comm_schedule-v1": "phased"}


# %% rules that use a task's extra information
class Gated:
    """Base bits where the announced ``G[k+1]`` gives the agent an out-neighbour."""

    def __init__(self, core, base):
        self.L, self.base = core.layout, base

    def __call__(self, obs, mask):
        return self.base(obs, mask) * (obs[..., self.L.next_out].sum(-1, keepdims=True) > 0)


class Acked:
    """Base bits unless the agent's last transmission that had out-links was lost on all
    of them (its channel is bad); after ``PROBE`` silent steps it tries again."""

    def __init__(self, core, base):
        self.L, self.base = core.layout, base
        self.ok = np.ones((core.B, core.N), bool)
        self.since = np.zeros((core.B, core.N), np.int64)

    def __call__(self, obs, mask):
        acks = obs[..., self.L.acks]
        seen = (obs[..., self.L.silence.start] == 0) & (acks != 0).any(-1)
        self.ok = np.where(seen, (acks > 0).any(-1), self.ok)
        self.since = np.where(seen, 0, self.since + 1)
        return self.base(obs, mask) * (self.ok | (self.since >= PROBE))[..., None]


class Phased:
    """Base bits where the agent's last transmission at the phase ``(k + 1) mod P`` of the
    periodic schedule had out-links (unknown phases: transmit)."""

    def __init__(self, core, base):
        self.L, self.base, self.H = core.layout, base, core.horizon
        self.P = len(core.model.graphs.graphs)
        self.table = np.ones((core.B, core.N, self.P), bool)

    def __call__(self, obs, mask):
        L = self.L
        k = np.rint(obs[:, 0, L.time.start] * self.H).astype(np.int64)
        b, i = np.nonzero(obs[..., L.silence.start] == 0)
        self.table[b, i, k[b] % self.P] = (obs[..., L.acks] != 0).any(-1)[b, i]
        nxt = self.table[np.arange(k.size), :, (k + 1) % self.P]
        return self.base(obs, mask) * nxt[..., None]


class Oracle:
    """Privileged: base bits where the next message reaches someone (``channel=False``:
    an out-link of ``G[k+1]`` whose message of step ``k + 1`` arrives) or where the
    sender's channel delivers at ``k + 1`` (``channel=True``)."""

    def __init__(self, core, base, channel: bool = False):
        self.core, self.base, self.channel = core, base, channel

    def next_arrivals(self) -> np.ndarray:
        """``(B, N, N)`` arrivals of step ``k + 1`` (``[b, i, l]``: link ``l -> i``), from
        the chunk or a peek at a copy of the member's arrival sampler."""
        c = self.core
        if c.buf_msg is None:
            return np.ones((c.B, c.N, c.N), bool)
        out = np.empty((c.B, c.N, c.N), bool)
        for b in range(c.B):
            p = int(c.ptr[b]) + 1
            out[b] = c.buf_msg[b, p] if p < c.chunk else copy.deepcopy(c.msg_sampler[b]).next()
        return out

    def __call__(self, obs, mask):
        c = self.core
        arrive = self.next_arrivals()
        if self.channel:
            ok = arrive.any(1)  # the sender's message arrives somewhere if it had links
        else:
            links = np.zeros((c.B, c.N, c.N), bool)  # [b, i, l]: l -> i in G[k+1]
            b, i, d = np.nonzero(c.nbr_next >= 0)
            links[b, i, c.nbr_next[b, i, d]] = True
            ok = (links & arrive).any(1)
        return self.base(obs, mask) * ok[..., None]


RULES = {"gated": Gated, "acked": Acked, "phased": Phased, "oracle": Oracle,
         "oracle_channel": lambda core, base: Oracle(core, base, channel=True)}


def rule_actor(rule: str, base: str):
    """``(core, seeds) -> act`` of ``rule`` on the base rule ``base`` (for
    :func:`netsense.benchmark.protocol.evaluate`)."""
    def build(core, seeds):
        return RULES[rule](core, make_comm_policy(base, core, seed=list(seeds)).act)
    return build


def rule_overrides(scenario: str, rule: str, overrides: dict | None = None) -> dict:
    """The oracle reads ``G[k+1]`` from the core's announced next graph: announce it (this
    changes no realisation, only the observation, which the rules do not read for it)."""
    over = frontier_overrides(scenario, overrides)
    if rule == "oracle":
        over = {**over, "control": {**over.get("control", {}), "announce": True}}
    return over


# %% summary
def _best(rows, keep) -> dict | None:
    rows = [r for r in rows if keep(r)]
    return max(rows, key=lambda r: r["reward_mean"]) if rows else None


def summarise(scenario: str, rows: list[dict], seeds: list[int],
              overrides: dict | None = None) -> list[dict]:
    """Best decentralised point (all families, older families, added families), best
    centralised scheduler, and for a new task the best informed and privileged rules
    with the paired interval of their gain over the best decentralised point."""
    dec = _best(rows, lambda r: r["family"] not in CENTRALISED)
    old = _best(rows, lambda r: r["family"] in OLD_FAMILIES)
    new = _best(rows, lambda r: r["family"] not in OLD_FAMILIES + CENTRALISED)
    cen = _best(rows, lambda r: r["family"] in CENTRALISED)
    out = [{"scenario": scenario, "what": what, "policy": r["policy"],
            "reward_mean": r["reward_mean"], "reward_ci_low": r["reward_ci_low"],
            "reward_ci_high": r["reward_ci_high"], "error": r["mean_rel_error_mean"],
            "msgs": r["msgs_per_agent_step_mean"], "gain": "", "gain_ci_low": "",
            "gain_ci_high": "", "gain_pct": ""}
           for what, r in (("best decentralised", dec), ("best older family", old),
                           ("best added family", new), ("best centralised", cen))
           if r is not None]
    if scenario not in NEW_TASKS:
        return out
    ref = evaluate(scenario, dec["policy"], seeds,
                   frontier_overrides(scenario, overrides))["reward"]
    for kind, rule in (("informed", INFORMED[scenario]), ("privileged", "oracle"),
                       ("privileged", "oracle_channel")):
        if rule == "oracle_channel" and scenario != "comm_fading-v0":
            continue
        best = None
        for base in BASES:
            m = evaluate(scenario, f"{rule}({base})", seeds,
                         rule_overrides(scenario, rule, overrides), actor=rule_actor(rule, base))
            if best is None or m["reward"].mean() > best[1]["reward"].mean():
                best = (f"{rule}({base})", m)
        name, m = best
        mean, lo, hi = bootstrap_ci(m["reward"])
        gain, glo, ghi = bootstrap_ci(m["reward"] - ref)
        out.append({"scenario": scenario, "what": f"{kind}: {rule}", "policy": name,
                    "reward_mean": mean, "reward_ci_low": lo, "reward_ci_high": hi,
                    "error": float(m["mean_rel_error"].mean()),
                    "msgs": float(m["msgs_per_agent_step"].mean()), "gain": gain,
                    "gain_ci_low": glo, "gain_ci_high": ghi,
                    "gain_pct": 100 * gain / abs(dec["reward_mean"])})
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
    lines = ["| scenario | what | policy | return [95 % CI] | error | msgs / agent-step | "
             "gain over best decentralised [paired 95 % CI] |", "|---|---|---|---|---|---|---|"]
    for r in summary:
        gain = ("" if r["gain"] == "" else f"{r['gain']:+.1f} [{r['gain_ci_low']:+.1f}, "
                f"{r['gain_ci_high']:+.1f}] ({r['gain_pct']:+.1f} %)")
        lines.append(f"| {r['scenario']} | {r['what']} | `{r['policy']}` | "
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
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    seeds = eval_seeds(args.episodes)
    over = {} if args.horizon is None else {"horizon": args.horizon}
    rows = run_frontier(args.scenarios, args.out, episodes=args.episodes, overrides=over,
                        progress=not args.no_progress)
    summary = []
    for sc in dict.fromkeys(args.scenarios):
        summary += summarise(sc, [r for r in rows if r["scenario"] == sc], seeds, over)
    write_summary(summary, args.out)
    print((args.out / "summary.md").read_text())
    return summary


if __name__ == "__main__":
    main()
