"""Learned communication against the scripted frontier, on every message-cost and
shared-channel scenario.

One command trains, evaluates and summarises (``python experiments/rl/learned_comm.py``;
about an hour on 2 cores, most of it training; ``--skip-train`` re-evaluates the committed
policies, ``--scenarios``/``--seeds``/``--steps``/``--episodes`` shrink it):

1. **Scripted frontier.** The protocol of :mod:`netsense.benchmark.protocol` (100 episodes,
   seeds 1000000-1000099, 95 % bootstrap intervals): every baseline of
   :mod:`netsense.env.comm_policies` at each knob, ``always`` (= the freshness observer) and
   ``never``, in the scenario's communication-only mode.
2. **Training** (``experiments/rl/configs/learned_comm.toml``), for each scenario, each
   variant and each seed: batched MAPPO (:func:`netsense.rl.ppo.train_ppo`) from scratch
   (``ppo``), and behaviour cloning of the scenario's best decentralised scripted point
   followed by conservative PPO fine-tuning (``bc_ppo``). Each run writes
   ``<out>/runs/<scenario>/<variant>/seed_<s>/`` (``policy.pt`` with the actor only,
   ``log.csv``, ``config.json``, ``summary.json``; intermediate checkpoints and the critic
   removed to keep the committed files small); an existing
   ``policy.pt`` is kept unless ``--retrain``. Then every policy is evaluated greedy and
   sampled on the same seeds, in the control mode it was trained in. Writes
   ``frontier_<scenario>.csv/.png`` (scripted curves and learned points with intervals),
   ``frontier.csv``, ``frontier.md``.
3. **Summary** (``summary.csv``, ``summary.md``), per learned point: mean relative error ``e``
   and messages ``m`` per agent-step (substate payloads / M in ``substates`` mode, the
   frontier's x-axis), reward; ``m_scripted(e)``, the fewest messages at which the lower
   convex hull of the scripted points has error ``e`` (switching between two scripted
   policies from episode to episode reaches any point of it; no scripted point reaches
   ``e`` -> empty); ``saving = 1 - m / m_scripted(e)`` (> 0: the learned point lies below
   the frontier, it dominates it there) and ``robust_saving``, the same with the learned
   point's upper interval ends (messages against the hull at its upper error). Per
   scenario the freshness observer's error ``e_F`` (``always``) and the aim: a learned
   point with ``e <= e_F`` and ``m <= 0.7 m_scripted(e_F)``. One sentence per scenario
   states the outcome.
4. **Size transfer** (``[transfer]``): the set network trained at ``train_size`` agents,
   evaluated with the protocol at each size of ``eval_sizes`` beside that size's scripted
   frontier (``transfer.csv``, ``transfer.md``, ``frontier_transfer_N<k>.png``).
"""

# %%
from __future__ import annotations

import argparse
import csv
import json
import math
import shutil
import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "experiments/rl/configs/learned_comm.toml"
RESULTS = ROOT / "experiments/results/rl/learned_comm"
TARGET_SAVING = 0.30


CENTRALISED = ("oldest", "whittle")  # scripted families that read every agent's ages


def load_config(path: Path = CONFIG) -> tuple[dict, dict, dict, dict | None]:
    """``(defaults, variants, {scenario: fields}, transfer)`` from the TOML file."""
    raw = tomllib.loads(path.read_text())
    return raw["defaults"], raw["variants"], raw["scenarios"], raw.get("transfer")


def ppo_config(scenario: str, seed: int, fields: dict, steps: int | None,
               bc: str | None = None):
    """The run's :class:`PPOConfig` from merged TOML fields (``bc = "best"`` -> ``bc``)."""
    from netsense.rl.config import PPOConfig

    skip = ("seeds", "eval_sizes", "scenario", "train_size", "conservative")
    # (TOML has no null: "none" means None, e.g. entropy_final = "none")
    kw = {k: (None if v == "none" else v) for k, v in fields.items() if k not in skip}
    if kw.get("bc") == "best":
        kw["bc"] = bc
    if steps is not None:
        kw["steps"] = steps
    if "overrides" in kw:
        kw["overrides"] = dict(kw["overrides"])
    cfg = PPOConfig(scenario, seed=seed, **kw)
    return cfg.conservative() if fields.get("conservative") else cfg


def best_decentralised(rows: list[dict]) -> dict:
    """The scripted row with the highest mean return among the decentralised ones."""
    ok = [r for r in rows if r["family"] not in ("learned", *CENTRALISED)]
    return max(ok, key=lambda r: r["reward_mean"])


def train(cfg, run: Path, retrain: bool) -> Path:
    """Train one seed into ``run`` (kept when its policy exists and not ``retrain``)."""
    from netsense.rl.ppo import train_ppo

    policy = run / "policy.pt"
    if policy.exists() and not retrain:
        return policy
    if run.exists():
        shutil.rmtree(run)
    train_ppo(cfg, run, progress=True)
    for f in run.glob("checkpoint_*.pt"):
        f.unlink()
    shutil.rmtree(run / "tb", ignore_errors=True)
    slim(policy)
    return policy


def slim(policy: Path) -> None:
    """Drop the critic from a ``policy.pt`` (evaluation reads only the actor): the
    committed files stay small."""
    from netsense.rl.checkpoint import read_policy, write_policy

    state = read_policy(policy)  # read as data, checksum verified; rewritten with a new one
    if state.pop("critic", None) is not None:
        write_policy(policy, state)


# %%
def x_metric(rows: list[dict]) -> str:
    """The frontier's x-axis: substate payloads in ``substates`` mode, else messages."""
    per_sub = any(r["control"] == "substates" for r in rows if r["family"] != "learned")
    return "load_per_agent_step" if per_sub else "msgs_per_agent_step"


def scripted_hull(rows: list[dict], xm: str) -> list[tuple[float, float]]:
    """``[(messages, error), ...]``: the lower convex hull of the scripted points, from the
    fewest messages on, while the error falls. Switching between two scripted policies
    from episode to episode reaches every point of it in expectation, so it is the
    frontier a learned point has to beat."""
    pts = sorted({(r[f"{xm}_mean"], r["mean_rel_error_mean"]) for r in rows
                  if r["family"] != "learned"})
    hull: list[tuple[float, float]] = []
    for p in pts:
        while len(hull) >= 2 and ((hull[-1][0] - hull[-2][0]) * (p[1] - hull[-2][1])
                                  - (hull[-1][1] - hull[-2][1]) * (p[0] - hull[-2][0])) <= 0:
            hull.pop()
        hull.append(p)
    best = min(range(len(hull)), key=lambda i: hull[i][1])
    return hull[:best + 1]


def scripted_messages(rows: list[dict], error: float, xm: str) -> float:
    """Fewest messages at which the scripted frontier (:func:`scripted_hull`) has mean
    error ``<= error`` (NaN: no scripted point or mixture gets there)."""
    hull = scripted_hull(rows, xm)
    if error >= hull[0][1]:
        return hull[0][0]
    for (m0, e0), (m1, e1) in zip(hull[:-1], hull[1:], strict=True):
        if e1 <= error <= e0:
            return m0 + (m1 - m0) * (e0 - error) / (e0 - e1)
    return float("nan")


def summarise(rows: list[dict]) -> tuple[list[dict], str]:
    """Per learned point: error, messages, reward, scripted envelope and saving; and the
    scenario's sentence."""
    xm = x_metric(rows)
    scenario = rows[0]["scenario"]
    scripted = [r for r in rows if r["family"] != "learned"]
    fresh = next(r for r in scripted if r["policy"] == "always")
    best = max(scripted, key=lambda r: r["reward_mean"])
    e_f = fresh["mean_rel_error_mean"]
    m_f = scripted_messages(rows, e_f, xm)
    out = []
    for r in rows:
        if r["family"] != "learned":
            continue
        e, m = r["mean_rel_error_mean"], r[f"{xm}_mean"]
        env = scripted_messages(rows, e, xm)
        saving = 1 - m / env if math.isfinite(env) and env > 0 else float("nan")
        # the same with the intervals against the learned point: its upper messages
        # against the scripted envelope at its upper error
        env_hi = scripted_messages(rows, r["mean_rel_error_ci_high"], xm)
        robust = (1 - r[f"{xm}_ci_high"] / env_hi if math.isfinite(env_hi) and env_hi > 0
                  else float("nan"))
        out.append({
            "scenario": scenario, "policy": r["knob"],
            "variant": Path(r["knob"]).parent.parent.name, "evaluation": r["evaluation"],
            "error": e, "error_ci": (r["mean_rel_error_ci_low"], r["mean_rel_error_ci_high"]),
            "messages": m, "messages_ci": (r[f"{xm}_ci_low"], r[f"{xm}_ci_high"]),
            "reward": r["reward_mean"], "reward_ci": (r["reward_ci_low"], r["reward_ci_high"]),
            "scripted_messages_at_error": env, "saving": saving, "robust_saving": robust,
            "reaches_freshness_error": e <= e_f,
            "saving_at_freshness_error": ((1 - m / m_f) if e <= e_f and math.isfinite(m_f)
                                          and m_f > 0 else float("nan")),
            "best_scripted": best["policy"], "best_scripted_reward": best["reward_mean"],
            "freshness_error": e_f, "freshness_messages": fresh[f"{xm}_mean"],
            "scripted_messages_at_freshness_error": m_f, "x_metric": xm})
    return out, sentence(out)


def _seed(path: str) -> str:
    """``<variant> seed <s>`` from ``.../<variant>/seed_<s>/policy.pt``."""
    run = Path(path).parent
    return f"{run.parent.name} {run.name.replace('seed_', 'seed ')}"


def sentence(points: list[dict]) -> str:
    """One honest sentence: does a learned point dominate the frontier, by how much, and
    does one reach the freshness error with >= 30 % fewer messages."""
    p0 = points[0]
    sc, xm = p0["scenario"], ("substate payloads" if p0["x_metric"].startswith("load")
                              else "messages")
    best_r = max(points, key=lambda p: p["reward"])
    dom = [p for p in points if math.isfinite(p["saving"]) and p["saving"] > 0]
    sure = [p for p in dom if math.isfinite(p["robust_saving"]) and p["robust_saving"] > 0]
    beyond = [p for p in points if not math.isfinite(p["scripted_messages_at_error"])]
    parts = [f"{sc}: best learned return {best_r['reward']:.1f} ({_seed(best_r['policy'])}, "
             f"{best_r['evaluation']}) vs best scripted {p0['best_scripted']} "
             f"{p0['best_scripted_reward']:.1f}"]
    if sure:
        top = max(sure, key=lambda p: p["robust_saving"])
        parts.append(f"{len(sure)} of {len(points)} learned points lie below the scripted "
                     f"frontier beyond their 95 % intervals, by at most "
                     f"{top['robust_saving']:.0%} fewer {xm} than the best scripted point "
                     f"of equal error ({_seed(top['policy'])}, {top['evaluation']}: error "
                     f"{top['error']:.3f}, {top['messages']:.3f} vs "
                     f"{top['scripted_messages_at_error']:.3f})")
    else:
        parts.append(f"no learned point lies below the scripted frontier beyond its 95 % "
                     f"intervals ({len(points)} points"
                     + (f"; {len(dom)} do in the means alone, by at most "
                        f"{max(p['saving'] for p in dom):.0%}" if dom else "") + ")")
    if beyond:
        parts.append(f"{len(beyond)} reach a lower error than any scripted point")
    hit = [p for p in points if p["reaches_freshness_error"]
           and math.isfinite(p["saving_at_freshness_error"])]
    m_f = p0["scripted_messages_at_freshness_error"]
    if not (math.isfinite(m_f) and m_f > 0):
        parts.append(f"the 30 % aim is void here: a scripted point without messages "
                     f"already reaches the freshness observer's error "
                     f"({p0['freshness_error']:.3f})")
    elif hit:
        top = max(hit, key=lambda p: p["saving_at_freshness_error"])
        ok = top["saving_at_freshness_error"] >= TARGET_SAVING
        sv = top["saving_at_freshness_error"]
        parts.append(f"at the freshness observer's error ({p0['freshness_error']:.3f}) the "
                     f"best learned point uses {abs(sv):.0%} {'fewer' if sv >= 0 else 'more'}"
                     f" {xm} than the scripted frontier "
                     f"({'meets' if ok else 'misses'} the 30 % aim)")
    else:
        parts.append(f"none reaches the freshness observer's error "
                     f"({p0['freshness_error']:.3f}; best learned "
                     f"{min(p['error'] for p in points):.3f}), so the 30 % aim is not met")
    return "; ".join(parts) + "."


def read_frontier(path: Path) -> list[dict]:
    """Rows of a ``frontier_<scenario>.csv`` with numbers as floats."""
    rows = []
    with path.open() as fh:
        for r in csv.DictReader(fh):
            for k, v in r.items():
                if k.endswith(("_mean", "_ci_low", "_ci_high")):
                    r[k] = float(v)
            r["pareto"] = r["pareto"] == "True"
            rows.append(r)
    return rows


def _fmt(v, digits=3) -> str:
    if isinstance(v, tuple):
        return f"[{v[0]:.{digits}g}, {v[1]:.{digits}g}]"
    if isinstance(v, float):
        return "–" if not math.isfinite(v) else f"{v:.{digits}g}"
    return str(v)


def write_summary(points: list[dict], sentences: list[str], out: Path) -> None:
    cols = ["scenario", "policy", "variant", "evaluation", "error", "error_ci", "messages",
            "messages_ci", "reward", "reward_ci", "scripted_messages_at_error", "saving",
            "robust_saving",
            "reaches_freshness_error", "saving_at_freshness_error", "best_scripted",
            "best_scripted_reward", "freshness_error", "freshness_messages",
            "scripted_messages_at_freshness_error", "x_metric"]
    with (out / "summary.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for p in points:
            w.writerow([";".join(f"{v:.6g}" for v in p[c]) if isinstance(p[c], tuple)
                        else (f"{p[c]:.6g}" if isinstance(p[c], float) else p[c])
                        for c in cols])
    lines = ["| scenario | policy | evaluation | error [95 % CI] | messages [95 % CI] | "
             "reward [95 % CI] | scripted messages at that error | saving |",
             "|---|---|---|---|---|---|---|---|"]
    for p in points:
        lines.append(f"| {p['scenario']} | {_seed(p['policy'])} | {p['evaluation']} | "
                     f"{_fmt(p['error'])} {_fmt(p['error_ci'])} | {_fmt(p['messages'])} "
                     f"{_fmt(p['messages_ci'])} | {_fmt(p['reward'], 4)} "
                     f"{_fmt(p['reward_ci'], 4)} | {_fmt(p['scripted_messages_at_error'])} | "
                     f"{_fmt(p['saving'], 2)} |")
    lines += [""] + [f"- {s}" for s in sentences]
    (out / "summary.md").write_text("\n".join(lines) + "\n")


# %%
def transfer(defaults: dict, tr: dict, out: Path, args) -> None:
    """Set network trained at ``train_size`` agents, evaluated at every size."""
    from netsense.benchmark import protocol

    scenario = tr["scenario"]

    def size(n: int) -> dict:
        return {"plant": {"num_agents": n, "n": n}, "graph": {"num_nodes": n}}

    fields = {**defaults, **{k: v for k, v in tr.items() if k != "scenario"}}
    fields["overrides"] = size(tr["train_size"])
    cfg = ppo_config(scenario, 0, fields, args.transfer_steps)
    run = out / "runs" / f"transfer_N{tr['train_size']}" / "set" / "seed_0"
    policy = run / "policy.pt"
    if not args.skip_train:
        train(cfg, run, args.retrain)
    rows_all = []
    for n in tr["eval_sizes"]:
        rows = protocol.frontier(scenario, episodes=args.episodes, learned=[str(policy)],
                                 overrides=size(n), progress=True, settled_bases=())
        for r in rows:
            r["N"] = n
        rows_all += rows
        protocol._plot(rows, out / f"frontier_transfer_N{n}.png")
    keep = ("N", "policy", "evaluation", "mean_rel_error_mean", "mean_rel_error_ci_low",
            "mean_rel_error_ci_high", "msgs_per_agent_step_mean", "reward_mean",
            "reward_ci_low", "reward_ci_high", "pareto")
    with (out / "transfer.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(keep)
        for r in rows_all:
            w.writerow([r[k] for k in keep])
    lines = ["| N | policy | error | messages | reward [95 % CI] | best scripted (reward) |",
             "|---|---|---|---|---|---|"]
    for n in tr["eval_sizes"]:
        rs = [r for r in rows_all if r["N"] == n]
        best = max((r for r in rs if r["family"] != "learned"), key=lambda r: r["reward_mean"])
        fresh = next(r for r in rs if r["policy"] == "always")
        for r in [fresh] + [r for r in rs if r["family"] == "learned"]:
            name = r["policy"] if r["family"] != "learned" else f"learned ({r['evaluation']})"
            lines.append(f"| {n} | {name} | {r['mean_rel_error_mean']:.3f} | "
                         f"{r['msgs_per_agent_step_mean']:.3f} | {r['reward_mean']:.1f} "
                         f"[{r['reward_ci_low']:.1f}, {r['reward_ci_high']:.1f}] | "
                         f"{best['policy']} ({best['reward_mean']:.1f}) |")
    (out / "transfer.md").write_text("\n".join(lines) + "\n")
    print((out / "transfer.md").read_text())


# %%
def main(argv: list[str] | None = None) -> Path:
    from netsense.benchmark import protocol

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default=str(CONFIG))
    p.add_argument("--scenarios", nargs="+", default=None)
    p.add_argument("--seeds", type=int, nargs="+", default=None)
    p.add_argument("--steps", type=int, default=None, help="agent-steps per run (override)")
    p.add_argument("--transfer-steps", type=int, default=None)
    p.add_argument("--episodes", type=int, default=protocol.DEFAULT_EPISODES)
    p.add_argument("--families", nargs="+", default=None, choices=list(protocol.FAMILIES))
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--retrain", action="store_true")
    p.add_argument("--skip-train", action="store_true")
    p.add_argument("--no-transfer", action="store_true")
    p.add_argument("--summarise-only", action="store_true",
                   help="rewrite summary.md/csv from the frontier_<scenario>.csv in --out")
    args = p.parse_args(argv)
    defaults, variants, scenarios, tr = load_config(Path(args.config))
    names = args.scenarios or list(scenarios)
    seeds = args.seeds or defaults["seeds"]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    families = (None if args.families is None
                else {f: protocol.FAMILIES[f] for f in args.families})
    points, sentences, all_rows = [], [], []
    if args.summarise_only:
        for sc in names:
            rows = read_frontier(out / f"frontier_{sc}.csv")
            for r in rows:
                if r["family"] == "learned":
                    r["label"] = Path(r["knob"]).parent.parent.name
            protocol._plot(rows, out / f"frontier_{sc}.png")
            for f in (out / "runs" / sc).glob("*/seed_*/policy.pt"):
                slim(f)
            best = best_decentralised(rows)
            pts, sent = summarise(rows)
            points += pts
            sentences.append(f"{sent[:-1]}; warm start cloned {best['policy']}.")
            print(sentences[-1])
        write_summary(points, sentences, out)
        (out / "sentences.json").write_text(json.dumps(sentences, indent=2) + "\n")
        return out / "summary.md"
    for sc in names:
        scripted = protocol.frontier(sc, episodes=args.episodes, families=families,
                                     progress=True, settled_bases=())
        best = best_decentralised(scripted)
        policies = []
        for variant, vfields in variants.items():
            for s in seeds:
                run = out / "runs" / sc / variant / f"seed_{s}"
                fields = {**defaults, **vfields, **scenarios[sc]}
                if not args.skip_train:
                    train(ppo_config(sc, s, fields, args.steps, bc=best["policy"]), run,
                          args.retrain)
                policies.append(str(run / "policy.pt"))
        learned = [r for r in protocol.frontier(sc, episodes=args.episodes, families={},
                                                learned=policies, progress=True,
                                                settled_bases=())
                   if r["family"] == "learned"]
        for r in learned:
            r["label"] = Path(r["knob"]).parent.parent.name
        rows = scripted + learned
        for r, flag in zip(rows, protocol.pareto_front(rows), strict=True):
            r["pareto"] = flag
        protocol.write_frontier(rows, out)
        all_rows += rows
        pts, sent = summarise(rows)
        points += pts
        sentences.append(f"{sent[:-1]}; warm start cloned {best['policy']}.")
        print(sentences[-1])
    with (out / "frontier.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(protocol.CSV_COLUMNS)
        for r in all_rows:
            w.writerow([protocol._cell(r[c]) for c in protocol.CSV_COLUMNS])
    (out / "frontier.md").write_text(protocol.markdown_frontier(all_rows))
    write_summary(points, sentences, out)
    (out / "sentences.json").write_text(json.dumps(sentences, indent=2) + "\n")
    if tr is not None and not args.no_transfer:
        transfer(defaults, tr, out, args)
    return out / "summary.md"


if __name__ == "__main__":
    print(main())
