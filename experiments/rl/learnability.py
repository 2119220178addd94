"""Learnability of the causal bound's decisions: how much of its headroom a decentralised
policy can see from its own observation.

``reference:causal`` (:mod:`netsense.benchmark.lookahead`) reads the whole simulation state
and beats the best decentralised scripted policy. This script asks how much of that a policy
that reads only one agent's observation could reproduce. Per communication task:

1. **Record.** The causal bound at its default :class:`~netsense.benchmark.lookahead_config.
   LookaheadConfig`, continuing with the policies the committed frontier chose for it (the
   ``knob`` of the task's ``reference:causal`` row of ``--frontier``), acts on ``--episodes``
   training episodes seeded ``TRAIN_SEED0 + e`` (below the protocol's
   ``TRAIN_SEED_LIMIT``, disjoint from its evaluation seeds; checked), built exactly as
   :func:`netsense.benchmark.protocol.evaluate` builds it (``BatchedCore(model, B,
   chunk=1)``, ``LookaheadReference``, ``core.reset(seeds)``, ``core.step(bound.act(obs,
   mask))``) in batches of :data:`BATCH` episodes. Recorded per step and agent: the
   agent's own flat observation (``core.layout``), its action mask and the bound's bits
   (one per agent, or per agent and substate in ``substates`` mode). ``message_cost-v0/v1``
   run in their communication-only ``transmit`` mode
   (:func:`netsense.benchmark.protocol.frontier_overrides`), as in the frontier.
2. **Classify.** A sample is one *free* decision: an (agent, step, bit) whose mask allows
   both 0 and 1 (a forced bit says nothing about what an agent can see); in ``substates``
   mode the features end with the one-hot of the substate. Features: (a) the agent's
   current observation; (b) its last :data:`HISTORY` observations stacked (newest first,
   zeros before the episode start). Episodes, not steps, are split: the last fifth is the
   test set, the fifth before it the validation set, the rest the training set. Two
   standard models are fitted on the training episodes by maximum likelihood (plain
   behavioural cloning, no class weights): ``logistic`` (``StandardScaler`` then
   ``LogisticRegression``) and ``hgb`` (``HistGradientBoostingClassifier``); the one of the
   higher balanced accuracy on the validation episodes is kept and scored on the test
   episodes (``balanced_accuracy_score``; the majority class scores 0.5; ROC AUC beside
   it).
3. **Clone.** The kept classifier (fitted on the training episodes only) acts for every
   agent on its own observation (history for (b)), its bits masked by the action mask, on
   the protocol's ``--eval-episodes`` evaluation seeds through
   :func:`netsense.benchmark.protocol.evaluate` (``actor=``). Its return is compared with
   the causal bound's and the best decentralised scripted policy's in ``--frontier``
   (the bound on the first 20 evaluation seeds, the scripted policies on 100): the
   fraction of the headroom it recovers is ``(clone - best decentralised) / (bound - best
   decentralised)`` (its interval: the clone's bootstrap interval mapped the same way,
   the references taken as fixed).

Writes into ``experiments/results/rl/learnability/``: ``learnability.csv`` (one row per
task, :data:`COLUMNS`), ``learnability.md`` (the table) and ``learnability.png`` (balanced
accuracy and headroom recovered per task). Run (23 min at the defaults, measured on one
core while two other jobs shared the two-core machine; ``--smoke`` for a seconds-long
check on a 12-step horizon)::

    NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 python experiments/rl/learnability.py
"""

# %%
from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from netsense.benchmark import protocol as pr
from netsense.benchmark.lookahead_config import LookaheadConfig

RESULTS = Path(__file__).resolve().parents[1] / "results" / "rl" / "learnability"
FRONTIER = RESULTS.parent / "comm_bounds" / "frontier.csv"
TASKS = ("comm_process_noise-v0", "comm_substates-v0", "comm_channel_k2-v0",
         "message_cost-v0", "message_cost-v1", "comm_announced-v0", "comm_fading-v0",
         "comm_schedule-v0", "comm_schedule-v1")
#: Observations stacked in the features of (b).
HISTORY = 4
#: First training seed: below the protocol's TRAIN_SEED_LIMIT, so never an evaluation seed.
TRAIN_SEED0 = 900_000
#: Episodes the bound runs at once (the frontier's bound_episodes, whose cost is measured).
BATCH = pr.DEFAULT_REFERENCE_EPISODES
#: Training episodes per task by default: the causal bound costs about 70 s per episode of
#: all nine tasks together on one core of the two-core machine (comm_substates-v0 and
#: comm_announced-v0 most), so with the classifiers and the clones about 30 min.
EPISODES = 20
MODELS = ("logistic", "hgb")
FEATURES = {"a": 1, "b": HISTORY}
COLUMNS = (
    ("task", "control", "continuation", "episodes", "train_seed_first", "train_seed_last",
     "train_episodes", "val_episodes", "test_episodes", "agent_steps", "decisions",
     "positive_share", "bound_train_return")
    + tuple(f"{c}_{f}" for f in FEATURES
            for c in ("model", "balanced_accuracy", "roc_auc", "val_logistic", "val_hgb",
                      "clone_return_mean", "clone_return_ci_low", "clone_return_ci_high",
                      "clone_msgs", "recovered", "recovered_ci_low", "recovered_ci_high"))
    + ("eval_episodes", "eval_seed_first", "eval_seed_last", "bound_return",
       "bound_episodes", "bound_msgs", "best_decentralised", "best_decentralised_return",
       "headroom", "seconds_bound", "seconds_fit", "seconds_eval"))


# %% The references of the committed frontier
def read_frontier(path: str | Path) -> list[dict]:
    """The rows of a frontier CSV (``experiments/rl/comm_bounds.py``) as dicts."""
    with Path(path).open(newline="") as fh:
        return list(csv.DictReader(fh))


def references(task: str, rows: Sequence[dict]) -> dict:
    """The causal bound's row of ``task`` (its continuation, return, episodes and messages)
    and the best decentralised scripted point (highest ``reward_mean``); NaN and
    ``continuation = None`` where the frontier lacks them."""
    mine = [r for r in rows if r["scenario"] == task]
    bound = next((r for r in mine if r["policy"] == "reference:causal"), None)
    dec = [r for r in mine if r["kind"] == "decentralised"]
    best = max(dec, key=lambda r: float(r["reward_mean"])) if dec else None
    nan = float("nan")
    return {
        "continuation": tuple(bound["knob"].split(" + ")) if bound else None,
        "bound_return": float(bound["reward_mean"]) if bound else nan,
        "bound_episodes": int(bound["episodes"]) if bound else 0,
        "bound_msgs": float(bound["msgs_per_agent_step_mean"]) if bound else nan,
        "best_decentralised": best["policy"] if best else "",
        "best_decentralised_return": float(best["reward_mean"]) if best else nan,
    }


# %% Recording the bound
def record(task: str, seeds: Sequence[int], config: LookaheadConfig,
           overrides: dict | None = None, batch: int = BATCH, progress: bool = True
           ) -> dict[str, np.ndarray]:
    """Roll the causal bound out on ``seeds`` and record every step.

    Built as :func:`netsense.benchmark.protocol.evaluate` builds a bound, at most
    ``batch`` episodes at a time (in groups of equal size).

    Returns
    -------
    dict
        ``obs`` (E, T, N, F) float32, ``mask`` (E, T, N, 2W) int8, ``bits`` (E, T, N, W)
        int8, ``live`` (E, T) bool (the step counts: the episode had not ended before it),
        ``reward`` (E,) the episode return (mean over agents), ``seconds``.
    """
    from tqdm.auto import tqdm

    from netsense.benchmark.lookahead import LookaheadReference
    from netsense.engine.core import BatchedCore
    from netsense.env.vector import load_model

    t0 = time.perf_counter()
    seeds = [int(s) for s in seeds]
    model, _ = load_model(task, **dict(overrides or {}))
    parts = []
    groups = [g.tolist() for g in np.array_split(seeds, math.ceil(len(seeds) / batch))]
    horizon = None
    bar = None
    for group in groups:
        core = BatchedCore(model, len(group), chunk=1)  # (a resampled fork needs chunk=1)
        bound = LookaheadReference(core, config, group)
        obs, mask = core.reset(group)
        if bar is None:
            horizon = core.horizon
            bar = tqdm(total=horizon * len(groups), desc=f"bound {task}", unit="step",
                       leave=False, disable=not progress)
        live = np.ones(len(group), dtype=bool)
        rew = np.zeros(len(group))
        steps: dict[str, list] = {"obs": [], "mask": [], "bits": [], "live": []}
        while live.any():
            bits = bound.act(obs, mask)
            steps["obs"].append(obs.astype(np.float32))
            steps["mask"].append(mask.astype(np.int8))
            steps["bits"].append(np.asarray(bits, dtype=np.int8))
            steps["live"].append(live.copy())
            out = core.step(bits)
            rew[live] += out.reward.mean(1)[live]
            live &= ~(out.terminated | out.truncated)
            obs, mask = out.obs, out.action_mask
            bar.update()
        part = {k: np.stack(v, axis=1) for k, v in steps.items()}  # (B, T, ...)
        part["reward"] = rew
        parts.append(part)
    bar.close()
    T = max(p["obs"].shape[1] for p in parts)
    out = {}
    for k in ("obs", "mask", "bits", "live"):  # pad to the longest (dead steps: live=False)
        out[k] = np.concatenate([np.pad(p[k], [(0, 0), (0, T - p[k].shape[1])]
                                        + [(0, 0)] * (p[k].ndim - 2)) for p in parts])
    out["reward"] = np.concatenate([p["reward"] for p in parts])
    out["seconds"] = time.perf_counter() - t0
    return out


# %% Features and samples
def stack_history(seq: np.ndarray, history: int) -> np.ndarray:
    """``(T, ..., F) -> (T, ..., history * F)``: at each step the observation and the
    ``history - 1`` before it, newest first, zeros before the first step."""
    T = seq.shape[0]
    pad = np.concatenate([np.zeros((history - 1,) + seq.shape[1:], seq.dtype), seq])
    return np.concatenate([pad[history - 1 - j:history - 1 - j + T] for j in range(history)],
                          axis=-1)


def with_substate(feats: np.ndarray, width: int) -> np.ndarray:
    """``(..., F) -> (..., W, F + W)`` with the one-hot of the bit's substate appended
    (``W = 1``: ``(..., 1, F)``, nothing appended)."""
    rep = np.repeat(feats[..., None, :], width, axis=-2)
    if width == 1:
        return rep
    eye = np.broadcast_to(np.eye(width, dtype=feats.dtype), feats.shape[:-1] + (width, width))
    return np.concatenate([rep, eye], axis=-1)


def free_bits(mask: np.ndarray) -> np.ndarray:
    """``(..., 2W) -> (..., W)``: the bits whose mask allows both 0 and 1."""
    return (mask[..., 0::2] > 0) & (mask[..., 1::2] > 0)


def samples(rec: dict[str, np.ndarray], history: int
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Features ``X``, bits ``y`` and episode ids of every free decision of ``rec``."""
    W = rec["bits"].shape[-1]
    feats = np.moveaxis(stack_history(np.moveaxis(rec["obs"], 1, 0), history), 0, 1)
    keep = free_bits(rec["mask"]) & rec["live"][:, :, None, None]  # (E, T, N, W)
    e, t, i, j = np.nonzero(keep)
    X = feats[e, t, i]
    if W > 1:  # as with_substate: the features, then the substate's one-hot
        X = np.concatenate([X, np.eye(W, dtype=X.dtype)[j]], axis=1)
    return X, rec["bits"][e, t, i, j].astype(np.int64), e


def split_episodes(episodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Training, validation and test episode ids: the last fifth (at least one) is the
    test set, the fifth before it the validation set (empty when fewer than two episodes
    would be left to train on: then models are compared on the training episodes)."""
    if episodes < 2:
        raise ValueError(f"need at least 2 episodes to hold one out, got {episodes}")
    n_test = max(1, round(episodes / 5))
    n_val = max(1, round(episodes / 5)) if episodes - n_test >= 3 else 0
    ids = np.arange(episodes)
    n_train = episodes - n_test - n_val
    return ids[:n_train], ids[n_train:n_train + n_val], ids[n_train + n_val:]


# %% Classifiers
def make_model(name: str):
    """The unfitted classifier ``name`` (:data:`MODELS`)."""
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.linear_model import LogisticRegression
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    if name == "logistic":
        return make_pipeline(StandardScaler(), LogisticRegression(max_iter=1000))
    if name == "hgb":
        return HistGradientBoostingClassifier(random_state=0)
    raise ValueError(f"model must be one of {MODELS}, got {name!r}")


def fit_classifier(X: np.ndarray, y: np.ndarray, episode: np.ndarray, train: np.ndarray,
                   val: np.ndarray, test: np.ndarray) -> dict:
    """Fit every model of :data:`MODELS` on the ``train`` episodes, keep the one of the
    higher balanced accuracy on ``val`` (on ``train`` if ``val`` is empty; ties: the
    first) and score it on ``test``.

    A training set with one class gets a constant classifier (``DummyClassifier``, model
    ``"constant"``).

    Returns
    -------
    dict
        ``model`` (name), ``estimator`` (fitted), ``balanced_accuracy`` and ``roc_auc`` on
        the test episodes (NaN without test samples; AUC NaN with one class),
        ``val_<model>`` (validation balanced accuracy of each model).
    """
    from sklearn.dummy import DummyClassifier
    from sklearn.metrics import balanced_accuracy_score, roc_auc_score

    tr, va, te = (np.isin(episode, ids) for ids in (train, val, test))
    if not va.any():
        va = tr
    out: dict = {f"val_{m}": float("nan") for m in MODELS}
    if np.unique(y[tr]).size < 2:
        out["model"] = "constant"
        out["estimator"] = DummyClassifier(strategy="most_frequent").fit(X[tr], y[tr])
    else:
        fitted = {}
        for name in MODELS:
            fitted[name] = make_model(name).fit(X[tr], y[tr])
            out[f"val_{name}"] = float(balanced_accuracy_score(
                y[va], fitted[name].predict(X[va])))
        out["model"] = max(MODELS, key=lambda m: (out[f"val_{m}"], -MODELS.index(m)))
        out["estimator"] = fitted[out["model"]]
    est = out["estimator"]
    out["balanced_accuracy"] = out["roc_auc"] = float("nan")
    if te.any():
        import warnings

        with warnings.catch_warnings():  # one class in y_true: recall of that class
            warnings.simplefilter("ignore", UserWarning)
            out["balanced_accuracy"] = float(balanced_accuracy_score(y[te],
                                                                     est.predict(X[te])))
        if np.unique(y[te]).size == 2:
            out["roc_auc"] = float(roc_auc_score(y[te], est.predict_proba(X[te])[:, 1]))
    return out


# %% The cloned decentralised policy
def clone_actor(estimator, history: int, width: int
                ) -> Callable[[object, Sequence[int]], Callable]:
    """An ``actor`` for :func:`netsense.benchmark.protocol.evaluate`: every agent's bits
    are ``estimator``'s prediction from its own last ``history`` observations (the
    features of :func:`samples`), then masked (a bit the mask forbids is 0; a bit whose 0
    is forbidden is 1)."""

    def actor(core, seeds):
        buf: list[np.ndarray] = []

        def act(obs, mask):
            nonlocal buf
            if (core.k == 0).all():
                buf = []
            buf = (buf + [np.asarray(obs, dtype=np.float32)])[-history:]
            seq = np.stack([np.zeros_like(buf[0])] * (history - len(buf)) + buf)
            feats = with_substate(stack_history(seq, history)[-1], width)  # (B, N, W, F')
            pred = estimator.predict(feats.reshape(-1, feats.shape[-1]))
            pred = pred.reshape(feats.shape[:-1]).astype(np.int64)
            on, off = mask[..., 1::2] > 0, mask[..., 0::2] > 0
            return np.where(on & off, pred, on.astype(np.int64))

        return act

    return actor


def recovered(clone: float, bound: float, reference: float) -> float:
    """``(clone - reference) / (bound - reference)``: the fraction of the headroom of
    ``bound`` over ``reference`` that ``clone`` recovers (NaN without positive headroom)."""
    gap = bound - reference
    if not (math.isfinite(gap) and gap > 0):
        return float("nan")
    return (clone - reference) / gap


# %% One task
def run_task(task: str, frontier: Sequence[dict], episodes: int, eval_episodes: int,
             horizon: int | None = None, progress: bool = True) -> dict:
    """Record, classify and clone on ``task`` (module docstring); one row of
    :data:`COLUMNS`. ``horizon`` overrides the episode length (the smoke run: the
    frontier's returns, of full-length episodes, are then not comparable and left NaN,
    and a task the frontier lacks continues with the default continuation)."""
    over = pr.frontier_overrides(task, None if horizon is None else {"horizon": horizon})
    ref = references(task, frontier)
    if ref["continuation"] is None:
        if horizon is None:
            raise ValueError(f"the frontier has no reference:causal row for {task}: run "
                             "experiments/rl/comm_bounds.py first")
        ref["continuation"] = LookaheadConfig().continuation  # smoke run only
    if horizon is not None:  # the frontier's returns are of full-length episodes
        ref.update(bound_return=float("nan"), bound_msgs=float("nan"),
                   best_decentralised_return=float("nan"))
    config = LookaheadConfig(continuation=ref["continuation"])
    train_seeds = list(range(TRAIN_SEED0, TRAIN_SEED0 + episodes))
    seeds = pr.eval_seeds(eval_episodes)
    pr.check_disjoint(train_seeds, seeds)
    pr.check_disjoint(train_seeds, pr.eval_seeds())
    rec = record(task, train_seeds, config, over, progress=progress)
    t1 = time.perf_counter()
    train, val, test = split_episodes(episodes)
    width = rec["bits"].shape[-1]
    row = {"task": task, "control": pr._mode(task, over),
           "continuation": " + ".join(config.continuation), "episodes": episodes,
           "train_seed_first": train_seeds[0], "train_seed_last": train_seeds[-1],
           "train_episodes": len(train), "val_episodes": len(val),
           "test_episodes": len(test),
           "agent_steps": int(rec["live"].sum()) * rec["obs"].shape[2],
           "bound_train_return": float(rec["reward"].mean()),
           **{k: v for k, v in ref.items() if k != "continuation"},
           "headroom": ref["bound_return"] - ref["best_decentralised_return"],
           "eval_episodes": eval_episodes, "eval_seed_first": seeds[0],
           "eval_seed_last": seeds[-1], "seconds_bound": rec["seconds"]}
    fits = {}
    for f, h in FEATURES.items():
        X, y, episode = samples(rec, h)
        row["decisions"], row["positive_share"] = len(y), float(y.mean()) if len(y) else 0.0
        fits[f] = fit_classifier(X, y, episode, train, val, test)
        row.update({f"{k}_{f}": v for k, v in fits[f].items() if k != "estimator"})
    row["seconds_fit"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    for f, h in FEATURES.items():
        vals = pr.evaluate(task, f"clone:{f}", seeds, over,
                           actor=clone_actor(fits[f]["estimator"], h, width))
        mean, lo, hi = pr.bootstrap_ci(vals["reward"])
        row.update({f"clone_return_mean_{f}": mean, f"clone_return_ci_low_{f}": lo,
                    f"clone_return_ci_high_{f}": hi,
                    f"clone_msgs_{f}": float(vals["msgs_per_agent_step"].mean())})
        for key, v in (("recovered", mean), ("recovered_ci_low", lo),
                       ("recovered_ci_high", hi)):
            row[f"{key}_{f}"] = recovered(v, ref["bound_return"],
                                          ref["best_decentralised_return"])
    row["seconds_eval"] = time.perf_counter() - t2
    return row


# %% Outputs
def _cell(v) -> str:
    if isinstance(v, float):
        return "nan" if not math.isfinite(v) else f"{v:.6g}"
    return str(v)


def write_csv(rows: Sequence[dict], path: Path) -> None:
    """``learnability.csv``: :data:`COLUMNS`, one row per task."""
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow([_cell(r[c]) for c in COLUMNS])


def markdown(rows: Sequence[dict]) -> str:
    """The table of ``learnability.md``."""

    def num(v, fmt="{:.3f}"):
        return "–" if not math.isfinite(v) else fmt.format(v)

    def ret(r, f):
        return (f"{num(r[f'clone_return_mean_{f}'], '{:.2f}')} "
                f"[{num(r[f'clone_return_ci_low_{f}'], '{:.2f}')}, "
                f"{num(r[f'clone_return_ci_high_{f}'], '{:.2f}')}]")

    lines = ["| task | episodes | agent-steps | free decisions | positive share | "
             "balanced acc. (a) | balanced acc. (b) | model (a) / (b) | clone return (a) | "
             "clone return (b) | bound return | best decentralised | "
             "headroom recovered (a) / (b) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['task']} | {r['episodes']} | {r['agent_steps']} | {r['decisions']} | "
            f"{num(r['positive_share'])} | {num(r['balanced_accuracy_a'])} | "
            f"{num(r['balanced_accuracy_b'])} | {r['model_a']} / {r['model_b']} | "
            f"{ret(r, 'a')} | {ret(r, 'b')} | {num(r['bound_return'], '{:.2f}')} | "
            f"{r['best_decentralised']} {num(r['best_decentralised_return'], '{:.2f}')} | "
            f"{num(r['recovered_a'], '{:.1%}')} / {num(r['recovered_b'], '{:.1%}')} |")
    return "\n".join(lines) + "\n"


def details(rows: Sequence[dict]) -> str:
    """The second table of ``learnability.md``: ROC AUC, each model's validation balanced
    accuracy, messages per agent-step, the bound's return on the training episodes and the
    wall time of each part."""

    def num(v, fmt="{:.3f}"):
        return "–" if not math.isfinite(v) else fmt.format(v)

    lines = ["| task | continuation | ROC AUC (a) / (b) | validation logistic / hgb (a) | "
             "validation logistic / hgb (b) | msgs / agent-step: bound, clone (a), (b) | "
             "bound return, training episodes | s: bound, fit, clone |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['task']} | {r['continuation']} | {num(r['roc_auc_a'])} / "
            f"{num(r['roc_auc_b'])} | {num(r['val_logistic_a'])} / {num(r['val_hgb_a'])} | "
            f"{num(r['val_logistic_b'])} / {num(r['val_hgb_b'])} | "
            f"{num(r['bound_msgs'])}, {num(r['clone_msgs_a'])}, {num(r['clone_msgs_b'])} | "
            f"{num(r['bound_train_return'], '{:.2f}')} | {r['seconds_bound']:.0f}, "
            f"{r['seconds_fit']:.0f}, {r['seconds_eval']:.0f} |")
    return "\n".join(lines) + "\n"


def write_markdown(rows: Sequence[dict], path: Path, command: str, seconds: float,
                   frontier: str | Path = FRONTIER) -> None:
    """``learnability.md``: what was run, the tables and how to read them."""
    r0 = rows[0]
    head = (f"Learnability of `reference:causal`'s decisions "
            f"(`experiments/rl/learnability.py`).\n\n"
            f"Command: `{command}` ({seconds / 60:.1f} min).\n\n"
            f"Training episodes: seeds {r0['train_seed_first']}.. (disjoint from the "
            f"evaluation seeds), split by episode into training / validation / test "
            f"({r0['train_episodes']} / {r0['val_episodes']} / {r0['test_episodes']} of "
            f"{r0['episodes']}). A decision is an (agent, step, bit) whose mask allows both "
            f"values; positive share: bits the bound set among them. Balanced accuracy on "
            f"the test episodes (0.5: the majority class); (a) the agent's current "
            f"observation, (b) its last {HISTORY}; model kept by validation balanced "
            f"accuracy. Clone returns: the kept classifier acting for every agent on its own "
            f"observation, {r0['eval_episodes']} evaluation seeds {r0['eval_seed_first']}–"
            f"{r0['eval_seed_last']}, mean [95 % bootstrap CI]. Bound return: "
            f"`reference:causal` in the frontier `{_shown(frontier)}; the first "
            f"{r0['bound_episodes']} evaluation seeds); best decentralised: its best "
            f"decentralised scripted point (100 evaluation seeds). Headroom recovered: "
            f"(clone - best decentralised) / (bound - best decentralised).\n\n")
    path.write_text(head + markdown(rows) + "\n" + details(rows))


def _shown(path: str | Path) -> str:
    """``path`` from its ``experiments/`` folder on (the repository's layout, whichever
    checkout it was read from) and the first 12 hex digits of its SHA-256."""
    import hashlib

    path = Path(path).resolve()
    digest = hashlib.sha256(path.read_bytes()).hexdigest()[:12]
    parts = path.parts
    shown = (Path(*parts[parts.index("experiments"):]).as_posix() if "experiments" in parts
             else str(path))
    return f"{shown}` (sha256 {digest}…"


def plot(rows: Sequence[dict], path: Path) -> None:
    """``learnability.png``: balanced accuracy (a)/(b) and headroom recovered per task."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = [r["task"] for r in rows]
    x = np.arange(len(rows))
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for k, (f, colour) in enumerate((("a", "#4393c3"), ("b", "#d6604d"))):
        label = "own observation (a)" if f == "a" else f"last {HISTORY} observations (b)"
        axes[0].bar(x + (k - 0.5) * 0.38, [r[f"balanced_accuracy_{f}"] for r in rows], 0.38,
                    color=colour, label=label)
        rec = np.array([r[f"recovered_{f}"] for r in rows], dtype=float)
        err = np.abs(np.array([[r[f"recovered_ci_low_{f}"], r[f"recovered_ci_high_{f}"]]
                               for r in rows], dtype=float).T - rec)
        axes[1].bar(x + (k - 0.5) * 0.38, rec, 0.38, color=colour, label=label,
                    yerr=np.nan_to_num(err), capsize=2)
    axes[0].axhline(0.5, color="k", lw=0.8, ls="--", label="majority class")
    axes[0].set_ylim(0, 1)
    axes[0].set_ylabel("balanced accuracy on held-out episodes")
    axes[1].axhline(0.0, color="k", lw=0.8)
    axes[1].axhline(1.0, color="#b2182b", lw=0.8, ls="--", label="reference:causal")
    axes[1].set_ylabel("headroom recovered by the clone\n(0: best decentralised, 1: bound)")
    for ax in axes:
        ax.set_xticks(x, tasks, rotation=30, ha="right", fontsize=8)
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Cloning reference:causal's bits from one agent's observation "
                 "(clone interval: 95 % bootstrap of its return)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# %% Main
def main(argv: Sequence[str] | None = None) -> list[dict]:
    """Run the tasks and write the outputs; returns the rows."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", nargs="+", default=list(TASKS))
    p.add_argument("--episodes", type=int, default=EPISODES,
                   help="training episodes of the bound per task")
    p.add_argument("--eval-episodes", type=int, default=pr.DEFAULT_EPISODES)
    p.add_argument("--frontier", type=Path, default=FRONTIER,
                   help="frontier CSV with the reference:causal rows (experiments/rl/"
                        "comm_bounds.py)")
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument("--smoke", action="store_true",
                   help="horizon 12, 2 episodes, 2 evaluation episodes")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    horizon = None
    if args.smoke:
        horizon, args.episodes, args.eval_episodes = 12, 2, 2
    from tqdm.auto import tqdm

    t0 = time.perf_counter()
    frontier = read_frontier(args.frontier)
    rows = []
    for task in tqdm(args.tasks, desc="tasks", disable=args.no_progress):
        rows.append(run_task(task, frontier, args.episodes, args.eval_episodes, horizon,
                             progress=not args.no_progress))
    seconds = time.perf_counter() - t0
    args.out.mkdir(parents=True, exist_ok=True)
    command = "python experiments/rl/learnability.py " + " ".join(
        sys.argv[1:] if argv is None else argv)
    write_csv(rows, args.out / "learnability.csv")
    write_markdown(rows, args.out / "learnability.md", command.strip(), seconds,
                   args.frontier)
    plot(rows, args.out / "learnability.png")
    print(markdown(rows))
    print(f"wrote {args.out} in {seconds:.0f} s")
    return rows


if __name__ == "__main__":
    main()
    sys.exit(0)
