"""The evaluation protocol of the communication tasks, and the scripted frontier.

What a number from ``netsense benchmark --frontier`` means (cite this module's defaults):

* **Seeds.** Evaluation episodes use the seeds ``EVAL_SEED0 + e`` for ``e = 0 ..
  episodes - 1`` (:func:`eval_seeds`, default :data:`DEFAULT_EPISODES` = 100 episodes,
  ``EVAL_SEED0 = 10^6``). Training runs use explicit seeds below
  :data:`TRAIN_SEED_LIMIT` ``= 10^6`` (``netsense train --seed s`` seeds copy ``c`` of the
  environment with ``s + c``); :func:`check_disjoint` refuses an overlap. Later training
  episodes draw their seeds from a generator over ``[0, 2^62)``: the chance that one of
  them is an evaluation seed is about ``episodes / 2^62`` per episode.
* **Metrics** per episode, as in :mod:`netsense.benchmark.metrics`: ``mean_rel_error``
  (``||x_hat_i[k] - x[k]|| / max(||x[k]||, floor)`` over ``k = 1..K`` and agents),
  ``final_rel_error``, ``msgs_per_agent_step`` (transmissions / ``N K``; in a shared
  channel attempts count, collided or not), ``load_per_agent_step`` (substates sent /
  ``M N K``: equal to the messages unless messages are per substate) and ``reward`` (the
  episode return, mean over agents).
* **Intervals.** Mean over the episodes with a 95 % percentile bootstrap confidence
  interval (:func:`bootstrap_ci`: ``scipy.stats.bootstrap``, 9999 resamples, generator
  seeded with 0, so the interval is reproducible).
* **Learned policies** (``learned:PATH``: a ``.pt`` policy of the batched trainer,
  :mod:`netsense.rl.ppo`, or a MaskablePPO ``policy.zip``) are evaluated twice on the
  same seeds: ``greedy`` (the most likely allowed action) and ``sampled`` (actions drawn
  from the policy, torch seeded with the first evaluation seed). They run in the control
  mode they were trained in (a ``.pt`` file stores it; a ``policy.zip`` runs in the
  scenario's, plus the given overrides). A policy whose training seeds overlap the
  evaluation seeds is refused.
* **Frontier.** Every communication baseline of :mod:`netsense.env.comm_policies` at each
  knob of :data:`FAMILIES`, plus ``always`` and ``never``, in the scenario's
  communication-only mode; a scenario with full control is run in ``mode =
  "transmit"`` with freshness fusion (``always`` then equals the freshness observer, bit
  for bit). Every (policy, knob) is one :class:`netsense.engine.core.BatchedCore` run of
  all the seeds (member ``b`` = seed ``b``).

* **Informed and privileged rules.** Besides :data:`FAMILIES`, the frontier runs the
  informed rules of :mod:`netsense.env.comm_informed` (``gated``, ``acked``, ``phased``)
  over each base rule of :data:`INFORMED_BASES`, on the scenarios whose observation
  carries the fields they read (``next_out``, ``acks``; ``phased`` also needs a periodic
  link schedule), and the privileged rules of :mod:`netsense.env.comm_privileged`
  (``oracle`` everywhere, ``oracle_channel`` where messages can be dropped) over the
  same bases. Their rows have ``family`` = the rule, ``knob`` = the base spec.
* **Settled rules.** ``settled:e(BASE)``
  (:class:`netsense.env.comm_decentralised.Settled`: the base's bits once the agent's
  estimate of its own block has settled) at each ``e`` of :data:`SETTLED_KNOBS` over each
  base of :data:`SETTLED_BASES`, on every scenario (kind ``decentralised``; ``family`` =
  ``settled``, ``knob`` = the base spec).
* **Kinds.** Every row has a ``kind`` (:data:`~netsense.benchmark.kinds.KINDS`, the score
  ladder): ``decentralised`` (what an agent could run from its own observation history:
  every scripted family but the schedulers and the privileged rules, the informed rules
  included, and the endpoints), ``privileged`` (reads what no agent observes: evidence
  of what information is worth, never a reference for the decentralised rows),
  ``centralised`` (schedulers that read every agent's state), ``learned`` and
  ``reference`` (the full-information reference schedulers of
  :mod:`netsense.benchmark.lookahead`: achieved returns, not deployable). "Best
  decentralised" (:func:`best_scripted`) is the best of every decentralised row.
* **Full-information references** (``references=("causal", "clairvoyant")``,
  ``--references``): policies ``reference:causal`` / ``reference:clairvoyant`` on the
  first ``reference_episodes`` of the same seeds (they cost far more than a scripted run;
  the ``episodes`` column says how many), continuing with the best scripted point of the
  same run and the best decentralised one (:func:`best_scripted`, deterministic rules
  only). :func:`netsense.benchmark.headroom.headroom` compares them with the best
  decentralised (and centralised) scripted point on the common seeds, with a paired
  bootstrap interval.

Outputs (:func:`write_frontier`): ``frontier_<scenario>.csv`` (one row per policy and
knob: the mean and interval of every metric, the wall time of the run and whether the
point is on the Pareto front of error vs load), ``frontier_<scenario>.png``
(:func:`netsense.benchmark.frontier_plot.plot_frontier`: error vs messages per agent-step
and reward vs messages, one marker and legend group per kind) and ``frontier.md`` (the
table); with references, ``headroom.csv`` and ``headroom.md``.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from netsense.benchmark.headroom import best_scripted, headroom, write_headroom
from netsense.benchmark.intervals import CONFIDENCE, RESAMPLES, bootstrap_ci
from netsense.benchmark.kinds import CENTRALISED_FAMILIES, KINDS, family_kind, reference_label
from netsense.benchmark.rollouts import is_batched_policy, learned_overrides
from netsense.rl.atomic import atomic_path, write_atomic

__all__ = ["CENTRALISED_FAMILIES", "CONFIDENCE", "CSV_COLUMNS", "DEFAULT_REFERENCE_EPISODES",
           "DEFAULT_EPISODES", "EVAL_SEED0", "FAMILIES", "KINDS", "PROTOCOL_METRICS",
           "RESAMPLES", "TRAIN_SEED_LIMIT", "best_scripted", "bootstrap_ci", "check_disjoint",
           "evaluate", "eval_seeds", "family_kind", "frontier", "frontier_overrides",
           "markdown_frontier", "pareto_front", "reference_rows", "run_frontier",
           "write_frontier", "write_frontiers"]

EVAL_SEED0 = 1_000_000
TRAIN_SEED_LIMIT = EVAL_SEED0
DEFAULT_EPISODES = 100
PROTOCOL_METRICS = ("mean_rel_error", "final_rel_error", "msgs_per_agent_step",
                    "load_per_agent_step", "reward")
#: Knob settings of each scripted family (from most to fewest messages, roughly); a
#: family with two knobs takes strings ``"knob1,knob2"`` (the spec is ``family:knobs``).
FAMILIES: dict[str, tuple] = {
    "periodic": (1, 2, 3, 4, 5, 6, 8, 12, 16),
    "bernoulli": (1.0, 0.7, 0.5, 0.35, 0.25, 0.15, 0.1, 0.05),
    "sources": (1, 2, 4, 8, 16, 0),
    "event": (1, 2, 3, 4, 6, 8, 12, 16),
    "until": (120, 80, 60, 40, 30, 20, 10),
    "settle": (0.001, 0.003, 0.01, 0.03, 0.1, 0.3),
    # threshold ALOHA: the proven K = 1 optimum (2.2, 4.69), lower thresholds, then lower
    # probabilities (the optimum collides on channels with K > 1)
    "aloha": ("2.2,4.69", "0.5,1", "1,1", "2.2,1", "2.2,0.5", "4.4,0.5", "4.4,0.25"),
    "tdma": (1, 2, 3, 4, 6, 8),
    "oldest": (1, 2, 3, 4, 6),
    "whittle": (1, 2, 3, 4, 6),
}
ENDPOINTS = ("always", "never")
#: Base rules the informed and privileged rules wrap in the frontier (a handful of the
#: families' points: the frontier stays affordable).
INFORMED_BASES = ("always", "sources:0", "event:1", "event:2", "event:3", "event:4",
                  "until:40")
#: Base rules and thresholds of the ``settled`` rows of the frontier: the informed rules'
#: bases and the talk-then-stop rule ``settle`` at the two knobs that lead
#: ``message_cost-v0``/``-v1``; ``e`` from opening at a correction as large as the
#: estimate itself down to a tenth of it.
SETTLED_BASES = INFORMED_BASES + ("settle:0.01", "settle:0.03")
SETTLED_KNOBS = (1.0, 0.3, 0.1)
CSV_COLUMNS = (("scenario", "control", "kind", "family", "policy", "knob", "evaluation",
                "episodes", "seed_first", "seed_last", "pareto", "seconds")
               + tuple(f"{m}_{s}" for m in PROTOCOL_METRICS
                       for s in ("mean", "ci_low", "ci_high")))


def eval_seeds(episodes: int = DEFAULT_EPISODES, seed0: int = EVAL_SEED0) -> list[int]:
    """The evaluation seeds ``seed0, ..., seed0 + episodes - 1``."""
    if isinstance(episodes, bool) or int(episodes) != episodes or episodes < 1:
        raise ValueError(f"episodes must be an integer >= 1, got {episodes!r}")
    if int(seed0) < 0:
        raise ValueError(f"seed0 must be >= 0, got {seed0}")
    return list(range(int(seed0), int(seed0) + int(episodes)))


def check_disjoint(train_seeds: Sequence[int], seeds: Sequence[int]) -> None:
    """Raise ``ValueError`` when training and evaluation seeds overlap."""
    common = sorted(set(int(s) for s in train_seeds) & set(int(s) for s in seeds))
    if common:
        raise ValueError(f"evaluation seeds {common[:5]} were used in training; evaluate on "
                         f"seeds >= {EVAL_SEED0} and train below {TRAIN_SEED_LIMIT}")


def _train_seeds(path: Path) -> list[int]:
    """Explicit seeds of the training run that wrote ``path`` (a ``.pt`` policy's stored
    config, a MaskablePPO policy's train_config.json)."""
    if is_batched_policy(path):
        from netsense.rl.checkpoint import policy_config, read_policy
        from netsense.rl.config import training_seeds

        return training_seeds(policy_config(read_policy(path)))
    from netsense.rl.sb3_policy import read_sb3_policy

    meta, _ = read_sb3_policy(path)  # the file's own record first, then its run's config
    cfg = path.parent / "train_config.json"
    if "seed" not in meta and cfg.exists():
        meta = json.loads(cfg.read_text())
    if "seed" not in meta:
        return []
    s, copies = int(meta.get("seed", 0)), int(meta.get("num_vec_envs", 1))
    return list(range(s, s + copies))


def frontier_overrides(scenario: str, overrides: dict | None = None) -> dict:
    """Overrides that put ``scenario`` in a communication-only mode (``"transmit"`` with
    freshness fusion unless the scenario or ``overrides`` choose one)."""
    from netsense.env.registry import control_overrides

    over = dict(overrides or {})
    if _mode(scenario, over) == "full":
        return control_overrides(scenario, "transmit", over)
    return over


def _mode(scenario: str, overrides: dict) -> str:
    from netsense.env.registry import load, with_overrides

    return with_overrides(load(scenario), **overrides).control.get("mode", "full")


# ----------------------------------------------------------------------------- rollouts
def _learned_actor(path: str, deterministic: bool, seed: int, core=None):
    import torch

    if is_batched_policy(path):
        from netsense.rl.checkpoint import load_policy

        pol = load_policy(path, core, deterministic=deterministic)
        if not deterministic:
            torch.manual_seed(int(seed))
        return pol.act

    from netsense.rl.sb3_policy import LearnedPolicy

    model = LearnedPolicy(path, deterministic=deterministic).model
    if not deterministic:
        torch.manual_seed(int(seed))

    def act(obs, mask):
        B, N = obs.shape[:2]
        flat = np.concatenate([obs, mask.astype(np.float32)], axis=-1).reshape(B * N, -1)
        acts, _ = model.predict(flat, action_masks=mask.reshape(B * N, -1) > 0,
                                deterministic=deterministic)
        return np.asarray(acts).reshape(B, N, -1)

    return act


def evaluate(scenario: str, policy: str, seeds: Sequence[int], overrides: dict | None = None,
             *, actor=None, reference=None, on_step=None) -> dict[str, np.ndarray]:
    """Per-episode :data:`PROTOCOL_METRICS` of ``policy`` on ``seeds``, as one batched run.

    ``policy``: a communication baseline spec (``periodic:4``, ...), a scripted policy name
    of :mod:`netsense.env.policies` (``freshness``, ...), ``learned:PATH`` (greedy),
    ``learned_sampled:PATH``, or a full-information reference ``reference:causal`` /
    ``reference:clairvoyant`` (optionally ``reference:KIND:CONTINUATION``; search settings
    from ``reference``, a :class:`~netsense.benchmark.lookahead.LookaheadConfig`). Member
    ``b`` is seeded with ``seeds[b]``; members that terminate early (``divergence_limit``)
    are scored over their own steps.
    ``actor``: a callable ``(core, seeds) -> act`` that builds the acting function on the
    evaluated :class:`~netsense.engine.core.BatchedCore` instead (``policy`` is then only
    its label): a rule that is no registered policy, scored exactly like one.
    ``on_step``: a callable ``(core, live)`` run after every step, with the members still in
    their episode (``live``, before this step's ends), to record what the metrics do not
    (the channel's collisions, say).
    """
    return _evaluate(scenario, policy, seeds, overrides, reference, actor, on_step)[0]


def _evaluate(scenario: str, policy: str, seeds: Sequence[int], overrides: dict | None,
              reference=None, actor=None, on_step=None
              ) -> tuple[dict[str, np.ndarray], dict]:
    """:func:`evaluate` and the run's cost: ``seconds`` and, for a reference, its
    :meth:`~netsense.benchmark.lookahead.LookaheadReference.cost`."""
    import time

    from netsense.engine.core import BatchedCore
    from netsense.env.vector import load_model

    t0 = time.perf_counter()
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds must be non-empty")
    name, _, arg = policy.partition(":")
    learned = actor is None and name in ("learned", "learned_sampled")
    if learned:
        if not arg:
            raise ValueError(f"{name} needs a path: {name}:PATH")
        overrides = learned_overrides(scenario, arg, overrides)
    model, _ = load_model(scenario, **dict(overrides or {}))
    B = len(seeds)
    lookahead = None
    if actor is None and name in ("reference", "bound"):  # (bound: refused, renamed)
        from netsense.benchmark.lookahead import LookaheadReference, parse_reference

        config = parse_reference(policy, reference)
        core = BatchedCore(model, B, chunk=1)  # (a resampled fork needs chunk=1)
        lookahead = LookaheadReference(core, config, seeds)
        act = lookahead.act
    else:
        core = BatchedCore(model, B)
    if actor is not None:
        act = actor(core, seeds)
    elif learned:
        check_disjoint(_train_seeds(Path(arg)), seeds)
        act = _learned_actor(arg, name == "learned", seeds[0], core)
    elif lookahead is None:
        act = _scripted(policy, core, seeds).act
    obs, mask = core.reset(seeds)
    floor = model.reward.error_floor
    N = core.N
    err, msgs, load, rew = (np.zeros(B) for _ in range(4))
    final, steps = np.zeros(B), np.zeros(B)
    live = np.ones(B, dtype=bool)
    while live.any():
        out = core.step(act(obs, mask))
        obs, mask = out.obs, out.action_mask
        rel = (np.linalg.norm(core.estimates - core.x[:, None, :], axis=-1)
               / np.maximum(np.linalg.norm(core.x, axis=-1), floor)[:, None]).mean(1)
        sent = (core.transmit.sum(1) if core.comm is None or not core.comm.per_substate
                else core.comm.sent.sum((1, 2)) / core.M)
        err[live] += rel[live]
        final[live] = rel[live]
        msgs[live] += core.transmit.sum(1)[live] / N
        load[live] += sent[live] / N
        rew[live] += out.reward.mean(1)[live]
        steps[live] += 1
        if on_step is not None:
            on_step(core, live.copy())
        live &= ~(out.terminated | out.truncated)
    values = {"mean_rel_error": err / steps, "final_rel_error": final,
              "msgs_per_agent_step": msgs / steps, "load_per_agent_step": load / steps,
              "reward": rew}
    cost = {"seconds": time.perf_counter() - t0}
    if lookahead is not None:
        cost.update(lookahead.cost())
    return values, cost


def _scripted(policy: str, core, seeds: Sequence[int]):
    from netsense.env.comm_policies import COMM_POLICIES, make_comm_policy, spec_family
    from netsense.env.policies import make_policy

    if spec_family(policy) in COMM_POLICIES:
        return make_comm_policy(policy, core, seed=list(seeds))
    kwargs = {"seed": list(seeds)} if policy == "random" else {}
    return make_policy(policy, core, **kwargs)


def _summary(values: dict[str, np.ndarray]) -> dict[str, float]:
    out = {}
    for m in PROTOCOL_METRICS:
        mean, lo, hi = bootstrap_ci(values[m])
        out.update({f"{m}_mean": mean, f"{m}_ci_low": lo, f"{m}_ci_high": hi})
    return out


def pareto_front(rows: Sequence[dict], x: str = "load_per_agent_step",
                 y: str = "mean_rel_error") -> list[bool]:
    """Which rows are not dominated in (``x``, ``y``) means (both smaller is better)."""
    pts = np.array([[r[f"{x}_mean"], r[f"{y}_mean"]] for r in rows], dtype=float)
    out = []
    for p in pts:
        worse = np.all(pts <= p, axis=1) & np.any(pts < p, axis=1)
        out.append(bool(np.isfinite(p).all() and not worse.any()))
    return out


def frontier(scenario: str, *, episodes: int = DEFAULT_EPISODES, seed0: int = EVAL_SEED0,
             families: dict[str, Sequence] | None = None, learned: Sequence[str] = (),
             overrides: dict | None = None, progress: bool = True,
             informed_bases: Sequence[str] = INFORMED_BASES, privileged: bool = True,
             settled_bases: Sequence[str] = SETTLED_BASES,
             settled_knobs: Sequence[float] = SETTLED_KNOBS,
             references: Sequence[str] = (), reference_episodes: int | None = None,
             reference_config=None, reference_continuation: str | Sequence[str] = "best"
             ) -> list[dict]:
    """Rows of the scripted frontier, the informed and privileged rules, the learned points
    and the full-information references of one scenario.

    Parameters
    ----------
    scenario : str
    episodes, seed0 : int
        Evaluation seeds (:func:`eval_seeds`).
    families : dict, optional
        Family -> knob settings (default :data:`FAMILIES`); ``always`` and ``never`` are
        always run.
    learned : sequence of str
        Paths of learned policies (``.pt`` of the batched trainer or a MaskablePPO
        ``policy.zip``; ``{scenario}`` is replaced by the scenario id); each is evaluated
        greedy and sampled.
    overrides : dict, optional
        Scenario overrides (the learned policies run with exactly these).
    progress : bool
        A tqdm bar over the runs.
    informed_bases : sequence of str
        Base rules of the informed rules that apply to the scenario
        (:func:`netsense.env.comm_informed.applicable`; default :data:`INFORMED_BASES`;
        empty: none) and of the privileged rules.
    privileged : bool
        Run the privileged rules that apply (:func:`netsense.env.comm_privileged.
        applicable`) over ``informed_bases`` (kind ``privileged``).
    settled_bases, settled_knobs : sequence
        ``settled:e(BASE)`` for every ``e`` and base (default :data:`SETTLED_KNOBS`,
        :data:`SETTLED_BASES`; either empty: none).
    references : sequence of {"causal", "clairvoyant"}
        Full-information reference schedulers to run (:mod:`netsense.benchmark.lookahead`).
    reference_episodes : int, optional
        The references run on the first ``reference_episodes`` seeds (default
        :data:`DEFAULT_REFERENCE_EPISODES`, at most ``episodes``).
    reference_config : LookaheadConfig, optional
        Search settings of the references (default :class:`~netsense.benchmark.lookahead.
        LookaheadConfig`); its ``kind`` and ``continuation`` are set here.
    reference_continuation : "best" or sequence of str
        The references' continuation policies: ``"best"`` takes the best scripted point of
        this run and the best decentralised one (:func:`best_scripted`, deterministic rules
        only), else the specs given.

    Returns
    -------
    list of dict
        One row per run: the :data:`CSV_COLUMNS` and ``values`` (the per-episode metrics,
        for paired comparisons such as :func:`netsense.benchmark.headroom.headroom`).
    """
    from tqdm.auto import tqdm

    from netsense.benchmark.lookahead import REFERENCE_KINDS, LookaheadConfig
    from netsense.env import comm_informed, comm_privileged
    from netsense.env.comm_policies import parse_spec
    from netsense.env.vector import load_model

    seeds = eval_seeds(episodes, seed0)
    for kind in references:
        if kind not in REFERENCE_KINDS:
            raise ValueError(f"references must be among {REFERENCE_KINDS}, got {kind!r}")
    E = min(DEFAULT_REFERENCE_EPISODES if reference_episodes is None else reference_episodes,
            episodes)
    if isinstance(E, bool) or int(E) != E or E < 1:
        raise ValueError(f"reference_episodes must be an integer >= 1, got "
                         f"{reference_episodes!r}")
    if reference_config is not None and not isinstance(reference_config, LookaheadConfig):
        raise TypeError(f"reference_config must be a LookaheadConfig, got "
                        f"{type(reference_config).__name__}")
    if isinstance(informed_bases, str):
        raise ValueError(f"informed_bases must be a sequence of specs, got {informed_bases!r}")
    for base in informed_bases:  # a bad base fails before minutes of runs
        parse_spec(f"gated({base})")
    if isinstance(settled_bases, str):
        raise ValueError(f"settled_bases must be a sequence of specs, got {settled_bases!r}")
    for e in settled_knobs:
        if (isinstance(e, bool) or not isinstance(e, (int, float, np.integer, np.floating))
                or not (math.isfinite(e) and e > 0)):
            raise ValueError(f"settled_knobs must be numbers > 0, got {e!r}")
    settled = [(base, f"settled:{float(e)!r}({base})") for base in settled_bases
               for e in settled_knobs]
    for _, spec in settled:  # a bad base fails here, before the runs
        parse_spec(spec)
    for path in learned:  # a missing or refused file, or training seeds among the
        # evaluation seeds, fail before the scripted runs (minutes) rather than after
        check_disjoint(_train_seeds(Path(path.replace("{scenario}", scenario))), seeds)
    fams = dict(FAMILIES if families is None else families)
    comm_over = frontier_overrides(scenario, overrides)
    control = _mode(scenario, comm_over)
    model, _ = load_model(scenario, **comm_over)
    wrappers = comm_informed.applicable(model)
    if privileged:
        wrappers += comm_privileged.applicable(model)
    runs = [(name, None, name, "scripted", comm_over) for name in ENDPOINTS]
    runs += [(fam, knob, f"{fam}:{knob}", "scripted", comm_over)
             for fam, knobs in fams.items() for knob in knobs]
    runs += [(rule, base, f"{rule}({base})", "scripted", comm_over)
             for rule in wrappers for base in informed_bases]
    runs += [("settled", base, spec, "scripted", comm_over) for base, spec in settled]
    for path in learned:
        path = path.replace("{scenario}", scenario)
        runs += [("learned", path, f"learned:{path}", "greedy", dict(overrides or {})),
                 ("learned", path, f"learned_sampled:{path}", "sampled",
                  dict(overrides or {}))]
    rows = []
    for fam, knob, spec, how, over in tqdm(runs, desc=f"frontier {scenario}",
                                           disable=not progress):
        vals, cost = _evaluate(scenario, spec, seeds, over)
        mode = (_mode(scenario, learned_overrides(scenario, knob, over)) if fam == "learned"
                else control)
        rows.append(_row(scenario, mode, fam, spec, knob, how, seeds, vals, cost))
    rows += reference_rows(scenario, rows, references, reference_episodes=int(E),
                           reference_config=reference_config,
                           reference_continuation=reference_continuation,
                           overrides=overrides)
    # points an agent or a coordinator could reach (not privileged rules nor references)
    front = [r for r in rows if r["kind"] in ("decentralised", "centralised", "learned")]
    for r, p in zip(front, pareto_front(front), strict=True):
        r["pareto"] = p
    for r in rows:
        r.setdefault("pareto", "")
    return rows


#: Episodes of the references in :func:`frontier` unless told (they cost far more per
#: episode).
DEFAULT_REFERENCE_EPISODES = 20


def _row(scenario, control, fam, spec, knob, how, seeds, vals, cost) -> dict:
    return {"scenario": scenario, "control": control, "kind": family_kind(fam),
            "family": fam, "policy": spec, "knob": "" if knob is None else knob,
            "evaluation": how, "episodes": len(seeds), "seed_first": seeds[0],
            "seed_last": seeds[-1], "seconds": cost["seconds"], **_summary(vals),
            "values": vals, "pareto": ""}


def reference_rows(scenario: str, rows: Sequence[dict], references: Sequence[str] = (
        "causal", "clairvoyant"), *, reference_episodes: int = DEFAULT_REFERENCE_EPISODES,
        reference_config=None, reference_continuation: str | Sequence[str] = "best",
        overrides: dict | None = None) -> list[dict]:
    """The rows of the full-information references of ``scenario`` that :func:`frontier`
    adds to its scripted ``rows`` (the continuation ``"best"`` is chosen among them), on
    the first ``reference_episodes`` seeds of those rows."""
    from netsense.benchmark.lookahead import LookaheadConfig

    mine = [r for r in rows if r["scenario"] == scenario]
    if references and not mine:
        raise ValueError(f"no rows of {scenario} to continue from")
    out = []
    for kind in references:
        seed0 = int(mine[0]["seed_first"])
        seeds = eval_seeds(reference_episodes, seed0)
        cont = (_continuation(mine) if reference_continuation == "best"
                else tuple([reference_continuation] if isinstance(reference_continuation, str)
                           else reference_continuation))
        base = reference_config or LookaheadConfig()
        config = LookaheadConfig(**{**_fields(base), "kind": kind, "continuation": cont})
        over = frontier_overrides(scenario, overrides)
        vals, cost = _evaluate(scenario, f"reference:{kind}", seeds, over, config)
        row = _row(scenario, _mode(scenario, over), "reference", f"reference:{kind}",
                   " + ".join(cont), "lookahead", seeds, vals, cost)
        row["reference_config"], row["cost"] = config, cost
        out.append(row)
    return out


def _fields(config) -> dict:
    from dataclasses import fields

    return {f.name: getattr(config, f.name) for f in fields(config)}


def _continuation(rows: Sequence[dict]) -> tuple[str, ...]:
    """The best scripted point and the best decentralised one (deterministic families)."""
    best = best_scripted(rows, deterministic=True)["policy"]
    dec = best_scripted(rows, "decentralised", deterministic=True)["policy"]
    return (best,) if best == dec else (best, dec)


# ----------------------------------------------------------------------------- outputs
def _cell(v) -> str:
    if isinstance(v, float):
        return "nan" if not math.isfinite(v) else f"{v:.6g}"
    return str(v)


def write_frontier(rows: Sequence[dict], out: str | Path) -> tuple[Path, Path]:
    """``frontier_<scenario>.csv`` and ``.png`` of one scenario's rows into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scenario = rows[0]["scenario"]
    path_csv = out / f"frontier_{scenario}.csv"
    with atomic_path(path_csv) as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_COLUMNS)
        for r in rows:
            w.writerow([_cell(r[c]) for c in CSV_COLUMNS])
    path_png = out / f"frontier_{scenario}.png"
    _plot(rows, path_png)
    return path_csv, path_png


def _plot(rows: Sequence[dict], path: Path) -> None:
    """:func:`netsense.benchmark.frontier_plot.plot_frontier` (the name scripts call)."""
    from netsense.benchmark.frontier_plot import plot_frontier

    plot_frontier(rows, path)


def markdown_frontier(rows: Sequence[dict]) -> str:
    """The rows as a Markdown table: mean [95 % CI] of error, messages and reward; per
    scenario, the kinds in the order of :data:`~netsense.benchmark.kinds.KINDS` (each its
    own group of rows)."""

    def f(r, m, digits=3):
        mean, lo, hi = r[f"{m}_mean"], r[f"{m}_ci_low"], r[f"{m}_ci_high"]
        if not math.isfinite(mean):
            return "–"
        if hi - lo <= 1e-12 * max(abs(mean), 1e-300):
            return f"{mean:.{digits}g}"
        return f"{mean:.{digits}g} [{lo:.{digits}g}, {hi:.{digits}g}]"

    lines = ["| scenario | kind | policy | evaluation | episodes | mean rel. error | "
             "msgs / agent-step | load / agent-step | reward | Pareto |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in _by_kind(rows):
        policy = r["policy"]
        if r.get("kind") == "reference":
            policy = f"{reference_label(policy)}: {policy} (continues {r['knob']})"
        lines.append(f"| {r['scenario']} | {r.get('kind', '')} | {policy} | "
                     f"{r['evaluation']} | {r['episodes']} | "
                     f"{f(r, 'mean_rel_error')} | {f(r, 'msgs_per_agent_step')} | "
                     f"{f(r, 'load_per_agent_step')} | {f(r, 'reward')} | "
                     f"{'yes' if r['pareto'] is True else ''} |")
    return "\n".join(lines) + "\n"


def _by_kind(rows: Sequence[dict]) -> list[dict]:
    """The rows per scenario (first-seen order), kinds in :data:`KINDS` order."""
    scen = {s: i for i, s in enumerate(dict.fromkeys(r["scenario"] for r in rows))}
    rank = {k: i for i, k in enumerate(KINDS)}
    return sorted(rows, key=lambda r: (scen[r["scenario"]], rank.get(r.get("kind"), len(rank))))


def run_frontier(scenarios: Sequence[str], out: str | Path, *, workers: int = 1,
                 **kwargs) -> list[dict]:
    """:func:`frontier` of every scenario, written by :func:`write_frontier`, plus
    ``frontier.csv`` (all rows) and ``frontier.md``; with references, ``headroom.csv`` and
    ``headroom.md`` (:mod:`netsense.benchmark.headroom`).

    ``workers > 1`` runs the scenarios in that many processes at once (each scenario in
    one process, the same rows as one by one; no progress bars).
    """
    if isinstance(workers, bool) or int(workers) != workers or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scenarios = list(dict.fromkeys(scenarios))
    if workers > 1 and len(scenarios) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        from functools import partial

        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(min(int(workers), len(scenarios)), mp_context=ctx) as pool:
            per = list(pool.map(partial(frontier, **{**kwargs, "progress": False}),
                                scenarios))
    else:
        per = [frontier(sc, **kwargs) for sc in scenarios]
    rows = [r for rs in per for r in rs]
    write_frontiers(rows, out)
    return rows


def write_frontiers(rows: Sequence[dict], out: str | Path) -> None:
    """The outputs of :func:`run_frontier` for ``rows`` (of any scenarios): per scenario
    :func:`write_frontier`, then ``frontier.csv``, ``frontier.md`` and, with reference
    rows (their per-episode ``values``), ``headroom.csv`` and ``headroom.md``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for sc in dict.fromkeys(r["scenario"] for r in rows):
        write_frontier([r for r in rows if r["scenario"] == sc], out)
    with atomic_path(out / "frontier.csv") as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_COLUMNS)
        for r in rows:
            w.writerow([_cell(r[c]) for c in CSV_COLUMNS])
    write_atomic(out / "frontier.md", markdown_frontier(rows))
    if any(r["kind"] == "reference" for r in rows):
        write_headroom(headroom(rows), out)
