"""From-scratch multi-agent PPO on every communication task, against the scripted frontier
and the bounds, with rliable's aggregates; and the ablation of the training recipe.

The commands (``experiments/rl/configs/learners.toml`` holds every setting)::

    python experiments/rl/learners.py ablation    # the recipe, one change at a time
    python experiments/rl/learners.py results     # every task x learner x seed, evaluated
    python experiments/rl/learners.py summary     # the summaries again, from episodes.csv
    python experiments/rl/learners.py diagnose    # one decision's signal against the noise
    python experiments/rl/learners.py channel     # how the learners use the collision channel
    python experiments/rl/learners.py substates   # which substates the learners send
    python experiments/rl/learners.py memory      # where the learners would need memory
    python experiments/rl/learners.py reaction    # comm_fading-v0: what the row shows, done
    python experiments/rl/learners.py values      # comm_fading-v0: what each choice is worth
    python experiments/rl/learners.py credit      # comm_fading-v0: what a message earns
    python experiments/rl/learners.py standing    # per task: one configuration, best learner
    python experiments/rl/learners.py time-to-rule   # when training reaches the rule
    python experiments/rl/learners.py news-sends  # what the news gate closes, per task
    python experiments/rl/learners.py curve-points  # where the validation curves cross

``--tasks``, ``--learners``, ``--seeds``, ``--steps`` shrink either; ``--retrain`` trains
again where a run's ``policy.pt`` exists (by default an existing run is evaluated as it is,
so the committed policies are re-evaluated without training). Runs train one at a time, in
this process, with one torch thread (the config's ``[defaults]``; ``PPOConfig``'s default
is torch's own count) and one numba thread (``PPOConfig``'s default); a progress bar counts
the runs.

**results** writes into ``experiments/results/rl/learners/``:

* ``runs/<task>/<learner>/seed_<s>/``: ``policy.pt`` (the final actor), ``policy_best.pt``
  (the checkpoint with the best greedy return in the periodic evaluation during training,
  whose episodes are seeded from 10^9: a validation set apart from the training and the
  protocol's seeds; runs trained before this option have none), ``log.csv``,
  ``config.json``, ``summary.json``, ``training_curve.png``; ``runs/summary.json``
  lists the runs of the last launch (:func:`netsense.rl.launch.launch`; folders trained
  with a launch per task have a ``runs/<task>/summary.json`` instead);
* ``episodes.csv``: every final policy on the protocol's 100 evaluation episodes (seeds
  ``10^6 .. 10^6 + 99``, disjoint from every training seed; checked), greedy and sampled,
  and the best-validated checkpoint greedy (evaluation ``best-validated``) where a run has one,
  beside the task's references on the same episodes: ``never``, the best decentralised
  rule (the benchmark suite's, :mod:`netsense.benchmark.references`) and the causal and
  clairvoyant lookahead references (read from the lookahead experiment's
  ``episodes.csv``, fewer episodes; labelled ``reference:causal``, ``reference:clairvoyant``);
* ``curves.png`` / ``curves.csv``: evaluation return against agent-steps, the interquartile
  mean (IQM) over the training seeds with a 95 % stratified-bootstrap band (the greedy
  return of the periodic evaluation during training, on its own episodes), with the best
  decentralised scripted return on those same episodes, and on the test episodes that
  return (thin), the causal bound and ``never`` as lines (``curve_refs.csv``);
* ``summary.csv`` / ``summary.md``: per task and learner, the IQM of the return over seeds
  x evaluation episodes with its 95 % bootstrap interval (``rliable``), the probability of
  improvement over the best decentralised scripted policy, whether the interval reaches
  that policy's IQM on the same episodes, the fraction of the gap between that policy and
  the causal bound the learner closes (every term an IQM: :func:`summarise`, with the
  benchmark suite's statistics, :mod:`netsense.benchmark.scores`); and ``aggregate.png``,
  the suite's figure (:mod:`netsense.benchmark.suite`): scores normalised per episode,
  ``never`` = 0 and the certified upper bound = 1, per task beside the suite's best
  decentralised rule and best full-information reference, the IQM over tasks and the
  performance profiles (drawn once the suite's references hold a bound for every task).
  The best decentralised scripted policy is the suite's reference
  (:mod:`netsense.benchmark.references`).

**summary** rebuilds ``summary.{csv,md}``, ``curves.{csv,png}``, ``curve_refs.csv`` and
``aggregate.png`` of ``--out`` from its ``episodes.csv`` and its runs' logs, without
evaluating a learned policy again (the curves' scripted reference is one rollout).

**diagnose** writes ``diagnosis.csv`` / ``diagnosis.md``: per agent, the effect of one
transmission on the discounted team return under a random policy, against the return's
spread (how much signal a policy gradient gets per decision).

**channel** writes ``channel.csv`` / ``channel.md``: on ``comm_channel_k2-v0``, every final
policy under ``--out`` (all its results folders) beside ``tdma:1`` and the best ALOHA point
on the protocol's episodes: senders per step, the share of steps whose messages collided,
messages delivered per step, silent steps, and the send rates of sources and relays; and
``channel_rules.csv`` / ``channel_rules.md``: the exact schedules one rule shared by the
agents can express with the clock in each agent's own frame (source ``i`` sends iff
``(t - i) mod 5`` is in a pair of phases), beside ``tdma:1``, with their paired difference
to it on the same episodes.

**substates** writes ``substates.csv`` / ``substates.md``: on ``comm_substates-v0``, every
final policy under ``--out`` beside ``event:1`` on the protocol's episodes: how often a
substate is sent without news, on news of the agent's own substate and on news of another
agent's substate; and ``substates_relay.csv`` / ``substates_relay.md``: the return of
``event:1`` with its relays thinned (another agent's news sent with probability ``p``, the
agent's own news always) and with substates without news sent anyway (probability ``q``,
as a policy that still explores does), the landscape a learner that does not relay stands
on.

**ablation** writes ``ablation/runs/...``, ``ablation.csv``, ``ablation.md`` and
``ablation.png`` (final greedy and sampled evaluation return per variant, mean and range
over the seeds, and the diagnostics that explain it: explained variance, entropy, action
gap).

**values** writes ``values_fading.csv`` / ``values_fading.md`` into ``--out``: on
``comm_fading-v0``, for the feed-forward twin of ``acked(sources:0)`` and every final
policy under ``--out``, what each decision of an owner is worth under that policy's own
play (:func:`decision_values`: forks of 32 evaluation episodes where one owner makes the
other choice, realised futures), per class of its row, with the first-order gain of
choosing by the class's value.

**time-to-rule** writes ``time_to_rule.csv`` / ``time_to_rule.md`` into ``--out`` (a
results folder): per task and learner, how many seeds reach the best decentralised rule
during training and stay there to the end of the run (the monitoring evaluation's greedy
return against the rule's on the same episodes, ``curve_refs.csv``), with the median
agent-steps and wall-clock minutes they took (the runs' own clocks: on the machine and
with the workers they trained with).

**news-sends** writes ``news_sends.csv`` / ``news_sends.md`` into ``--out``: on every task
(``--tasks``), its best decentralised rule and every final policy of the task under
``--out``, each send choice paired with the news its agent saw (:func:`news_use`): sends
per choice (of sources and of relays, or of the agent's own substate and of another's),
how often a choice has news, the send probability with news and without, and the share of
the sends made without news, the sends the news gate (``PPOConfig.news_gate``) closes.

**curve-points** writes ``curve_points.csv`` / ``curve_points.md`` into ``--out`` (a
results folder) and prints them: from its ``curves.csv`` (the validation IQM over the
seeds), per task and learner and per ``--levels`` value, the last evaluation at or below
the level and the first above it (:func:`level_points`); and with ``--at``, from each
run's ``log.csv``, every seed's validation return (or another ``--column`` of the log,
then into ``curve_points_<column>.{csv,md}``) at the last evaluation at or before each of
those agent-steps, and on how many seeds it is higher at the later one
(:func:`seed_points`).
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

import numpy as np

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[2]
CONFIG = Path(__file__).resolve().parent / "configs" / "learners.toml"
RESULTS = ROOT / "experiments" / "results" / "rl" / "learners"
BOUNDS = ROOT / "experiments" / "results" / "rl" / "comm_bounds" / "episodes.csv"
FRONTIER = ROOT / "experiments" / "results" / "rl" / "comm_bounds" / "frontier.csv"
NONE = "none"  # TOML has no null: "none" in the config means None
EPISODES = 100
#: a run's best-validated checkpoint (actor only), kept beside its final ``policy.pt``
BEST = "policy_best.pt"


def load_config(path: Path = CONFIG) -> dict:
    return tomllib.loads(path.read_text())


def _fields(*tables: dict) -> dict:
    out: dict = {}
    for t in tables:
        out.update({k: (None if v == NONE else v) for k, v in t.items()})
    for k in ("seeds", "tasks"):
        out.pop(k, None)
    return out


#: Keys of a learner table that configure the evolution strategy (``algorithm =
#: "es"``, :class:`netsense.rl.es.ESConfig`) rather than the actor's PPOConfig.
ES_KEYS = ("popsize", "episodes", "sigma", "init")


def es_config(fields: dict):
    """The run's :class:`netsense.rl.es.ESConfig` when its table says ``algorithm = "es"``,
    else ``None`` (PPO); an unknown algorithm, or ES keys without it, is refused by name."""
    algorithm = fields.get("algorithm", "ppo")
    if algorithm not in ("ppo", "es"):
        raise ValueError(f"learner table: algorithm must be 'ppo' or 'es', got {algorithm!r}")
    given = {k: fields[k] for k in ES_KEYS if k in fields}
    if algorithm == "ppo":
        if given:
            raise ValueError(f"learner table: {sorted(given)} configure the evolution "
                             "strategy; set algorithm = \"es\" or remove them")
        return None
    from netsense.rl.es import ESConfig

    return ESConfig(**given)


def ppo_config(task: str, seed: int, fields: dict):
    """The run's :class:`netsense.rl.config.PPOConfig` (for an ES learner: the actor's
    network and task, :func:`es_config`)."""
    from netsense.rl.config import PPOConfig

    kw = {k: v for k, v in fields.items() if k not in ES_KEYS + ("algorithm",)}
    if "hidden" in kw:
        kw["hidden"] = tuple(kw["hidden"])
    return PPOConfig(scenario=task, seed=seed, **kw)


# %% training
def _finish(folder: Path) -> Path:
    """A trained run's committed files: the best-validated checkpoint copied to
    :data:`BEST`, checkpoints and TensorBoard events removed, the critic stripped."""
    from netsense.rl.checkpoint import strip_critic

    best = best_validated(folder)
    if best is not None:
        shutil.copyfile(best, folder / BEST)
        strip_critic(folder / BEST)
    for ck in folder.glob("checkpoint_*.pt"):
        ck.unlink()
    shutil.rmtree(folder / "tb", ignore_errors=True)
    strip_critic(folder / "policy.pt")  # the committed file holds the actor only
    return folder


def best_validated(folder: Path) -> Path | None:
    """The run's checkpoint with the highest greedy return in the periodic evaluation
    during training (its own episodes, seeds from ``EVAL_SEED`` = 10^9 on: a validation
    set, disjoint from the training seeds and from the protocol's test seeds); the later
    one on a tie. ``None`` where the run kept no evaluated checkpoint."""
    best, path = -math.inf, None
    for r in read_log(folder):
        ck = folder / f"checkpoint_{int(r['iteration']) + 1:05d}.pt"
        if r.get("eval_return") and ck.exists() and float(r["eval_return"]) >= best:
            best, path = float(r["eval_return"]), ck
    return path


def train_runs(runs: list[tuple[str, str, int, dict]], out: Path, retrain: bool,
               progress: bool = True, workers: int = 1) -> list[Path]:
    """Train every ``(task, name, seed, fields)`` into ``out/runs/<task>/<name>/seed_<s>``
    unless its ``policy.pt`` exists, through :func:`netsense.rl.launch.launch` (``workers``
    > 1: that many spawned processes with one-thread pools; a learner with ``algorithm =
    "es"`` searches with :func:`netsense.rl.es.train_es`), one launch for every task (run
    names ``<task>/<name>``: a worker that finishes a task's last seed takes the next
    task's first, where a launch per task left workers idle); returns the run folders. A
    failed run raises once the other runs have finished."""
    from netsense.rl.launch import Run, launch

    folders = [out / "runs" / t / n / f"seed_{s}" for t, n, s, _ in runs]
    todo = []
    for (t, n, s, f), d in zip(runs, folders, strict=True):
        if retrain or not (d / "policy.pt").exists():
            es = es_config(f)  # (checked before any folder is removed)
            shutil.rmtree(d, ignore_errors=True)
            todo.append(Run(ppo_config(t, s, f), f"{t}/{n}", es))
    if todo:
        entries = launch(todo, out / "runs", workers=workers, progress=progress)
        failed = [f"{e['folder']}: {e['error']}" for e in entries if e["status"] != "ok"]
        if failed:
            raise RuntimeError(f"runs failed: {'; '.join(failed)}")
        for e in entries:
            _finish(out / "runs" / e["folder"])
    return folders


def read_log(folder: Path) -> list[dict]:
    with (folder / "log.csv").open() as fh:
        return list(csv.DictReader(fh))


def seed_runs(folder: Path) -> list[Path]:
    """The ``seed_<s>`` runs of a ``runs/<task>/<learner>`` folder that have a
    ``log.csv``, in the order of their seeds."""
    return sorted((d for d in folder.glob("seed_*") if (d / "log.csv").exists()),
                  key=lambda d: int(d.name.removeprefix("seed_")))


# %% references and evaluation
def best_decentralised(task: str) -> str:
    """The spec of the task's best decentralised rule: the benchmark suite's reference
    (:mod:`netsense.benchmark.references`, the one definition every table reads)."""
    from netsense.benchmark.references import load_references

    return load_references()[task].best_decentralised


def best_frontier_point(task: str, what: str, keep) -> str:
    """The spec of the best point (mean return) of ``task`` among the frontier rows that
    ``keep`` accepts; ``ValueError`` naming ``what`` when there is none."""
    with FRONTIER.open() as fh:
        rows = [r for r in csv.DictReader(fh) if r["scenario"] == task and keep(r)]
    if not rows:
        raise ValueError(f"no {what} frontier point for {task} in {FRONTIER}; run "
                         "experiments/rl/comm_bounds.py first")
    return max(rows, key=lambda r: float(r["reward_mean"]))["policy"]


def bound_episodes(task: str) -> dict[str, np.ndarray]:
    """``{"reference:causal": returns, "reference:clairvoyant": returns}`` per episode of the
    lookahead references (fewer episodes than the protocol's 100: the first ones of the
    same seeds)."""
    out: dict[str, list] = {}
    if BOUNDS.exists():
        with BOUNDS.open() as fh:
            for r in csv.DictReader(fh):
                if r["scenario"] == task:
                    name = "reference:" + r["policy"].split(":", 1)[1]
                    out.setdefault(name, []).append(float(r["reward"]))
    return {k: np.asarray(v) for k, v in out.items()}


def reference_rows(task: str, episodes: int, control: str | None = None) -> list[dict]:
    """The task's references per episode: ``never`` and the best decentralised rule of
    the full frontier (the suite's, informed rules included) on the protocol's
    ``episodes`` evaluation episodes, the lookahead references (``reference:causal``,
    ``reference:clairvoyant``) and the certified upper bound (``upper_bound``, from the
    suite's references) on their first ones."""
    from netsense.benchmark.protocol import eval_seeds, evaluate
    from netsense.benchmark.references import load_references

    seeds = eval_seeds(episodes)
    rows = []
    refs = {"never": "never", "best_decentralised": best_decentralised(task)}
    scr_over = {"control": {"mode": control}} if control else {}
    for label, spec in refs.items():
        m = evaluate(task, spec, seeds, scr_over)
        rows += [{"task": task, "policy": label, "spec": spec, "seed": "",
                  "evaluation": "scripted", "episode": e, "reward": float(v)}
                 for e, v in enumerate(m["reward"])]
    for label, values in bound_episodes(task).items():
        rows += [{"task": task, "policy": label, "spec": label, "seed": "",
                  "evaluation": "reference", "episode": e, "reward": float(v)}
                 for e, v in enumerate(values)]
    bound = load_references()[task].upper_bound
    if bound is not None:
        episode = {sd: e for e, sd in enumerate(seeds)}
        rows += [{"task": task, "policy": "upper_bound", "spec": "upper_bound", "seed": "",
                  "evaluation": "bound", "episode": episode[sd], "reward": float(v)}
                 for sd, v in zip(bound.seeds, bound.values, strict=True) if sd in episode]
    return rows


def evaluate_all(tasks: dict[str, dict], folders: dict, episodes: int) -> list[dict]:
    """Per-episode returns of every learned policy (greedy, sampled) and the references
    (:func:`reference_rows`)."""
    from netsense.benchmark.protocol import eval_seeds, evaluate

    seeds = eval_seeds(episodes)
    rows = []
    for task, over in tasks.items():
        rows += reference_rows(task, episodes, over.get("control"))
        for (t, learner, seed), folder in folders.items():
            if t != task:
                continue
            kinds = [("greedy", "learned", "policy.pt"),
                     ("sampled", "learned_sampled", "policy.pt")]
            if (folder / BEST).exists():
                kinds.append(("best-validated", "learned", BEST))
            for kind, prefix, file in kinds:
                m = evaluate(task, f"{prefix}:{folder / file}", seeds)
                rows += [{"task": task, "policy": learner, "spec": learner, "seed": seed,
                          "evaluation": kind, "episode": e, "reward": float(v)}
                         for e, v in enumerate(m["reward"])]
    return rows


# %% aggregates (the benchmark suite's statistics, netsense.benchmark.scores)
def summarise(rows: list[dict], learners: list[str]) -> list[dict]:
    """Per task and learner: IQM [CI] over seeds x episodes, probability of improvement
    over the best decentralised rule, and the fraction of two gaps the learner closes: to
    the causal lookahead reference (``gap_closed``) and to the certified upper bound
    (``bound_gap_closed``) (the suite's statistics: :mod:`netsense.benchmark.scores`).

    The learner's IQM is compared with the references' IQM over their own episodes (the
    same 100 for the rule, the first ones for the lookahead and the bound), one statistic
    on both sides: an episode's return has a long lower tail, so an IQM lies above the
    mean of the same returns, and a learner's IQM against a reference's mean would credit
    it with gap it did not close (a policy identical to the rule would close some).
    ``reaches``: the learner's interval reaches the rule's IQM (its upper end at or above
    it); the reference means are kept beside them."""
    from netsense.benchmark.scores import iqm as aggregate_iqm
    from netsense.benchmark.scores import iqm_interval, probability_of_improvement

    def stat(values: np.ndarray, f) -> float:
        return float(f(values)) if values.size else math.nan

    def closed(iqm: float, low: float, high: float) -> float:
        gap = high - low
        return (iqm - low) / gap if gap > 0 else math.nan

    tasks = list(dict.fromkeys(r["task"] for r in rows))
    out = []
    for task in tasks:
        rs = [r for r in rows if r["task"] == task]
        ref = {p: np.array([r["reward"] for r in rs if r["policy"] == p])
               for p in ("never", "best_decentralised", "reference:causal",
                         "reference:clairvoyant", "upper_bound")}
        best = ref["best_decentralised"]
        b_iqm = aggregate_iqm(best)
        c_iqm = stat(ref["reference:causal"], aggregate_iqm)
        u_iqm = stat(ref["upper_bound"], aggregate_iqm)
        for learner in learners:
            for kind in ("greedy", "sampled", "best-validated"):
                seeds = sorted({r["seed"] for r in rs if r["policy"] == learner
                                and r["evaluation"] == kind})
                if not seeds:
                    continue
                per_seed = [np.array([r["reward"] for r in rs if r["policy"] == learner
                                      and r["evaluation"] == kind and r["seed"] == s])
                            for s in seeds]
                flat = np.concatenate(per_seed)[:, None]  # (seeds x episodes, 1 task)
                iqm, lo, hi = iqm_interval(flat)
                out.append({"task": task, "learner": learner, "evaluation": kind,
                            "seeds": len(seeds), "episodes": int(flat.shape[0]),
                            "iqm": iqm, "iqm_ci_low": lo, "iqm_ci_high": hi,
                            "seed_means": ";".join(f"{v.mean():.2f}" for v in per_seed),
                            "best_decentralised": float(best.mean()),
                            "best_decentralised_spec": next(r["spec"] for r in rs
                                                            if r["policy"] ==
                                                            "best_decentralised"),
                            "best_decentralised_iqm": b_iqm,
                            "causal_reference": stat(ref["reference:causal"], np.mean),
                            "causal_reference_iqm": c_iqm,
                            "upper_bound": stat(ref["upper_bound"], np.mean),
                            "upper_bound_iqm": u_iqm,
                            "never": float(ref["never"].mean()),
                            "p_improvement": probability_of_improvement(flat.ravel(), best),
                            "reaches": bool(hi >= b_iqm),
                            "gap_closed": closed(iqm, b_iqm, c_iqm),
                            "bound_gap_closed": closed(iqm, b_iqm, u_iqm)})
    return out


def suite_result(rows: list[dict], learners: list[str]):
    """The benchmark suite's :class:`~netsense.benchmark.suite.SuiteResult` of the learned
    policies' returns (each learner and evaluation one policy: ``mlp (greedy)``), under the
    suite's references (:func:`netsense.benchmark.suite.summarise`): normalised scores per
    episode, ``never`` = 0 and the certified upper bound = 1, and their aggregate."""
    from netsense.benchmark.protocol import EVAL_SEED0
    from netsense.benchmark.references import load_references
    from netsense.benchmark.suite import reference_rows, summarise

    refs = load_references()
    pol = [{"task": r["task"], "learner": f"{r['policy']} ({r['evaluation']})",
            "kind": "policy", "seed": int(r["seed"]),
            "episode_seed": EVAL_SEED0 + int(r["episode"]), "return": float(r["reward"])}
           for r in rows if r["policy"] in learners
           and r["evaluation"] in ("greedy", "sampled", "best-validated")]
    refs = {t: refs[t] for t in refs if any(r["task"] == t for r in pol)}
    seeds = sorted({r["episode_seed"] for r in pol})
    return summarise(reference_rows(refs, seeds) + pol, refs)


#: The reference lines of :func:`plot_curves`: ``refs`` key -> (colour, style, width, label).
REFERENCE_LINES = {
    "best_decentralised_validation": ("k", "--", 1.1, "best decentralised scripted"),
    "best_decentralised": ("0.35", "--", 0.7,
                           "best decentralised scripted, test episodes"),
    "reference:causal": ("C3", ":", 1.1, "causal full-information reference, test episodes"),
    "upper_bound": ("C2", "-", 1.1, "certified upper bound, test episodes"),
    "never": ("0.5", "-.", 1.1, "never, test episodes")}


def validation_return(spec: str, folder: Path) -> float:
    """Return of the scripted policy ``spec`` on the episodes of the periodic evaluation
    during training, which the learning curves plot (seeds ``EVAL_SEED`` + b, the run's
    ``eval_envs``, the scenario's reward: :func:`netsense.rl.evaluation.evaluate_scripted`),
    with the configuration of the run in ``folder`` (the task's first run: the learners
    share the evaluation's seeds and count): the curves' reference on their own episodes
    (the protocol's test episodes give other returns)."""
    from netsense.rl.checkpoint import policy_config
    from netsense.rl.evaluation import evaluate_scripted

    config = policy_config({"config": json.loads((folder / "config.json").read_text())},
                           folder / "config.json")
    return float(evaluate_scripted(spec, config)["return"])


# %% plots
def plot_curves(curves: dict, refs: dict, path: Path) -> None:
    """One panel per task: IQM over seeds with a 95 % bootstrap band per learner; the best
    decentralised scripted policy on the curves' own episodes (the periodic evaluation's)
    and, thin, on the protocol's test episodes, with the causal bound and ``never`` on
    the test episodes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(curves)
    cols = min(4, len(tasks))
    rows = -(-len(tasks) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    for ax, task in zip(axes.flat, tasks, strict=False):
        for c, (learner, (x, iqm, lo, hi)) in enumerate(curves[task].items()):
            ax.plot(x, iqm, color=f"C{c}", lw=1.4, label=f"{learner} (IQM, greedy)")
            ax.fill_between(x, lo, hi, color=f"C{c}", alpha=0.2)
        for name, (color, ls, lw, label) in REFERENCE_LINES.items():
            v = refs[task].get(name)
            if v is not None and math.isfinite(v):
                ax.axhline(v, color=color, ls=ls, lw=lw, label=label)
        ax.set_title(task, fontsize=9)
        ax.set_xlabel("agent-steps")
        ax.set_ylabel("return per agent")
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(tasks):]:
        ax.axis("off")
    # the legend below the panels, where it hides no curve: the figure grows by its height
    handles, labels = axes.flat[0].get_legend_handles_labels()
    ncol = min(cols, len(labels))
    below = 0.2 * -(-len(labels) // ncol) + 0.15
    height = fig.get_figheight()
    fig.set_figheight(height + below)
    fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=7, frameon=False)
    fig.tight_layout(rect=(0, below / (height + below), 1, 1))
    _savefig(fig, path)
    plt.close(fig)


def plot_aggregate(result, path: Path) -> None:
    """The benchmark suite's figure of the learned policies
    (:func:`netsense.benchmark.suite_output.plot_result`): per task the normalised IQM
    with its interval beside the best decentralised rule and the best full-information
    reference, the aggregate over tasks and the performance profiles; not drawn (said on
    the console) while a task has no certified upper bound."""
    from netsense.benchmark.suite_output import plot_result

    if not result.scores:
        print(f"{path}: not drawn: the suite's references hold no certified upper bound "
              "for every task (experiments/rl/suite_references.py)")
        return
    plot_result(result, path)


def learning_curves(folders: dict, learners: list[str]) -> dict:
    """``{task: {learner: (agent_steps, iqm, lo, hi)}}`` of the greedy evaluation return
    over the seeds (runs with fewer evaluations are cut to the shortest)."""
    from rliable import library as rly
    from rliable import metrics

    from netsense.benchmark.intervals import seeded_global_rng

    out: dict = {}
    for task in dict.fromkeys(t for t, _, _ in folders):
        for learner in learners:
            logs = [read_log(f) for (t, ln, _), f in folders.items()
                    if t == task and ln == learner]
            if not logs:
                continue
            ev = [[(int(r["agent_steps"]), float(r["eval_return"])) for r in log
                   if r.get("eval_return")] for log in logs]
            n = min(len(e) for e in ev)
            x = np.array([p[0] for p in ev[0][:n]])
            y = np.array([[p[1] for p in e[:n]] for e in ev])  # (seeds, points)
            with seeded_global_rng():
                point, ci = rly.get_interval_estimates(
                    {"y": y}, lambda s: np.array([metrics.aggregate_iqm(s[:, [j]])
                                                  for j in range(s.shape[1])]),
                    reps=500, random_state=np.random.RandomState(0))
            out.setdefault(task, {})[learner] = (x, point["y"], ci["y"][0], ci["y"][1])
    return out


# %% I/O
def write_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        return
    cols: list[str] = []
    for r in rows:
        cols += [c for c in r if c not in cols]
    from netsense.rl.atomic import atomic_path

    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        w.writerows(rows)


def _write(path: Path, text: str) -> None:
    from netsense.rl.atomic import write_atomic

    write_atomic(path, text)


def _savefig(fig, path: Path) -> None:
    from netsense.rl.atomic import save_figure

    save_figure(fig, path)


def _f(v: float, d: int = 1) -> str:
    return "–" if not math.isfinite(v) else f"{v:.{d}f}"


def markdown_summary(rows: list[dict]) -> str:
    lines = ["| task | learner | agent-steps | evaluation | IQM return [95 % CI] | best "
             "decentralised rule: IQM (mean) | causal reference: IQM (mean) | upper bound: "
             "IQM (mean) | never | reaches the rule | P(learned > rule) | gap closed to "
             "the causal reference | to the bound |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['task']} | {r['learner']} | {r.get('agent_steps', 0) / 1e6:.1f}M | "
            f"{r['evaluation']} | {_f(r['iqm'])} "
            f"[{_f(r['iqm_ci_low'])}, {_f(r['iqm_ci_high'])}] | "
            f"{_f(r['best_decentralised_iqm'])} ({_f(r['best_decentralised'])}, "
            f"`{r['best_decentralised_spec']}`) | {_f(r['causal_reference_iqm'])} "
            f"({_f(r['causal_reference'])}) | {_f(r['upper_bound_iqm'])} "
            f"({_f(r['upper_bound'])}) | {_f(r['never'])} | "
            f"{'yes' if r['reaches'] else 'no'} | {r['p_improvement']:.2f} | "
            f"{_f(100 * r['gap_closed'], 0)} % | {_f(100 * r['bound_gap_closed'], 0)} % |")
    return "\n".join(lines) + "\n"


# %% commands
def cmd_results(args, cfg: dict) -> None:
    defaults = cfg["defaults"]
    seeds = args.seeds or defaults["seeds"]
    tasks = {t: cfg["tasks"][t] for t in (args.tasks or cfg["tasks"])}
    learners = args.learners or list(cfg["learners"])
    runs = []
    for task, over in tasks.items():
        for learner in learners:
            fields = _fields(defaults, cfg["learners"][learner], over)
            if args.steps:
                fields["steps"] = args.steps
            if args.eval_interval:
                fields["eval_interval"] = args.eval_interval
            runs += [(task, learner, s, fields) for s in seeds]
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    dirs = train_runs(runs, out, args.retrain, progress=not args.no_progress,
                      workers=args.workers)
    folders = {(t, ln, s): d for (t, ln, s, _), d in zip(runs, dirs, strict=True)}
    rows = evaluate_all(tasks, folders, args.episodes)
    write_csv(out / "episodes.csv", rows)
    write_summaries(out, rows, folders, list(tasks), learners)


def cmd_summary(args, cfg: dict) -> None:
    """Rebuild ``--out``'s summaries, curves and aggregate from its ``episodes.csv`` and
    its runs' logs, without evaluating a learned policy again (what :func:`cmd_results`
    writes after its evaluation)."""
    out = args.out
    with (out / "episodes.csv").open() as fh:
        rows = [dict(r, reward=float(r["reward"])) for r in csv.DictReader(fh)]
    learned = [r for r in rows if r["evaluation"] in ("greedy", "sampled", "best-validated")]
    tasks = list(dict.fromkeys(r["task"] for r in rows))
    if args.refresh_references:  # the references again, on the learned rows' episodes
        episodes = 1 + max(int(r["episode"]) for r in learned)
        rows = [r for t in tasks for r in reference_rows(
            t, episodes, cfg["tasks"].get(t, {}).get("control"))] + learned
        write_csv(out / "episodes.csv", rows)
    learners = list(dict.fromkeys(r["policy"] for r in learned))
    folders = {(r["task"], r["policy"], int(r["seed"])):
               out / "runs" / r["task"] / r["policy"] / f"seed_{r['seed']}" for r in learned}
    write_summaries(out, rows, folders, tasks, learners)


def write_summaries(out: Path, rows: list[dict], folders: dict, tasks: list[str],
                    learners: list[str]) -> None:
    """``summary.{csv,md}``, ``curves.{csv,png}``, ``curve_refs.csv`` and ``aggregate.png``
    from the episode rows of :func:`evaluate_all` and the runs' folders."""
    summary = summarise(rows, learners)
    for r in summary:  # the training budget the row's runs had
        r["agent_steps"] = int(np.median([
            json.loads((d / "summary.json").read_text())["agent_steps"]
            for (t, ln, _), d in folders.items() if t == r["task"] and ln == r["learner"]]))
    write_csv(out / "summary.csv", summary)
    from netsense.rl.atomic import write_atomic

    write_atomic(out / "summary.md", markdown_summary(summary))
    curves = learning_curves(folders, learners)
    refs = {t: {p: float(np.mean([r["reward"] for r in rows if r["task"] == t
                                  and r["policy"] == p])) if any(
        r["task"] == t and r["policy"] == p for r in rows) else math.nan
        for p in ("never", "best_decentralised", "reference:causal", "upper_bound")}
        for t in tasks}
    lines = []
    for t in curves:
        spec = next(r["spec"] for r in rows if r["task"] == t
                    and r["policy"] == "best_decentralised")
        folder = next(d for (task, _, _), d in folders.items() if task == t)
        refs[t]["best_decentralised_validation"] = validation_return(spec, folder)
        lines += [{"task": t, "policy": p.removesuffix("_validation"),
                   "spec": spec if p.startswith("best") else p,
                   "episodes": "validation" if p.endswith("_validation") else "test",
                   "return": refs[t][p]} for p in REFERENCE_LINES]
    write_csv(out / "curve_refs.csv", lines)
    write_csv(out / "curves.csv", [{"task": t, "learner": ln, "agent_steps": int(x),
                                    "iqm": float(m), "ci_low": float(lo),
                                    "ci_high": float(hi)}
                                   for t, d in curves.items() for ln, c in d.items()
                                   for x, m, lo, hi in zip(*c, strict=True)])
    plot_curves(curves, refs, out / "curves.png")
    plot_aggregate(suite_result(rows, learners), out / "aggregate.png")
    print(markdown_summary(summary))


def cmd_ablation(args, cfg: dict) -> None:
    ab = cfg["ablation"]
    seeds = args.seeds or ab["seeds"]
    tasks = args.tasks or ab["tasks"]
    variants = ab["variants"]
    names = args.learners or list(variants)
    runs = []
    for task in tasks:
        for name in names:
            fields = _fields(cfg["defaults"], cfg["tasks"][task], ab.get("base", {}),
                             variants[name])
            fields["steps"] = args.steps or ab["steps"]
            runs += [(task, name, s, fields) for s in seeds]
    out = args.out / "ablation"
    out.mkdir(parents=True, exist_ok=True)
    dirs = train_runs(runs, out, args.retrain, progress=not args.no_progress,
                      workers=args.workers)
    rows = []
    for (task, name, seed, _), d in zip(runs, dirs, strict=True):
        log = read_log(d)
        last = [r for r in log if r.get("eval_return")][-1]
        tail = log[-max(1, len(log) // 10):]  # diagnostics: the last tenth of the run
        rows.append({"task": task, "variant": name, "seed": seed,
                     "eval_return": float(last["eval_return"]),
                     "eval_sampled_return": float(last["eval_sampled_return"]),
                     "eval_messages": float(last["eval_messages"]),
                     **{k: float(np.mean([float(r[k]) for r in tail])) for k in (
                         "explained_variance", "entropy", "action_gap", "advantage_sd",
                         "agent_steps_per_s")}})
    write_csv(out.parent / "ablation.csv", rows)
    table = _ablation_table(rows, tasks, names)
    _write(out.parent / "ablation.md", table)
    _plot_ablation(rows, tasks, names, out.parent / "ablation.png")
    print(table)


def _ablation_table(rows, tasks, names) -> str:
    lines = ["| variant | " + " | ".join(f"{t}: greedy / sampled (mean [min, max] over "
                                         "seeds)" for t in tasks)
             + " | explained variance | entropy | action gap |",
             "|---|" + "---|" * len(tasks) + "---|---|---|"]
    for name in names:
        cells = []
        diag = []
        for t in tasks:
            rs = [r for r in rows if r["task"] == t and r["variant"] == name]
            g = np.array([r["eval_return"] for r in rs])
            s = np.array([r["eval_sampled_return"] for r in rs])
            cells.append(f"{g.mean():.1f} [{g.min():.1f}, {g.max():.1f}] / {s.mean():.1f}")
            diag.append(rs)
        flat = [r for d in diag for r in d]
        lines.append(f"| {name} | " + " | ".join(cells)
                     + f" | {np.mean([r['explained_variance'] for r in flat]):.2f} | "
                     f"{np.mean([r['entropy'] for r in flat]):.2f} | "
                     f"{np.mean([r['action_gap'] for r in flat]):+.3f} |")
    return "\n".join(lines) + "\n"


def _plot_ablation(rows, tasks, names, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(tasks), figsize=(5.5 * len(tasks), 0.32 * len(names) + 1.5),
                             squeeze=False)
    for ax, t in zip(axes[0], tasks, strict=True):
        for i, name in enumerate(names):
            rs = [r for r in rows if r["task"] == t and r["variant"] == name]
            g = [r["eval_return"] for r in rs]
            s = [r["eval_sampled_return"] for r in rs]
            ax.plot(g, [i] * len(g), "o", color="C0", ms=4, label="greedy" if i == 0 else None)
            ax.plot(s, [i + 0.2] * len(s), "s", color="C1", ms=4, mfc="none",
                    label="sampled" if i == 0 else None)
        ax.set_yticks(range(len(names)), names, fontsize=7)
        ax.set_title(f"{t}: final evaluation return per seed", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    _savefig(fig, path)
    plt.close(fig)


def cmd_diagnose(args, cfg: dict) -> None:
    """How large one agent's decision is against the noise of the team return: under the
    uniformly random policy (every bit 1 with probability 1/2, independent of the state),
    the mean discounted team return-to-go after an agent transmitted minus after it stayed
    silent, per agent, against the return's standard deviation (steps 20-149 of 4096
    episodes, discounts 0.95 and 0.99; actions are independent of the state, so the
    difference is the action's effect)."""
    from netsense.rl.envs import NetSenseBatchedEnv, make_core

    tasks = args.tasks or cfg["ablation"]["tasks"]
    rows = []
    for task in tasks:
        control = cfg["tasks"][task].get("control")
        core = make_core(task, 4096, control=control)
        env = NetSenseBatchedEnv(core, reward="team", seed=0)
        env.restart()
        H, N, B = core.horizon, core.N, core.B
        rng = np.random.default_rng(0)
        A = np.zeros((H, B, N), bool)
        R = np.zeros((H, B))
        for k in range(H):
            a = rng.random((B, N, 1)) < 0.5
            r = env.advance(a.astype(np.int64))[2]  # the team reward, the same for all
            A[k], R[k] = a[..., 0], r[:, 0]
        src = core.is_source
        for gamma in (0.95, 0.99):
            G = np.zeros((H, B))
            acc = np.zeros(B)
            for k in reversed(range(H)):
                acc = R[k] + gamma * acc
                G[k] = acc
            g, sd = G[20:150], G[20:150].std()
            for i in range(N):
                a = A[20:150, :, i]
                gap = g[a].mean() - g[~a].mean()
                se = np.sqrt(g[a].var() / a.sum() + g[~a].var() / (~a).sum())
                rows.append({"task": task, "gamma": gamma, "agent": i,
                             "kind": "source" if src[i] else "relay", "gap": gap,
                             "gap_se": se, "return_sd": sd, "gap_over_sd": gap / sd})
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "diagnosis.csv", rows)
    lines = ["| task | discount | agent | kind | effect of transmitting on the discounted "
             "team return [± s.e.] | over the return's s.d. |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['task']} | {r['gamma']} | {r['agent']} | {r['kind']} | {r['gap']:+.4f} "
              f"[± {r['gap_se']:.4f}] | {r['gap_over_sd']:+.4f} (s.d. {r['return_sd']:.2f}) |"
              for r in rows]
    _write(out / "diagnosis.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


CHANNEL_TASK = "comm_channel_k2-v0"


def channel_use(spec: str, seeds: list[int], actor=None, returns: bool = False) -> dict:
    """How a policy uses the collision channel of :data:`CHANNEL_TASK` on the episodes
    ``seeds`` (the protocol's rollout, with its checks of learned policies): mean return,
    senders per step, share of steps whose messages collided, messages delivered per step
    (senders of steps without a collision), share of silent steps, and the send rate of
    sources and of relays (agents that measure nothing), and the mean length of a source's
    runs of consecutive sends (a run still open at the episode's end counts as it stands;
    a time division sends in runs of one slot). ``actor``: a rule that is no
    registered policy (``spec`` is then its label), as
    :func:`netsense.benchmark.protocol.evaluate` takes it. The return also as its 95 %
    bootstrap interval (``return_ci_low``, ``return_ci_high``) and its IQM over the
    episodes (``return_iqm``, rliable's); ``returns``: the episodes' returns too
    (``returns``, an array)."""
    from rliable import metrics

    from netsense.benchmark.intervals import bootstrap_ci
    from netsense.benchmark.protocol import evaluate

    senders, collided, sent, source, runs, run = [], [], [], [], [], []

    def record(core, live):
        senders.append(core.transmit.sum(1)[live])
        collided.append(core.collided[live])
        sent.append(core.transmit[live])
        if not source:
            source.append(core.is_source)
            run.append(np.zeros(core.transmit.shape, dtype=np.int64))
        tx, r = core.transmit & live[:, None], run[0]
        ended = ~tx & (r > 0) & live[:, None]
        runs.append(r[ended & source[0]])
        r[ended] = 0
        r[tx] += 1

    ret = evaluate(CHANNEL_TASK, spec, seeds, on_step=record, actor=actor)["reward"]
    s, c = np.concatenate(senders), np.concatenate(collided)
    rate, src = np.concatenate(sent).mean(0), source[0]
    runs.append(run[0][(run[0] > 0) & src])  # the runs open at the episodes' ends
    run_lengths = np.concatenate(runs)
    _, lo, hi = bootstrap_ci(ret)
    return {"return": float(ret.mean()), "return_ci_low": lo, "return_ci_high": hi,
            "return_iqm": float(metrics.aggregate_iqm(ret)),
            "senders_per_step": float(s.mean()),
            "collided_steps": float(c.mean()), "delivered_per_step": float((s * ~c).mean()),
            "silent_steps": float((s == 0).mean()), "source_rate": float(rate[src].mean()),
            "relay_rate": float(rate[~src].mean()) if (~src).any() else math.nan,
            "send_run": float(run_lengths.mean()) if run_lengths.size else math.nan,
            **({"returns": ret} if returns else {})}


#: Columns of the channel table: (key, header, scale, decimals, unit).
CHANNEL_COLUMNS = (("return", "return", 1, 1, ""),
                   ("senders_per_step", "senders per step", 1, 2, ""),
                   ("collided_steps", "steps with a collision", 100, 1, " %"),
                   ("delivered_per_step", "delivered per step", 1, 2, ""),
                   ("silent_steps", "silent steps", 100, 1, " %"),
                   ("source_rate", "source send rate", 1, 2, ""),
                   ("relay_rate", "relay send rate", 1, 2, ""),
                   ("send_run", "source's run of consecutive sends", 1, 2, ""))


def cmd_channel(args, cfg: dict) -> None:
    """Why the learners stay below time division on the collision channel: every final
    policy of the task under ``--out`` (all its results folders) beside ``tdma:1`` and the
    best ALOHA point, on the protocol's evaluation episodes (``--episodes``); and the
    exact agent-frame slot rules (:func:`channel_rules`)."""
    aloha = best_frontier_point(CHANNEL_TASK, "ALOHA", lambda r: r["family"] == "aloha")
    policy_use(args, CHANNEL_TASK, channel_use, ["tdma:1", aloha], CHANNEL_COLUMNS,
               "channel")
    channel_rules(args)


def agent_frame_slots(phases: tuple[int, ...]):
    """An ``actor`` for :func:`netsense.benchmark.protocol.evaluate`: source ``i`` (an agent
    with a non-empty block of Lemma 1) sends the message of step ``t`` iff
    ``(t - i) mod S`` is in ``phases``, ``S`` the number of sources; the others never send.

    One rule shared by all agents, read in each agent's own frame of the clock: the rule a
    learner with ``PPOConfig.clock_shift`` can express with one network. Where the sources'
    ids are distinct modulo ``S`` (on :data:`CHANNEL_TASK` they are 0, 2, 4, 6, 8), exactly
    ``len(phases)`` sources send at every step, each source ``len(phases)`` steps in ``S``:
    a time division like ``tdma:1``'s in another order of the sources. It is ``tdma:1``'s
    policy (its clock from the observation, its sources and its action layout) with the
    slot rule replaced."""
    from netsense.env.comm_policies import Tdma

    class AgentFrameSlots(Tdma):
        def act(self, obs, mask):
            t = self.steps(np.asarray(obs)) + 1  # the step the bits are sent at
            ids = np.arange(self.N)
            return self._send(mask, np.isin((t[:, None] - ids[None]) % self.S, phases)
                              & self.is_source[None])

    def actor(core, seeds):
        return AgentFrameSlots(core.layout, core.comm.width, core.horizon,
                               is_source=core.is_source,
                               capacity=core.capacity).act

    return actor


#: Phase sets of :func:`channel_rules`: every pair of phases up to a rotation (which only
#: changes which source starts), for the channel's capacity of two.
CHANNEL_RULES = ((0, 1), (0, 2), (0, 3), (0, 4))


def channel_rules(args) -> None:
    """``channel_rules.{csv,md}``: :func:`agent_frame_slots` for every phase set of
    :data:`CHANNEL_RULES`, beside ``tdma:1``, on the protocol's evaluation episodes: the
    return's mean with its 95 % bootstrap interval and its IQM (the statistic the learners'
    summaries compare), its difference to ``tdma:1`` on the same episodes (mean of the
    paired differences with its 95 % bootstrap interval), and the channel use of
    :func:`channel_use`."""
    from netsense.benchmark.intervals import bootstrap_ci
    from netsense.benchmark.protocol import eval_seeds
    from netsense.rl.envs import make_core

    seeds = eval_seeds(args.episodes)
    S = int(np.sum(make_core(CHANNEL_TASK, 1).is_source))  # the rules' frame: the sources
    rows = [{"policy": label, **channel_use(label, seeds, actor=actor, returns=True)}
            for label, actor in [("tdma:1", None)] + [
                (f"agent-frame slots (t - i) mod {S} in {{{', '.join(map(str, ph))}}}",
                 agent_frame_slots(ph)) for ph in CHANNEL_RULES]]
    tdma = rows[0]["returns"]
    for r in rows:
        r["vs_tdma"], r["vs_tdma_ci_low"], r["vs_tdma_ci_high"] = bootstrap_ci(
            r.pop("returns") - tdma)
    write_csv(args.out / "channel_rules.csv", rows)
    lines = ["| policy | return [95 % CI] | return IQM | minus `tdma:1`, paired [95 % CI] | "
             "steps with a collision | delivered per step |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['policy']} | {r['return']:.1f} [{r['return_ci_low']:.1f}, "
              f"{r['return_ci_high']:.1f}] | {r['return_iqm']:.1f} | {r['vs_tdma']:+.2f} "
              f"[{r['vs_tdma_ci_low']:+.2f}, {r['vs_tdma_ci_high']:+.2f}] | "
              f"{100 * r['collided_steps']:.1f} % | "
              f"{r['delivered_per_step']:.2f} |" for r in rows]
    _write(args.out / "channel_rules.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


SUBSTATES_TASK = "comm_substates-v0"


def news_pairs(task: str, spec: str, seeds: list[int], actor=None,
               control: str | None = None):
    """Each send choice of ``spec`` on ``task``'s episodes ``seeds`` paired with the news
    its agent saw when it chose (the protocol's rollout; the observation is the core's own,
    read after every step, so a choice is paired from the episode's second step on).

    A choice is what :class:`netsense.rl.policy.NewsGateActor` gates: in control mode
    ``"substates"`` the bit of substate ``j`` (substates with an empty block, which no
    agent can send, left out), news where the observation's ``news[j] > 0``; in
    ``"transmit"`` the agent's transmit bit, news where any ``news`` entry is positive.

    Returns ``(returns, news, sent, own)``: the episodes' returns, and per choice (flat
    over members, steps, agents and, per substate, substates) whether it had news, whether
    it was sent, and whether it is the agent's own substate (``"transmit"``: whether the
    agent is a source). ``control``: the control mode a scripted ``spec`` runs in on a
    task that is not communication-only (the config's ``[tasks]`` field; a learned policy
    runs in the mode it was trained in)."""
    from netsense.benchmark.protocol import evaluate

    seen, pairs, meta = [], [], []

    def record(core, live):
        per_substate = core.comm.per_substate
        if seen:
            sent = core.comm.sent if per_substate else core.transmit
            pairs.append((seen[-1][live], sent[live]))
        else:
            own = core.layout.own
            meta.append((per_substate, ~core.comm.empty,
                         own[:, None] == np.arange(core.M)[None, :] if per_substate
                         else own >= 0))
        fresh = core.observe()[0][..., core.layout.news] > 0
        seen.append(fresh if per_substate else fresh.any(-1))

    over = {"control": {"mode": control}} if control else {}
    ret = evaluate(task, spec, seeds, over, on_step=record, actor=actor)["reward"]
    per_substate, open_, own = meta[0]
    news = np.concatenate([n for n, _ in pairs])
    sent = np.concatenate([a for _, a in pairs])
    own = np.broadcast_to(own, news.shape)
    if per_substate:
        news, sent, own = news[..., open_], sent[..., open_], own[..., open_]
    return ret, news.ravel(), sent.ravel(), own.ravel()


def substate_use(spec: str, seeds: list[int], actor=None) -> dict:
    """Which substates a policy sends on :data:`SUBSTATES_TASK`, against the observation's
    ``news`` (steps by which the next message of a substate would be fresher than the last
    one sent), on the episodes ``seeds`` (:func:`news_pairs`): mean return, substates sent
    per agent-step and substate, and the probability of sending a substate without news,
    with news of the agent's own substate and with news of another agent's substate.
    ``actor``: a rule that is no registered policy (``spec`` is then its label), as
    :func:`netsense.benchmark.protocol.evaluate` takes it."""
    ret, news, sent, mine = news_pairs(SUBSTATES_TASK, spec, seeds, actor)
    return {"return": float(ret.mean()), "sent_rate": float(sent.mean()),
            "send_without_news": float(sent[~news].mean()),
            "send_own_news": float(sent[news & mine].mean()),
            "send_others_news": float(sent[news & ~mine].mean())}


def news_use(task: str, spec: str, seeds: list[int], actor=None,
             control: str | None = None) -> dict:
    """What the news gate (:class:`netsense.rl.policy.NewsGateActor`) would close of
    ``spec``'s sends on ``task``, on the episodes ``seeds`` (:func:`news_pairs`): mean
    return, sends per choice (also over the choices of the agent's own substate and of
    another's; in control mode ``"transmit"``, of sources and of relays), the share of
    choices with news, the probability of a send with news and without it, and
    ``without_news``, the share of the sends made without news (those the gate closes; 0
    for a policy the gated class contains). ``nan`` where a conditioning set is empty.
    ``control``: as :func:`news_pairs` takes it."""
    ret, news, sent, own = news_pairs(task, spec, seeds, actor, control)

    def share(num, den) -> float:
        return float(num.sum() / den.sum()) if den.any() else math.nan

    return {"return": float(ret.mean()), "send_rate": float(sent.mean()),
            "send_rate_own": share(sent & own, own), "send_rate_other": share(sent & ~own, ~own),
            "news_rate": float(news.mean()), "send_on_news": share(sent & news, news),
            "send_without_news": share(sent & ~news, ~news),
            "without_news": share(sent & ~news, sent)}


#: Columns of the substates table: (key, header, scale, decimals, unit).
SUBSTATES_COLUMNS = (("return", "return", 1, 1, ""),
                     ("sent_rate", "substates sent per agent-step and substate", 1, 3, ""),
                     ("send_without_news", "P(send) without news", 1, 2, ""),
                     ("send_own_news", "P(send) on news of its own substate", 1, 2, ""),
                     ("send_others_news", "P(send) on news of another's substate", 1, 2,
                      ""))


def cmd_substates(args, cfg: dict) -> None:
    """Why the learners stay below ``event:1`` on the per-substate task: every final
    policy of the task under ``--out`` beside ``event:1`` (send a substate iff it is news),
    on the protocol's evaluation episodes (``--episodes``)."""
    policy_use(args, SUBSTATES_TASK, substate_use, ["event:1"], SUBSTATES_COLUMNS,
               "substates")
    relay_landscape(args)


#: Relay probabilities of :func:`relay_landscape`.
RELAY_PROBS = (0.0, 0.05, 0.1, 0.2, 0.5, 1.0)
#: Probabilities of :func:`relay_landscape` with which a substate without news is sent
#: anyway: none (``event:1``'s rule), a little, and about the 20M MLP's rate (0.42 in the
#: substates table), as a policy still exploring sends.
RELAY_NOISE = (0.0, 0.1, 0.4)


def thinned_relays(p: float, q: float = 0.0, seed: int = 0):
    """An ``actor`` for :func:`netsense.benchmark.protocol.evaluate`: ``event:1``'s choice
    (send a substate iff it is news), with each send of a substate the agent does not own
    kept with probability ``p``, and each substate ``event:1`` does not send (no news) sent
    anyway with probability ``q`` where the mask allows (independently per agent, substate
    and step; ``p = 1, q = 0`` is ``event:1``)."""
    from netsense.rl.scripted import scripted_actions

    def actor(core, seeds):
        event = scripted_actions("event:1", core)
        foreign = ~(core.layout.own[:, None] == np.arange(core.M)[None, :])  # (N, M)
        rng = np.random.default_rng(seed)

        def act(obs, mask):
            base = np.asarray(event(obs, mask))
            a = base.copy()
            a[foreign & (rng.random(a.shape) >= p)] = 0
            if q > 0:  # the substates layout: head j's "send" is flat entry 2 j + 1
                allowed = np.asarray(mask, bool).reshape(*a.shape, 2)[..., 1]
                a[(base == 0) & allowed & (rng.random(a.shape) < q)] = 1
            return a

        return act

    return actor


def relay_landscape(args) -> None:
    """``substates_relay.{csv,md}``: the return of :func:`thinned_relays` for every
    :data:`RELAY_NOISE` x :data:`RELAY_PROBS` on the protocol's evaluation episodes (mean
    and 95 % bootstrap CI, standard deviation between episodes), with the substates sent
    per agent-step and substate."""
    from netsense.benchmark.intervals import bootstrap_ci
    from netsense.benchmark.protocol import eval_seeds, evaluate

    seeds = eval_seeds(args.episodes)
    rows = []
    for q in RELAY_NOISE:
        for p in RELAY_PROBS:
            m = evaluate(SUBSTATES_TASK, f"event:1, relays kept with p = {p}, sends without "
                         f"news with q = {q}", seeds, actor=thinned_relays(p, q))
            mean, lo, hi = bootstrap_ci(m["reward"])
            rows.append({"q": q, "p": p, "return": mean, "ci_low": lo, "ci_high": hi,
                         "return_sd": float(m["reward"].std()),
                         "sent_rate": float(m["load_per_agent_step"].mean())})
    write_csv(args.out / "substates_relay.csv", rows)
    lines = ["| q (a substate without news sent with probability q) | p (another agent's news "
             "sent with probability p; own news always) | return [95 % CI] | standard "
             "deviation between episodes | substates sent per agent-step and substate |",
             "|---|---|---|---|---|"]
    lines += [f"| {r['q']:g} | {r['p']:g} | {r['return']:.1f} [{r['ci_low']:.1f}, "
              f"{r['ci_high']:.1f}] | {r['return_sd']:.1f} | {r['sent_rate']:.3f} |"
              for r in rows]
    _write(args.out / "substates_relay.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


#: Task -> (the informed rule that wins there, the best rule that does not read its field).
MEMORY_TASKS = {"comm_fading-v0": ("acked(sources:0)", "event:3"),
                "comm_schedule-v0": ("phased(event:2)", "event:2")}


def probed_policy(task: str, spec: str):
    """``(overrides, actions)`` of a policy the probes below run on ``task``: ``spec`` is
    ``learned:PATH`` (greedy; its file's overrides), :data:`TWIN` or a scripted spec;
    ``actions(core)`` builds its acting function on a core."""
    from netsense.benchmark.rollouts import learned_overrides
    from netsense.rl.scripted import scripted_actions

    if spec.startswith("learned:"):
        path = spec.partition(":")[2]

        def learned(core):
            from netsense.rl.checkpoint import load_policy

            return load_policy(path, core, deterministic=True).act

        return learned_overrides(task, path, None), learned
    if spec == TWIN:
        return {}, acked_twin
    return {}, lambda core: scripted_actions(spec, core)


def memory_use(task: str, rule: str, spec: str, seeds: list[int]) -> dict:
    """How the policy ``spec`` (a scripted spec or ``learned:PATH``) decides on ``task``
    where the informed ``rule`` needs memory: on the policy's own trajectory, the rule's
    gate is computed from the agent's observations (the rule's memory of its own last
    acks, :mod:`netsense.env.comm_informed`), and every agent-step is classed by the gate
    (open: the rule would let its base speak; closed: the agent's last evidence says its
    message would be lost) and by whether that evidence is in view in the current
    observation (the agent sent at the step before, so ``acks`` are about its own last
    message) or only in memory (older). Returns the mean return (checked equal to the
    protocol's evaluation of ``spec``) and the send rate in each class: a policy that
    reads only the current observation cannot tell "closed, in memory" from "open, in
    memory" (the rows a memory makes the difference on)."""
    from netsense.benchmark.protocol import evaluate
    from netsense.env.comm_policies import make_comm_policy

    over, actions = probed_policy(task, spec)
    counts = np.zeros((2, 2, 2))  # gate open?, evidence in view?, sent?

    def actor(core, _seeds):
        act0 = actions(core)
        probe = make_comm_policy(rule, core)
        silence = core.layout.silence.start

        def act(obs, mask):
            a = np.asarray(act0(obs, mask))
            gate = probe.gate(np.asarray(obs))  # the rule's memory, on this trajectory
            view = np.asarray(obs)[..., silence] == 0
            sent = a.reshape(*gate.shape, -1).any(-1)  # (B, N)
            for g in (0, 1):
                for v in (0, 1):
                    sel = (gate == g) & (view == v)
                    counts[g, v, 1] += (sel & sent).sum()
                    counts[g, v, 0] += (sel & ~sent).sum()
            return a

        return act

    ret = evaluate(task, spec, seeds, over, actor=actor)["reward"]
    want = evaluate(task, spec, seeds)["reward"]
    if not np.allclose(ret, want, atol=1e-6):
        raise RuntimeError(f"{spec}: the probed episodes differ from the protocol's")
    rate = counts[..., 1] / np.maximum(counts.sum(-1), 1)
    share = counts.sum(-1) / counts.sum()
    return {"return": float(ret.mean()),
            "send_open_view": float(rate[1, 1]), "send_open_memory": float(rate[1, 0]),
            "send_closed_view": float(rate[0, 1]), "send_closed_memory": float(rate[0, 0]),
            "closed_share": float(share[0].sum()),
            "closed_memory_share": float(share[0, 0] / max(share[0].sum(), 1e-12))}


#: Columns of the memory table: (key, header, scale, decimals, unit).
MEMORY_COLUMNS = (("return", "return", 1, 1, ""),
                  ("send_open_view", "P(send): gate open, evidence in view", 1, 2, ""),
                  ("send_open_memory", "open, in memory", 1, 2, ""),
                  ("send_closed_view", "closed, in view", 1, 2, ""),
                  ("send_closed_memory", "closed, in memory", 1, 2, ""),
                  ("closed_share", "agent-steps with the gate closed", 100, 1, " %"),
                  ("closed_memory_share", "of them, evidence only in memory", 100, 1,
                   " %"))


def cmd_memory(args, cfg: dict) -> None:
    """Why the feed-forward learners stop below the memory rules (``acked`` on
    ``comm_fading-v0``, ``phased`` on ``comm_schedule-v0``): :func:`memory_use` of the rule,
    its base rule's best generic counterpart and every final policy of the task under
    ``--out``; writes ``memory_<task>.{csv,md}``."""
    from functools import partial

    for task, (rule, generic) in MEMORY_TASKS.items():
        if args.tasks and task not in args.tasks:
            continue
        policy_use(args, task, partial(memory_use, task, rule), [rule, generic],
                   MEMORY_COLUMNS, f"memory_{task.removesuffix('-v0')}")


#: The silence classes of :func:`reaction_use`: 1 .. 8 steps, then 9 or more.
SILENCES = tuple(range(1, 9))
#: The feed-forward twin of ``acked(sources:0)`` (:func:`acked_twin`): its label in the
#: reaction table, and the probe the rule waits for (its default knob).
TWIN = "feed-forward twin of acked(sources:0)"
TWIN_PROBE = 6


def acked_twin(core, probe: int = TWIN_PROBE):
    """``acked:probe(sources:0)`` as a function of the current observation alone: an agent
    that owns a substate sends unless its message of the step before was lost on every
    out-link that it had (``acks``) or it has been silent for 1 to ``probe - 1`` steps
    (``silence``); the others never send. Under ``sources:0`` an owner is silent only
    where the gate closed it, so its silence is the rule's memory (after a transmission
    without out-links the rule keeps its older evidence, which the twin cannot: where that
    matters the episodes differ, so the reaction table gives the twin's return beside the
    rule's; on the protocol's 100 episodes they are equal)."""
    L, H = core.layout, core.horizon
    owner = np.asarray(core.layout.own) >= 0

    def act(obs, mask):
        o = np.asarray(obs)
        sil = np.rint(o[..., L.silence.start] * H).astype(np.int64)
        acks = o[..., L.acks]
        lost = (sil == 0) & (acks < 0).any(-1) & ~(acks > 0).any(-1)
        quiet = lost | ((sil >= 1) & (sil < probe))
        return (owner[None] & ~quiet)[..., None].astype(np.int64)

    return act


#: The classes of an owner's row (:func:`row_classes`), in the tables' order.
ROW_CLASSES = ("delivered", "lost", "no_link", *(f"silent_{s}" for s in SILENCES),
               f"silent_{SILENCES[-1] + 1}_plus")


def row_classes(obs: np.ndarray, layout, horizon: int) -> np.ndarray:
    """The class (an index into :data:`ROW_CLASSES`) of every agent's current row on
    ``comm_fading-v0``: it sent at the step before and the message was ``delivered`` on some
    out-link, ``lost`` on every out-link it had, or it had ``no out-link``; or it has been
    silent ``s`` steps (the last class: more than :data:`SILENCES`)."""
    o = np.asarray(obs)
    sil = np.rint(o[..., layout.silence.start] * horizon).astype(np.int64)
    acks = o[..., layout.acks]
    good = (acks > 0).any(-1)
    lost = (acks < 0).any(-1) & ~good
    now = np.where(good, 0, np.where(lost, 1, 2))
    return np.where(sil == 0, now, 2 + np.minimum(sil, SILENCES[-1] + 1))


def reaction_use(task: str, spec: str, seeds: list[int]) -> dict:
    """What the policy ``spec`` (a scripted spec, :data:`TWIN` or ``learned:PATH``) does on
    ``task`` (``comm_fading-v0``) with what the current observation shows: each agent-step
    of an agent that owns a substate (the agents ``sources:0`` lets speak) is classed by
    its own row alone — it sent at the step before and the message was ``delivered`` on
    some out-link, ``lost`` on every out-link it had, or it had ``no out-link``; or it has
    been silent ``s`` steps — and the table gives the send rate per class and the share of
    those agent-steps in each. ``acked(sources:0)`` sends after a delivery, stays silent
    after a loss and probes at silence 6: a function of this row alone (its twin)."""
    from netsense.benchmark.protocol import evaluate

    over, actions = probed_policy(task, spec)
    classes = ROW_CLASSES
    counts = np.zeros((len(classes), 2))

    def actor(core, _seeds):
        act0 = actions(core)
        owner = np.asarray(core.layout.own) >= 0

        def act(obs, mask):
            a = np.asarray(act0(obs, mask))
            sent = a.reshape(*a.shape[:2], -1).any(-1)
            cls = row_classes(obs, core.layout, core.horizon)[:, owner]
            np.add.at(counts, (cls, sent[:, owner].astype(np.int64)), 1)
            return a

        return act

    ret = evaluate(task, "never" if spec == TWIN else spec, seeds, over, actor=actor)["reward"]
    if spec != TWIN and not np.allclose(ret, evaluate(task, spec, seeds)["reward"], atol=1e-6):
        raise RuntimeError(f"{spec}: the probed episodes differ from the protocol's")
    rate = counts[:, 1] / np.maximum(counts.sum(1), 1)
    share = counts.sum(1) / max(counts.sum(), 1)
    out = {"return": float(ret.mean())}
    for c, name in enumerate(classes):
        out[f"send_{name}"] = float(rate[c])
        out[f"share_{name}"] = float(share[c])
    return out


#: The parts of ``acked(sources:0)``'s reaction to an owner's row (:func:`acked_twin`) that
#: :func:`hybrid_use` imposes on a policy, each a map from row class to the rule's choice:
#: ``quiet``, silent after a loss and for 1 to 5 steps of silence; ``probe``, send after
#: six steps of silence or more; ``no_link``, send after a message that had no out-link.
#: (After a delivery the learners measured send already; the twin's variant adds it.)
HYBRID_PARTS = ("quiet", "probe", "no_link")


def _imposed(parts, cls: np.ndarray) -> np.ndarray:
    """The rule's choice (1 send, 0 silent) where one of ``parts`` covers the row class
    ``cls`` (:func:`row_classes`), else -1 (the policy's own choice)."""
    names = np.asarray(ROW_CLASSES)[cls]
    sil = np.where(cls >= 3, cls - 2, 0)  # steps of silence; the 9+ class counts as 9
    out = np.full(cls.shape, -1, dtype=np.int64)
    if "quiet" in parts:
        out[(names == "lost") | ((sil >= 1) & (sil < TWIN_PROBE))] = 0
    if "probe" in parts:
        out[sil >= TWIN_PROBE] = 1
    if "no_link" in parts:
        out[names == "no_link"] = 1
    if "delivered" in parts:
        out[names == "delivered"] = 1
    return out


def hybrid_use(task: str, spec: str, seeds: list[int]) -> dict:
    """The return of the policy ``spec`` on ``task`` (``comm_fading-v0``) with the parts of
    :data:`HYBRID_PARTS` in every subset imposed on the owners' rows (the rest of its
    choices its own); with the agents that own no substate silent
    (``return_others_silent``); and (``return_quiet_probe_no_link_twin``) with all three,
    sending after a delivery, and the other agents silent, which is the twin of
    ``acked(sources:0)`` whatever the policy: which changes of its reaction, alone and
    together, take a policy to the rule."""
    from itertools import combinations

    from netsense.benchmark.protocol import evaluate

    over, actions = probed_policy(task, spec)
    subsets = [c for k in range(len(HYBRID_PARTS) + 1)
               for c in combinations(HYBRID_PARTS, k)]
    out = {}
    for parts, silence_others in ([(c, False) for c in subsets]
                                  + [((), True), ((*HYBRID_PARTS, "delivered"), True)]):
        def actor(core, _seeds, parts=parts, silence_others=silence_others):
            act0 = actions(core)
            owner = np.asarray(core.layout.own) >= 0

            def act(obs, mask):
                a = np.array(act0(obs, mask))
                forced = _imposed(parts, row_classes(obs, core.layout, core.horizon))
                sel = (forced >= 0) & owner[None, :]
                a[..., 0][sel] = forced[sel]
                if silence_others:
                    a[:, ~owner] = 0
                return a

            return act

        key = ("return_others_silent" if silence_others and not parts else
               "return_" + ("_".join(parts[:len(HYBRID_PARTS)]) or "own")
               + ("_twin" if silence_others else ""))
        out[key] = float(evaluate(task, "never", seeds, over, actor=actor)["reward"].mean())
    return out


def cmd_hybrids(args, cfg: dict) -> None:
    """Which changes of the learners' reaction to their row reach ``acked(sources:0)`` on
    ``comm_fading-v0`` (:func:`hybrid_use`), beside ``never`` and the rule; writes
    ``hybrids_fading.{csv,md}``."""
    from functools import partial
    from itertools import combinations

    task = "comm_fading-v0"
    columns = [("return_own", "own", 1, 1, "")]
    for k in range(1, len(HYBRID_PARTS) + 1):
        for c in combinations(HYBRID_PARTS, k):
            columns.append(("return_" + "_".join(c), " + ".join(c).replace("_", " "), 1, 1,
                            ""))
    columns.append(("return_others_silent", "non-owners silent", 1, 1, ""))
    columns.append(("return_quiet_probe_no_link_twin", "all, others silent", 1, 1, ""))
    policy_use(args, task, partial(hybrid_use, task), ["acked(sources:0)", "never"],
               columns, "hybrids_fading")


#: Steps between the states :func:`decision_values` forks at (offset ``every // 2``).
VALUE_EVERY = 10


def decision_visits(task: str, spec: str, seeds: list[int], every: int = VALUE_EVERY
                    ) -> list[tuple]:
    """Every owner's decision at every ``every``-th step (from ``every // 2``) under
    ``spec``'s own play on ``task`` (``comm_fading-v0``), with its worth: for every agent
    that owns a substate, a fork of the episode (:func:`netsense.engine.fork.fork`, its
    realised future: the same channel, noise and graphs) where that agent alone makes the
    other choice at that step, and ``spec`` plays on. Returns ``(step, member, agent,
    row class, sent, worth)`` per decision, where ``worth`` is the undiscounted team return
    to the end of the choice made minus that of the other choice (the protocol's return
    units; ``Q(send) - Q(silent)`` of that state under ``spec`` where it sent). ``spec``
    must act on the current observation alone (a fork's policy starts without memory): a
    feed-forward ``learned:PATH`` or :data:`TWIN`."""
    from netsense.engine.core import BatchedCore
    from netsense.engine.fork import fork
    from netsense.env.vector import load_model

    if spec != TWIN and not spec.startswith("learned:"):
        raise ValueError(f"decision_visits needs a policy of the current observation alone "
                         f"(a feed-forward learned:PATH or {TWIN!r}); a scripted rule keeps "
                         f"a memory a fork does not copy, got {spec!r}")
    over, actions = probed_policy(task, spec)
    core = BatchedCore(load_model(task, **over)[0], len(seeds))
    act = actions(core)
    net = getattr(getattr(act, "__self__", None), "net", None)
    if net is not None:  # a learned policy (torch is there)
        from netsense.rl.memory import is_recurrent

        if is_recurrent(net):
            raise ValueError(f"{spec}: a recurrent policy's memory is not carried into a "
                             f"fork")
    L, H, B = core.layout, core.horizon, len(seeds)
    if core.nvec.size != 1:
        raise ValueError(f"decision_visits flips one transmit bit per agent; {task} in "
                         f"this control mode has {core.nvec.size} choices per agent")
    owners = np.flatnonzero(np.asarray(L.own) >= 0)
    obs, mask = core.reset(seeds)
    team = np.zeros((H, B))
    visits = []  # (step, member, agent, class, sent)
    forks = {}  # step -> (core of the flipped lanes, lanes' members, lanes' agents)
    for k in range(H):
        a = np.asarray(act(obs, mask))
        if k % every == every // 2:
            cls = row_classes(obs, L, H)
            sent = a.reshape(B, core.N, -1).any(-1)
            mem, ag = np.repeat(np.arange(B), len(owners)), np.tile(owners, B)
            visits += [(k, b, i, cls[b, i], sent[b, i]) for b, i in zip(mem, ag, strict=True)]
            forks[k] = (fork(core, mem), mem, ag)
        out = core.step(a)
        if out.terminated.any():
            raise RuntimeError(f"{spec}: an episode ended early (divergence) at step {k}")
        team[k] = out.reward.mean(axis=1)
        obs, mask = out.obs, out.action_mask
    to_go = np.cumsum(team[::-1], axis=0)[::-1]  # the return from step k on
    flipped = {}
    for k, (f, mem, ag) in forks.items():
        fo, fm = f.observe()
        fact, ret = actions(f), np.zeros(len(mem))
        for j in range(k, H):
            fa = np.array(fact(fo, fm))
            if j == k:
                lane = np.arange(len(mem))
                fa[lane, ag] = 1 - fa[lane, ag].reshape(len(mem), -1).any(-1)[:, None]
            step = f.step(fa)
            ret += step.reward.mean(axis=1)
            fo, fm = step.obs, step.action_mask
        for lane, (b, i) in enumerate(zip(mem, ag, strict=True)):
            flipped[k, b, i] = ret[lane]
    # per visit: the choice made minus the other one
    return [(k, b, i, int(c), bool(s), float(to_go[k, b] - flipped[k, b, i]))
            for k, b, i, c, s in visits]


def decision_values(task: str, spec: str, seeds: list[int], every: int = VALUE_EVERY
                    ) -> dict:
    """What each of an owner's decisions is worth under ``spec``'s own play on ``task``
    (``comm_fading-v0``; :func:`decision_visits`): per row class (:data:`ROW_CLASSES`),
    visits per episode (owners' agent-steps, scaled by ``every``), ``spec``'s send rate,
    the mean ``Q(send) - Q(silent)`` and its standard error, and ``gain``: what choosing
    by the class's mean value would add per episode over ``spec``'s choices in that class,
    to first order (one step of policy improvement on the class at ``spec``'s own values;
    0 unless the mean is beyond two standard errors)."""
    rows = {}
    for _k, _b, _i, c, s, diff in decision_visits(task, spec, seeds, every):
        rows.setdefault(c, []).append((diff if s else -diff, s))
    B = len(seeds)
    out = {}
    for c, name in enumerate(ROW_CLASSES):
        v = np.array([d for d, _ in rows.get(c, [])])
        s = np.array([x for _, x in rows.get(c, [])], dtype=bool)
        n = len(v)
        mean = float(v.mean()) if n else float("nan")
        out[f"visits_{name}"] = n * every / B
        out[f"send_{name}"] = float(s.mean()) if n else float("nan")
        out[f"value_{name}"] = mean
        out[f"value_se_{name}"] = float(v.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan")
        clear = n > 1 and abs(mean) > 2 * out[f"value_se_{name}"]
        wrong = ((~s).sum() if mean > 0 else s.sum()) if clear else 0
        out[f"gain_{name}"] = float(wrong * abs(mean) * every / B) if wrong else 0.0
    out["gain_total"] = sum(out[f"gain_{c}"] for c in ROW_CLASSES)
    return out


#: The row classes the values table shows (:func:`decision_values`).
VALUE_CLASSES = ("delivered", "lost", "silent_1", "silent_2", "silent_3", "silent_5",
                 "silent_6", "silent_9_plus")


def cmd_values(args, cfg: dict) -> None:
    """:func:`decision_values` of :data:`TWIN` and of every final policy of
    ``comm_fading-v0`` under ``--out`` (all its results folders), on the first 32 of the
    protocol's evaluation episodes; writes ``values_fading.csv`` (one row per policy and
    row class; ``key`` is policy and class, what the docs' tables group by; no value: an
    empty cell) and ``values_fading.md`` (learned runs: mean over the seeds [min, max])."""
    from netsense.benchmark.protocol import eval_seeds

    task = "comm_fading-v0"
    seeds = eval_seeds(min(args.episodes, 32))
    specs = [(TWIN, TWIN, "")]
    for pol in sorted(args.out.glob(f"**/runs/{task}/*/seed_*/policy.pt")):
        steps = json.loads((pol.parent / "summary.json").read_text())["agent_steps"]
        specs.append((f"learned:{pol}", f"{pol.parent.parent.name}, "
                      f"{round(steps / 1e6)}M agent-steps", str(pol.relative_to(args.out))))
    from tqdm.auto import tqdm

    rows = []
    for spec, label, run in tqdm(specs, desc="values", unit="policy",
                                 disable=args.no_progress):
        v = decision_values(task, spec, seeds)
        rows += [{"key": f"{label} / {c}", "policy": label, "run": run, "class": c,
                  "visits": v[f"visits_{c}"], "send": v[f"send_{c}"],
                  "value": v[f"value_{c}"], "value_se": v[f"value_se_{c}"],
                  "gain": v[f"gain_{c}"]} for c in ROW_CLASSES]
        rows.append({"key": f"{label} / all", "policy": label, "run": run, "class": "all",
                     "visits": float("nan"), "send": float("nan"), "value": float("nan"),
                     "value_se": float("nan"), "gain": v["gain_total"]})
    # no value: an empty cell (the docs' tables print it as a dash)
    write_csv(args.out / "values_fading.csv",
              [{k: "" if isinstance(x, float) and math.isnan(x) else x for k, x in r.items()}
               for r in rows])
    groups = {}
    for r in rows:
        groups.setdefault(r["policy"], {}).setdefault(r["class"], []).append(r)

    def cell(rs, key, d):
        x = np.array([r[key] for r in rs], dtype=float)
        if np.isnan(x).all():
            return "–"
        x = x[~np.isnan(x)]
        return f"{x.mean():+.{d}f}" if len(x) == 1 else \
            f"{x.mean():+.{d}f} [{x.min():+.{d}f}, {x.max():+.{d}f}]"

    lines = ["| policy | row | visits per episode | P(send) | Q(send) − Q(silent) | "
             "gain per episode |", "|---|---|---|---|---|---|"]
    for label, by in groups.items():
        n = len(by["all"])
        name = label + (f" ({n} seeds)" if n > 1 else "")
        for c in (*VALUE_CLASSES, "all"):
            rs = by[c]
            if c == "all":
                lines.append(f"| {name} | all rows | | | | {cell(rs, 'gain', 2)} |")
                continue
            se = np.array([r["value_se"] for r in rs], dtype=float)
            value = cell(rs, "value", 3)
            if not np.isnan(se).all():
                value += f" (± {np.nanmean(se):.3f})"
            lines.append(f"| {name} | {c.replace('_', ' ')} | "
                         f"{np.mean([r['visits'] for r in rs]):.1f} | "
                         f"{cell(rs, 'send', 2)} | {value} | {cell(rs, 'gain', 2)} |")
    _write(args.out / "values_fading.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


def cmd_reaction(args, cfg: dict) -> None:
    """What the learners on ``comm_fading-v0`` do with what the current observation shows,
    beside ``acked(sources:0)`` and its feed-forward twin (:func:`reaction_use`); writes
    ``reaction_fading.{csv,md}``."""
    from functools import partial

    task = "comm_fading-v0"
    short = ("delivered", "lost", "no_link", "silent_1", "silent_2", "silent_5",
             "silent_6", "silent_9_plus")
    columns = (("return", "return", 1, 1, ""),
               *((f"send_{c}", f"P(send): {c.replace('_', ' ')}", 1, 2, "") for c in short),
               ("share_silent_9_plus", "owner-steps silent 9+ steps", 100, 1, " %"))
    policy_use(args, task, partial(reaction_use, task), ["acked(sources:0)", TWIN], columns,
               "reaction_fading")


#: The owners' send probabilities of :func:`credit_rates`.
CREDIT_RATES = (0.5, 0.2, 0.1, 0.05, 0.02)


def credit_rates(task: str = "comm_fading-v0", rates=CREDIT_RATES, episodes: int = 128,
                 seed: int = 0) -> list[dict]:
    """What a message earns under the ``lifetime`` sender reward
    (:class:`netsense.rl.credit.LifetimeCredit`) where the agents that own a substate send
    with probability ``p`` at every step and the others never: the mean credit per message
    sent (lost ones included) against the message cost, and the team's return. Episodes
    seeded ``seed + b`` (training seeds, not the protocol's)."""
    from netsense.rl.envs import NetSenseBatchedEnv, make_core

    rows = []
    for p in rates:
        core = make_core(task, episodes, control="transmit")
        env = NetSenseBatchedEnv(core, reward="lifetime", seed=seed)
        env.restart()
        rng = np.random.default_rng(seed)
        owner = np.asarray(core.layout.own) >= 0
        earned, sent, team = 0.0, 0, np.zeros(episodes)
        for _ in range(core.horizon):
            a = ((rng.random((episodes, core.N)) < p) & owner[None])[..., None]
            a = a.astype(np.int64)
            env.lifetime_credit.before(core, a)
            out = core.step(a)
            earned += float(env.lifetime_credit.after(core).sum())
            sent += int(a.sum())
            team += out.reward.mean(axis=1)
        rows.append({"task": task, "owner_send_probability": p,
                     "credit_per_message": earned / max(sent, 1),
                     "message_cost": float(core.model.reward.message_cost),
                     "team_return": float(team.mean())})
    return rows


def cmd_credit(args, cfg: dict) -> None:
    """:func:`credit_rates` on ``comm_fading-v0``; writes ``credit_fading.{csv,md}`` into
    ``--out``."""
    rows = credit_rates()
    write_csv(args.out / "credit_fading.csv", rows)
    lines = ["| owners send with probability | lifetime credit per message | message cost | "
             "team return |", "|---|---|---|---|"]
    lines += [f"| {r['owner_send_probability']} | {r['credit_per_message']:.3f} | "
              f"{r['message_cost']:.2f} | {r['team_return']:.1f} |" for r in rows]
    _write(args.out / "credit_fading.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


#: PPOConfig fields that restrict the policy class (docs/rl.md): a learner that sets one
#: is task-specific in the standing table; inputs (clock, ages, memory) are not.
RESTRICTIONS = ("news_gate", "clock_only", "comm_fields_only")


def restriction(table: dict) -> str:
    """What a learner's config table restricts (:data:`RESTRICTIONS`), or changes in the
    reward, as text ("" for neither)."""
    out = [k.replace("_", " ") for k in RESTRICTIONS if table.get(k)]
    if table.get("reward", "team") != "team":
        out.append(f"reward {table['reward']}")
    return ", ".join(out)


def standing(root: Path, cfg: dict, recipe: str) -> list[dict]:
    """Per task, from every results folder's ``summary.csv`` under ``root`` (greedy
    evaluation, five seeds or more, from scratch: a learner whose config warm-starts with
    ``bc`` does not count): the run of ``recipe`` (the candidate for one configuration on
    every task) at its largest budget, and the best run of any learner whose interval
    reaches the best decentralised rule (else the best run of all), with its restriction
    of the policy class named (:func:`restriction`)."""
    rows = []
    for path in sorted(root.glob("*/summary.csv")):
        with path.open(newline="") as f:
            for r in csv.DictReader(f):
                scratch = "bc" not in cfg["learners"].get(r["learner"], {})
                if r["evaluation"] == "greedy" and int(r["seeds"]) >= 5 and scratch:
                    rows.append({**r, "folder": path.parent.name})
    out = []
    for task in cfg["tasks"]:
        here = [r for r in rows if r["task"] == task]
        if not here:
            continue
        mine = [r for r in here if r["learner"] == recipe]
        reach = [r for r in here if r["reaches"] == "True"]
        best = max(reach or here, key=lambda r: float(r["iqm"]))
        for role, r in (("one configuration", max(mine, key=lambda r: int(r["agent_steps"]))
                         if mine else None), ("best learner", best)):
            if r is None:
                continue
            table = cfg["learners"].get(r["learner"], {})
            out.append({"task": task, "role": role, "learner": r["learner"],
                        "folder": r["folder"], "agent_steps": int(r["agent_steps"]),
                        "budget": f"{int(r['agent_steps']) / 1e6:.1f}M",
                        "seeds": int(r["seeds"]), "iqm": float(r["iqm"]),
                        "iqm_ci_low": float(r["iqm_ci_low"]),
                        "iqm_ci_high": float(r["iqm_ci_high"]),
                        "rule": r["best_decentralised_spec"],
                        "rule_iqm": float(r["best_decentralised_iqm"]),
                        "reaches": "yes" if r["reaches"] == "True" else "no",
                        "p_improvement": float(r["p_improvement"]),
                        "restriction": restriction(table) or "none"})
    return out


def cmd_standing(args, cfg: dict) -> None:
    """:func:`standing` of every results folder under ``--out`` (default: the learners'
    results); ``--learners`` names the one configuration (default ``mlp_clock_news_gate``,
    the candidate that reaches the rule on the most tasks, docs/learned-results.md);
    writes ``standing.{csv,md}`` there."""
    recipe = (args.learners or ["mlp_clock_news_gate"])[0]
    rows = standing(args.out, cfg, recipe)
    write_csv(args.out / "standing.csv", rows)
    lines = ["| task | | learner (folder) | seeds x agent-steps | IQM [95 % CI] | best "
             "decentralised rule | reaches | restriction |", "|---" * 8 + "|"]
    lines += [f"| {r['task']} | {r['role']} | {r['learner']} ({r['folder']}) | {r['seeds']} x "
              f"{r['agent_steps'] / 1e6:.1f}M | {r['iqm']:.1f} [{r['iqm_ci_low']:.1f}, "
              f"{r['iqm_ci_high']:.1f}] | {r['rule']} {r['rule_iqm']:.1f} | "
              f"{r['reaches']} | {r['restriction']} |" for r in rows]
    _write(args.out / "standing.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


def time_to_rule(log: list[dict], rule: float) -> tuple[int, float] | None:
    """``(agent_steps, wall_s)`` of the first evaluation from which the run's greedy
    evaluation return (``eval_return``, the monitoring evaluation during training) stays at
    or above ``rule`` to the end of the run; ``None`` when its last evaluation is below.
    "Stays" rather than "touches": a curve that crosses the rule once and falls back has
    not given the user a policy that reaches it."""
    ev = [(int(r["agent_steps"]), float(r["wall_s"]), float(r["eval_return"]))
          for r in log if r.get("eval_return")]
    first = None
    for steps, wall, ret in ev:
        if ret >= rule:
            first = first or (steps, wall)
        else:
            first = None
    return first


def cmd_time(args, cfg: dict) -> None:
    """``time_to_rule.{csv,md}`` in ``--out``: per task and learner of its runs, how many
    seeds reach the best decentralised rule during training (:func:`time_to_rule`, on the
    monitoring evaluation's episodes against the rule's return on those same episodes,
    ``curve_refs.csv``) and the median agent-steps and wall-clock minutes they took."""
    out = args.out
    with (out / "curve_refs.csv").open() as fh:
        refs = {r["task"]: (r["spec"], float(r["return"])) for r in csv.DictReader(fh)
                if r["policy"] == "best_decentralised" and r["episodes"] == "validation"}
    rows = []
    for task in sorted((out / "runs").iterdir()):
        if not task.is_dir() or task.name not in refs or (args.tasks and task.name not in
                                                           args.tasks):
            continue
        spec, rule = refs[task.name]
        for learner in sorted(d for d in task.iterdir() if d.is_dir()):
            runs = seed_runs(learner)
            if not runs:
                continue
            got = [h for h in (time_to_rule(read_log(r), rule) for r in runs) if h]
            steps, minutes = ((float(np.median([h[0] for h in got])),
                               float(np.median([h[1] for h in got])) / 60) if got
                              else (float("nan"), float("nan")))
            rows.append({"task": task.name, "learner": learner.name, "rule": spec,
                         "rule_return": rule, "seeds": len(runs), "reached": len(got),
                         "agent_steps": steps, "minutes": minutes,
                         "budget": int(json.loads((runs[0] / "config.json").read_text())
                                       ["steps"]),
                         "agent_steps_text": f"{steps / 1e6:.2f}M" if got else "–",
                         "minutes_text": f"{minutes:.1f}" if got else "–"})
    if not rows:
        raise ValueError(f"{out}: no runs with a learning curve and a rule's validation "
                         "return (curve_refs.csv)")
    write_csv(out / "time_to_rule.csv", rows)
    lines = ["| task | learner | rule (validation return) | seeds that reach it and stay | "
             "median agent-steps | median minutes | budget |", "|---" * 7 + "|"]
    for r in rows:
        lines.append(f"| {r['task']} | {r['learner']} | `{r['rule']}` ({r['rule_return']:.1f})"
                     f" | {r['reached']} of {r['seeds']} | {r['agent_steps_text']} | "
                     f"{r['minutes_text']} | {r['budget'] / 1e6:.0f}M |")
    _write(out / "time_to_rule.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


def policy_use(args, task: str, measure, scripted: list[str], columns, name: str) -> None:
    """``measure(spec, seeds)`` for the ``scripted`` specs and every final policy of
    ``task`` under ``--out`` (all its results folders), on the protocol's evaluation
    episodes (:func:`policy_rows`); writes ``name.csv`` (one row per policy, a learned
    one's ``run`` its file relative to ``--out``) and ``name.md`` (:func:`policy_table`)."""
    write_policy_table(args.out, name, policy_rows(args, task, measure, scripted, name),
                       columns)


def write_policy_table(out: Path, name: str, rows: list[dict], columns,
                       keys: tuple[str, ...] = ()) -> None:
    """``name.csv`` (the ``rows``) and ``name.md`` (:func:`policy_table` of them, with
    ``columns`` and ``keys``) in ``out``; the table is printed too."""
    write_csv(out / f"{name}.csv", rows)
    lines = policy_table(rows, columns, keys)
    _write(out / f"{name}.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


def policy_rows(args, task: str, measure, scripted: list[str], name: str) -> list[dict]:
    """``measure(spec, seeds)`` for the ``scripted`` specs and every final policy of
    ``task`` under ``--out`` (all its results folders), on the protocol's evaluation
    episodes (a progress bar ``name`` over the policies): one row per policy, ``policy``
    the spec of a scripted one and ``"<learner>, <budget>M agent-steps"`` of a learned one,
    whose ``run`` is its file relative to ``--out``."""
    from netsense.benchmark.protocol import eval_seeds

    seeds = eval_seeds(args.episodes)
    specs = [(spec, "scripted") for spec in scripted]
    for pol in sorted(args.out.glob(f"**/runs/{task}/*/seed_*/policy.pt")):
        steps = json.loads((pol.parent / "summary.json").read_text())["agent_steps"]
        specs.append((f"learned:{pol}", f"{pol.parent.parent.name}, "
                      f"{round(steps / 1e6)}M agent-steps"))
    from tqdm.auto import tqdm

    rows = []
    for spec, label in tqdm(specs, desc=name, unit="policy", disable=args.no_progress):
        run = Path(spec.partition(":")[2]).relative_to(args.out) if label != "scripted" else ""
        rows.append({"policy": spec if label == "scripted" else label, "run": str(run),
                     **measure(spec, seeds)})
    return rows


def policy_table(rows: list[dict], columns, keys: tuple[str, ...] = ()) -> list[str]:
    """Markdown lines of :func:`policy_rows`' ``rows``: one line per scripted policy and
    per learner (its runs grouped: mean over the seeds [min, max]), the ``columns``
    ``(key, header, scale, decimals, unit)``; ``keys``: row fields to group by and lead
    the line with (the task, say) before the policy."""
    groups = {}
    for r in rows:
        groups.setdefault((*(r[k] for k in keys), r["policy"]), []).append(r)
    lines = ["| " + "".join(f"{k} | " for k in keys) + "policy (runs: mean over seeds "
             "[min, max]) | " + " | ".join(c[1] for c in columns) + " |",
             "|---" * (len(keys) + len(columns) + 1) + "|"]
    for (*lead, label), rs in groups.items():
        cells = []
        for key, _, scale, d, unit in columns:
            v = np.array([r[key] for r in rs], dtype=float) * scale
            if np.isnan(v).all():
                cells.append("–")
                continue
            cells.append(f"{np.nanmean(v):.{d}f}" + (
                f" [{np.nanmin(v):.{d}f}, {np.nanmax(v):.{d}f}]" if len(v) > 1 else "")
                + unit)
        if rs[0]["run"]:
            label += f" ({len(rs)} seed" + "s" * (len(rs) > 1) + ")"
        lines.append("| " + "".join(f"{x} | " for x in lead) + f"{label} | "
                     + " | ".join(cells) + " |")
    return lines


#: Columns of the news table: (key, header, scale, decimals, unit).
NEWS_COLUMNS = (("return", "return", 1, 1, ""),
                ("send_rate", "sends per choice", 1, 3, ""),
                ("send_rate_own", "own substate (transmit: source)", 1, 3, ""),
                ("send_rate_other", "another's (transmit: relay)", 1, 3, ""),
                ("news_rate", "choices with news", 100, 1, " %"),
                ("send_on_news", "P(send) on news", 1, 2, ""),
                ("send_without_news", "P(send) without news", 1, 2, ""),
                ("without_news", "sends without news (closed by the gate)", 100, 1, " %"))


def cmd_news(args, cfg: dict) -> None:
    """What the news gate closes: on every task (``--tasks``, default the config's), the
    task's best decentralised rule and every final policy of the task under ``--out``,
    measured by :func:`news_use` on the protocol's evaluation episodes (``--episodes``);
    writes ``news_sends.{csv,md}`` there."""
    from functools import partial

    rows = []
    for task in args.tasks or cfg["tasks"]:
        measure = partial(news_use, task, control=cfg["tasks"][task].get("control"))
        rows += [{"task": task, **r} for r in policy_rows(
            args, task, measure, [best_decentralised(task)], task)]
    write_policy_table(args.out, "news_sends", rows, NEWS_COLUMNS, keys=("task",))


# %% where the curves cross
def level_points(x: np.ndarray, y: np.ndarray, level: float) -> tuple[float, float]:
    """``(last x where y <= level, first x where y > level)`` of a curve, nan where there
    is none: where a validation curve was last at or below a return and first above it
    (the two differ where the curve crosses the level more than once)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if x.shape != y.shape or x.ndim != 1:
        raise ValueError(f"x and y must be one curve of equal length, got shapes "
                         f"{x.shape} and {y.shape}")
    low, high = np.flatnonzero(y <= level), np.flatnonzero(y > level)
    return (float(x[low[-1]]) if low.size else math.nan,
            float(x[high[0]]) if high.size else math.nan)


def seed_points(log: list[dict], at: list[int], column: str = "eval_return") -> list[float]:
    """A run's ``column`` (by default its validation, greedy evaluation, return) at the
    last row at or before each of ``at`` (agent-steps) where the column has a value, from
    its ``log.csv`` rows; nan before the first."""
    if log and column not in log[0]:
        raise ValueError(f"log.csv has no column {column!r}; it has {', '.join(log[0])}")
    ev = [(int(r["agent_steps"]), float(r[column])) for r in log if r.get(column)]
    return [next((v for s, v in reversed(ev) if s <= a), math.nan) for a in at]


def cmd_curve_points(args, cfg: dict) -> None:
    """Where the validation curves of ``--out`` cross ``--levels`` and, with ``--at``,
    each seed's validation return at those agent-steps (``curve_points.{csv,md}``)."""
    path = args.out / "curves.csv"
    if not path.is_file():
        raise SystemExit(f"curve-points: {path} does not exist (the results or summary "
                         f"command writes it)")
    if not args.levels and not args.at:
        raise SystemExit("curve-points: give --levels (returns) or --at (agent-steps)")
    if args.at and sorted(args.at) != list(args.at):
        raise SystemExit(f"curve-points: --at must be increasing agent-steps, got {args.at}")
    with path.open() as fh:
        curve_rows = list(csv.DictReader(fh))
    keys = list(dict.fromkeys((r["task"], r["learner"]) for r in curve_rows))
    if args.tasks:
        keys = [k for k in keys if k[0] in args.tasks]
    if args.learners:
        keys = [k for k in keys if k[1] in args.learners]
    if not keys:
        raise SystemExit(f"curve-points: no curve of the given --tasks/--learners in {path}")
    rows, lines = [], []
    for task, learner in keys:
        c = [r for r in curve_rows if (r["task"], r["learner"]) == (task, learner)]
        x = np.array([float(r["agent_steps"]) for r in c])
        y = np.array([float(r["iqm"]) for r in c])
        for level in args.levels or []:
            last, first = level_points(x, y, level)
            rows.append({"task": task, "learner": learner, "what": "validation IQM",
                         "level": level, "last_at_or_below": last, "first_above": first})
            lines.append(f"| {task} | {learner} | {level:g} | {_msteps(last)} | "
                         f"{_msteps(first)} |")
    seed_lines = []
    for task, learner in keys if args.at else []:
        runs = seed_runs(args.out / "runs" / task / learner)
        values = [seed_points(read_log(d), args.at, args.column) for d in runs]
        for d, v in zip(runs, values, strict=True):
            rows.append({"task": task, "learner": learner, "what": "per seed",
                         "seed": int(d.name.removeprefix("seed_")),
                         "column": args.column,
                         **{f"at_{a}": r for a, r in zip(args.at, v, strict=True)}})
        higher = [sum(v[j + 1] > v[j] for v in values) for j in range(len(args.at) - 1)]
        seed_lines.append(
            f"| {task} | {learner} | "
            + " | ".join(", ".join(f"{v[j]:.2f}" for v in values)
                         for j in range(len(args.at)))
            + "".join(f" | {h} of {len(values)}" for h in higher) + " |")
    md = []
    if lines:
        md += ["Validation IQM over the seeds (`curves.csv`): the last evaluation at or "
               "below each level and the first above it (agent-steps).", "",
               "| task | learner | level | last at or below | first above |",
               "|---|---|---|---|---|", *lines, ""]
    if seed_lines:
        at = [_msteps(a) for a in args.at]
        md += [f"Each seed's `{args.column}` at the last row at or before each step that "
               "has one (`log.csv` of its run), seeds in order.", "",
               "| task | learner | " + " | ".join(f"at {a}" for a in at)
               + "".join(f" | higher at {b} than at {a}" for a, b in zip(at, at[1:], strict=False))
               + " |",
               "|---|---|" + "---|" * (2 * len(at) - 1), *seed_lines, ""]
    stem = "curve_points" if args.column == "eval_return" else f"curve_points_{args.column}"
    write_csv(args.out / f"{stem}.csv", rows)
    _write(args.out / f"{stem}.md", "\n".join(md))
    print("\n".join(md))
    print(f"wrote {args.out / stem}.csv and {stem}.md")


def _msteps(steps: float) -> str:
    return "-" if math.isnan(steps) else f"{steps / 1e6:.1f}M"


COMMANDS = {"results": cmd_results, "summary": cmd_summary, "ablation": cmd_ablation,
            "diagnose": cmd_diagnose, "channel": cmd_channel, "substates": cmd_substates,
            "memory": cmd_memory, "reaction": cmd_reaction, "hybrids": cmd_hybrids,
            "values": cmd_values, "credit": cmd_credit, "standing": cmd_standing,
            "time-to-rule": cmd_time, "news-sends": cmd_news,
            "curve-points": cmd_curve_points}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("command", choices=tuple(COMMANDS))
    p.add_argument("--config", type=Path, default=CONFIG)
    p.add_argument("--tasks", nargs="+")
    p.add_argument("--learners", nargs="+", help="learners (results) or variants (ablation)")
    p.add_argument("--seeds", type=int, nargs="+")
    p.add_argument("--steps", type=int, help="agent-steps per run (default: the config's)")
    p.add_argument("--eval-interval", type=int,
                   help="PPO iterations between the learning curve's evaluations (default: "
                        "the config's)")
    p.add_argument("--episodes", type=int, default=EPISODES,
                   help="protocol evaluation episodes (default: 100)")
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument("--retrain", action="store_true")
    p.add_argument("--workers", type=int, default=1,
                   help="training processes at once (one core each; default 1)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--refresh-references", action="store_true",
                   help="summary: evaluate the references again (the suite's best "
                        "decentralised rule, the lookaheads, the upper bound) and rewrite "
                        "them into episodes.csv before summarising")
    p.add_argument("--levels", type=float, nargs="+",
                   help="curve-points: returns whose crossing by the validation IQM to find")
    p.add_argument("--at", type=int, nargs="+",
                   help="curve-points: agent-steps at which to read each seed's --column "
                        "(increasing)")
    p.add_argument("--column", default="eval_return",
                   help="curve-points: the log.csv column --at reads (default eval_return, "
                        "the validation return)")
    args = p.parse_args(argv)
    cfg = load_config(args.config)
    COMMANDS[args.command](args, cfg)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
