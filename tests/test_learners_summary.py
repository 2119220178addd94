"""The learners' aggregates (experiments/rl/learners.py): rliable's IQM and intervals, the
probability of improvement and the fraction of the gap closed, on returns whose answers
are known."""

import numpy as np
import pytest
from experiment_loader import load_experiment

pytest.importorskip("rliable")


@pytest.fixture(scope="module")
def learners():
    return load_experiment("rl/learners")


def _rows(learned: dict[int, np.ndarray], best: np.ndarray, causal: np.ndarray,
          never: np.ndarray, bound: np.ndarray | None = None) -> list[dict]:
    rows = []
    refs = [("never", never), ("best_decentralised", best), ("reference:causal", causal)]
    if bound is not None:
        refs.append(("upper_bound", bound))
    for policy, values in refs:
        rows += [{"task": "t", "policy": policy, "spec": "event:2", "seed": "",
                  "evaluation": "scripted", "episode": e, "reward": float(v)}
                 for e, v in enumerate(values)]
    for seed, values in learned.items():
        rows += [{"task": "t", "policy": "mlp", "spec": "mlp", "seed": seed,
                  "evaluation": "greedy", "episode": e, "reward": float(v)}
                 for e, v in enumerate(values)]
    return rows


def test_gap_closed_and_scores_on_known_returns(learners):
    rng = np.random.default_rng(0)
    best = -50 + rng.normal(0, 1, 100)
    causal = np.full(20, -30.0)
    never = np.full(100, -100.0)
    # five seeds whose returns sit halfway between the best scripted IQM and the bound
    b_iqm = float(np.mean(np.sort(best)[25:75]))  # 100 episodes: the middle 50
    target = b_iqm + 0.5 * (-30.0 - b_iqm)
    learned = {s: np.full(100, target) for s in range(5)}
    (row,) = learners.summarise(_rows(learned, best, causal, never), ["mlp"])
    assert row["seeds"] == 5 and row["episodes"] == 500
    assert row["iqm"] == pytest.approx(target) and row["iqm_ci_low"] <= target + 1e-9
    assert row["gap_closed"] == pytest.approx(0.5)
    assert row["p_improvement"] == pytest.approx(1.0)  # every learned episode is above
    # no upper bound among the rows: its gap is not a number, not a silent 0
    assert np.isnan(row["bound_gap_closed"]) and np.isnan(row["upper_bound_iqm"])


def test_gap_to_the_upper_bound_is_measured_apart_from_the_reference(learners):
    """The same learner closes half the gap to the causal reference and a quarter of the
    (twice as wide) gap to the certified upper bound."""
    best = np.full(100, -50.0)
    learned = {s: np.full(100, -40.0) for s in range(5)}
    (row,) = learners.summarise(_rows(learned, best, np.full(20, -30.0), np.full(100, -100.0),
                                      bound=np.full(20, -10.0)), ["mlp"])
    assert row["gap_closed"] == pytest.approx(0.5)
    assert row["bound_gap_closed"] == pytest.approx(0.25)
    assert row["upper_bound_iqm"] == pytest.approx(-10.0)


def test_aggregate_is_the_suites_normalisation(learners, monkeypatch):
    """The aggregate plot's scores are the suite's: per episode, never = 0 and the
    certified upper bound of the suite's references = 1."""
    from netsense.benchmark import references
    from netsense.benchmark.references import EpisodeValues, TaskReferences

    task = "comm_announced-v0"
    seeds = tuple(range(10**6, 10**6 + 4))
    never, bound = np.array([-100.0, -90, -80, -70]), np.array([-20.0, -30, -40, -50])
    ref = TaskReferences(task, "transmit", EpisodeValues(seeds, never), "event:2",
                         EpisodeValues(seeds, never + 10), None, None,
                         EpisodeValues(seeds, bound))
    # the suite imported before anything is patched: its module-level name would otherwise
    # bind the stand-in for good, and monkeypatch would "restore" it to the stand-in
    import netsense.benchmark.suite as suite

    monkeypatch.setattr(references, "load_references", lambda path=None: {task: ref})
    monkeypatch.setattr(suite, "load_references", lambda path=None: {task: ref})
    ret = {0: never + 0.25 * (bound - never), 1: never + 0.75 * (bound - never)}
    rows = [{"task": task, "policy": "mlp", "spec": "mlp", "seed": s,
             "evaluation": "greedy", "episode": e, "reward": float(v)}
            for s, vals in ret.items() for e, v in enumerate(vals)]
    result = learners.suite_result(rows, ["mlp"])
    np.testing.assert_allclose(np.sort(result.scores["mlp (greedy)"].ravel()),
                               [0.25] * 4 + [0.75] * 4)
    row = next(r for r in result.table if r["task"] == task)
    assert row["score"] == pytest.approx(0.5)  # the IQM of four 0.25 and four 0.75
    # four episodes: the IQM trims one from each end
    assert row["best_decentralised_score"] == pytest.approx(
        np.sort(10 / (bound - never))[1:3].mean())


def test_a_copy_of_the_scripted_policy_closes_no_gap(learners):
    """Returns with a long lower tail (as episodes have): a learner whose every seed scores
    exactly the scripted policy's episodes reaches it and closes no gap, although its IQM
    lies well above the scripted mean; the comparison is IQM against IQM."""
    rng = np.random.default_rng(1)
    best = -40 - rng.exponential(5.0, 100)
    causal = -30 - rng.exponential(5.0, 20)
    summary = learners.summarise(_rows({s: best.copy() for s in range(5)}, best, causal,
                                       np.full(100, -100.0)), ["mlp"])
    (row,) = summary
    assert row["iqm"] - best.mean() > 1.0  # the bias a mean reference would credit
    assert row["iqm"] == pytest.approx(row["best_decentralised_iqm"])
    assert row["gap_closed"] == pytest.approx(0.0, abs=1e-12)
    assert row["reaches"] and row["p_improvement"] == pytest.approx(0.5)
    assert row["best_decentralised"] == pytest.approx(best.mean())
    assert row["causal_reference_iqm"] == pytest.approx(np.mean(np.sort(causal)[5:15]))


def test_iqm_discards_the_outer_quartiles(learners):
    """One seed far below the others moves the mean but not the interquartile mean."""
    best = np.full(100, -50.0)
    learned = {s: np.full(100, -40.0) for s in range(7)}
    learned[7] = np.full(100, -1000.0)
    summary = learners.summarise(_rows(learned, best, np.full(20, -30.0),
                                       np.full(100, -100.0)), ["mlp"])
    assert summary[0]["iqm"] == pytest.approx(-40.0)
    assert summary[0]["p_improvement"] == pytest.approx(7 / 8)


def test_evaluation_seeds_are_disjoint_from_every_training_seed(learners):
    """The protocol's evaluation episodes never reuse a training member's seed."""
    from netsense.benchmark.protocol import eval_seeds

    pytest.importorskip("torch")
    from netsense.rl.config import training_seeds

    cfg = learners.load_config()
    seeds = set(eval_seeds(learners.EPISODES))
    for task in cfg["tasks"]:
        for s in cfg["defaults"]["seeds"]:
            config = learners.ppo_config(task, s, learners._fields(cfg["defaults"],
                                                                   cfg["tasks"][task]))
            assert not seeds & set(training_seeds(config))


def test_every_learner_is_a_valid_config_on_every_task(learners):
    """Each ``[learners.*]`` table of the config, on each task, is a ``PPOConfig`` its
    checks accept (a learner's option that a task cannot take fails here, not an hour into
    a run)."""
    pytest.importorskip("torch")
    cfg = learners.load_config()
    for name, table in cfg["learners"].items():
        for task in cfg["tasks"]:
            fields = learners._fields(cfg["defaults"], table, cfg["tasks"][task])
            config = learners.ppo_config(task, 0, fields)
            es = learners.es_config(fields)  # an ES learner: its own keys, checked too
            own = {k: v for k, v in table.items()
                   if k not in learners.ES_KEYS + ("algorithm",)}
            assert all(getattr(config, k) == (tuple(v) if isinstance(v, list) else v)
                       for k, v in own.items()), name
            if es is not None:
                assert all(getattr(es, k) == table[k] for k in learners.ES_KEYS
                           if k in table), name


def test_intervals_are_reproducible(learners):
    """The same returns give the same interval in every run (rliable resamples from
    NumPy's global generator, which the script seeds around each call)."""
    from netsense.benchmark.scores import iqm_interval

    x = np.random.default_rng(1).normal(size=(300, 1))
    first = iqm_interval(x)
    np.random.random(7)  # noqa: NPY002 (whatever the global generator did in between)
    assert iqm_interval(x) == first


def test_best_validated_checkpoint_is_the_highest_periodic_evaluation(learners, tmp_path):
    """The kept checkpoint is the one whose validation return is highest (the later one on a
    tie); iterations without an evaluation, or whose checkpoint is gone, are not chosen."""
    rows = [("0", "", True), ("1", "-30.0", True), ("2", "-12.5", True), ("3", "", True),
            ("4", "-12.5", True), ("5", "-20.0", True), ("6", "-5.0", False)]
    lines = ["iteration,agent_steps,eval_return"]
    for it, ret, keep in rows:
        lines.append(f"{it},{100 * (int(it) + 1)},{ret}")
        if keep:
            (tmp_path / f"checkpoint_{int(it) + 1:05d}.pt").write_bytes(b"x")
    (tmp_path / "log.csv").write_text("\n".join(lines) + "\n")
    assert learners.best_validated(tmp_path) == tmp_path / "checkpoint_00005.pt"
    (tmp_path / "log.csv").write_text("iteration,agent_steps,eval_return\n0,100,\n")
    assert learners.best_validated(tmp_path) is None


def test_validation_seeds_are_apart_from_training_and_test_seeds(learners):
    """The periodic evaluation that picks the best-validated checkpoint never sees a
    protocol test episode or a training episode."""
    from netsense.benchmark.protocol import eval_seeds

    pytest.importorskip("torch")
    from netsense.rl.config import EVAL_SEED, training_seeds

    cfg = learners.load_config()
    val = set(range(EVAL_SEED, EVAL_SEED + cfg["defaults"]["eval_envs"]))
    assert not val & set(eval_seeds(learners.EPISODES))
    for task in cfg["tasks"]:
        config = learners.ppo_config(task, max(cfg["defaults"]["seeds"]), learners._fields(
            cfg["defaults"], cfg["tasks"][task]))
        assert not val & set(training_seeds(config))


def test_learning_curve_bands_are_reproducible(learners, tmp_path):
    """The curves' bootstrap bands do not depend on what the global generator did before
    (the same seeding as the summary's intervals)."""
    rng = np.random.default_rng(2)
    folders = {}
    for s in range(5):
        d = tmp_path / f"seed_{s}"
        d.mkdir()
        lines = ["iteration,agent_steps,eval_return"]
        lines += [f"{i},{1000 * (i + 1)},{-50 + i + rng.normal():.6f}" for i in range(6)]
        (d / "log.csv").write_text("\n".join(lines) + "\n")
        folders["t", "mlp", s] = d
    first = learners.learning_curves(folders, ["mlp"])["t"]["mlp"]
    np.random.random(11)  # noqa: NPY002 (whatever the global generator did in between)
    again = learners.learning_curves(folders, ["mlp"])["t"]["mlp"]
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a, b)


def test_substate_use_pairs_each_choice_with_the_news_it_saw(learners):
    """``event:1`` sends a substate exactly when its news is at least one step: measured
    on the choices paired with their observations, the send probabilities must come out 0
    without news and 1 with it; off by a step, they would not. ``never`` sends nothing."""
    seeds = [10**6, 10**6 + 1]
    event = learners.substate_use("event:1", seeds)
    assert event["send_without_news"] == 0.0
    assert event["send_own_news"] == 1.0 and event["send_others_news"] == 1.0
    assert 0.0 < event["sent_rate"] < 1.0
    never = learners.substate_use("never", seeds)
    assert never["sent_rate"] == 0.0 and never["send_others_news"] == 0.0
    assert never["return"] < event["return"]


def test_news_use_measures_what_the_gate_closes_on_a_transmit_task(learners):
    """On ``comm_process_noise-v0`` (transmit bits): ``event:1`` sends exactly when any
    substate is news, so paired with the news it saw its send probabilities are 1 and 0
    (off by a step they would not be); ``sources:0`` sends every source choice and no
    relay's, all of them news; ``always`` keeps relays sending after they passed on what
    they hold, so the gate would close some of its sends; the gated learner's class holds
    the rules with none."""
    seeds = [10**6, 10**6 + 1]
    task = "comm_process_noise-v0"
    event = learners.news_use(task, "event:1", seeds)
    assert event["send_on_news"] == 1.0 and event["send_without_news"] == 0.0
    assert event["without_news"] == 0.0 and 0.0 < event["news_rate"] < 1.0
    sources = learners.news_use(task, "sources:0", seeds)
    assert sources["send_rate_own"] == 1.0 and sources["send_rate_other"] == 0.0
    assert sources["without_news"] == 0.0
    always = learners.news_use(task, "always", seeds)
    assert always["send_rate"] == 1.0 and always["without_news"] > 0.0
    assert always["send_without_news"] == 1.0


def test_news_use_runs_a_scripted_rule_in_the_tasks_control_mode(learners):
    """``message_cost-v0`` is no communication-only task: its rule ``settle:0.01`` runs in
    the config's control mode (transmit) and sends some messages without news, which
    the gate would close; without the mode the rule is refused by name."""
    seeds = [10**6, 10**6 + 1]
    settle = learners.news_use("message_cost-v0", "settle:0.01", seeds, control="transmit")
    assert 0.0 < settle["without_news"] < 1.0
    with pytest.raises(ValueError, match="communication-only control mode"):
        learners.news_use("message_cost-v0", "settle:0.01", seeds)


def test_policy_table_groups_a_learners_seeds_per_task(learners):
    """Rows of one learner on two tasks make one line per task (mean [min, max] over its
    seeds); a scripted row stands alone; a column that is nan throughout reads as a
    dash."""
    rows = [{"task": t, "policy": "mlp, 20M agent-steps", "run": f"runs/{t}/{s}", "x": v,
             "y": float("nan")} for t, vals in (("a", (1.0, 3.0)), ("b", (5.0, 7.0)))
            for s, v in enumerate(vals)]
    rows.append({"task": "a", "policy": "event:1", "run": "", "x": 2.0, "y": 0.5})
    lines = learners.policy_table(rows, (("x", "x", 1, 1, ""), ("y", "y", 100, 0, " %")),
                                  keys=("task",))
    assert lines[0] == "| task | policy (runs: mean over seeds [min, max]) | x | y |"
    assert lines[2:] == ["| a | mlp, 20M agent-steps (2 seeds) | 2.0 [1.0, 3.0] | – |",
                         "| b | mlp, 20M agent-steps (2 seeds) | 6.0 [5.0, 7.0] | – |",
                         "| a | event:1 | 2.0 | 50 % |"]


def test_thinned_relays_keep_own_news_and_thin_only_the_relays(learners):
    """``p = 1`` is ``event:1`` to the last digit; ``p = 0`` sends own news always and
    another agent's news never; ``p = 0.5`` relays about half of it; ``q = 0.4`` adds sends
    without news at about that rate (measured by the same pairing of choices and news as
    the learners' table)."""
    from netsense.benchmark.protocol import evaluate

    seeds = [10**6, 10**6 + 1]
    event = evaluate(learners.SUBSTATES_TASK, "event:1", seeds)["reward"]
    full = evaluate(learners.SUBSTATES_TASK, "p=1", seeds,
                    actor=learners.thinned_relays(1.0))["reward"]
    np.testing.assert_array_equal(full, event)
    for p, lo, hi in ((0.0, 0.0, 0.0), (0.5, 0.4, 0.6)):
        use = learners.substate_use("thinned", seeds, actor=learners.thinned_relays(p))
        assert use["send_own_news"] == 1.0 and use["send_without_news"] == 0.0
        assert lo <= use["send_others_news"] <= hi, (p, use)
    # q sends substates without news (where the mask lets the agent send them at all),
    # and leaves the choices on news alone
    noisy = learners.substate_use("noisy", seeds, actor=learners.thinned_relays(1.0, 0.4))
    assert noisy["send_own_news"] == 1.0 and noisy["send_others_news"] == 1.0
    assert 0.25 <= noisy["send_without_news"] <= 0.45, noisy


def test_agent_frame_slots_are_a_collision_free_time_division(learners):
    """Every phase pair puts exactly two sources (the channel's capacity) on the channel at
    every step, never a relay, each source on two steps in five: no collision, two messages
    delivered per step, like ``tdma:1``. Recorded per step: a rule that ignored the phase
    set or read the common clock would put all five sources, or none, on some steps."""
    from netsense.benchmark.protocol import evaluate

    seeds = [10**6, 10**6 + 1]
    for phases in learners.CHANNEL_RULES:
        steps = []
        evaluate(learners.CHANNEL_TASK, "slots", seeds, actor=learners.agent_frame_slots(
            phases), on_step=lambda core, live, steps=steps: steps.append(
                core.transmit[live].copy()))
        sent = np.stack(steps)  # (steps, B, N)
        np.testing.assert_array_equal(sent.sum(-1), 2)
        np.testing.assert_array_equal(sent[..., 1::2], 0)  # the relays: odd ids here
        k = np.arange(len(sent))[:, None, None]
        ids = np.arange(sent.shape[-1])[None, None]
        on = np.isin((k + 1 - ids) % 5, phases) & (ids % 2 == 0)  # t = k + 1 (sends at k+1)
        np.testing.assert_array_equal(sent.astype(bool), np.broadcast_to(on, sent.shape))
    use = learners.channel_use("slots", seeds, actor=learners.agent_frame_slots((0, 1)))
    assert use["collided_steps"] == 0.0 and use["delivered_per_step"] == 2.0
    # adjacent phases: runs of two sends (one where the episode cuts a run); apart: of one
    assert 1.9 < use["send_run"] < 2.0
    apart = learners.channel_use("slots", seeds, actor=learners.agent_frame_slots((0, 2)))
    assert apart["send_run"] == 1.0


def test_curve_reference_is_the_scripted_policy_on_the_curves_episodes(learners, tmp_path):
    """The learning curves' scripted line is the policy's return on the episodes of the
    periodic evaluation (seeds EVAL_SEED + b, the run's eval_envs), the same as the
    protocol's rollout on those seeds, and not its return on the test episodes."""
    pytest.importorskip("torch")
    import dataclasses
    import json

    from netsense.benchmark.protocol import eval_seeds, evaluate
    from netsense.rl.config import EVAL_SEED, PPOConfig

    config = PPOConfig(learners.CHANNEL_TASK, eval_envs=4)
    (tmp_path / "config.json").write_text(json.dumps(dataclasses.asdict(config)))
    got = learners.validation_return("tdma:1", tmp_path)
    same = evaluate(learners.CHANNEL_TASK, "tdma:1", range(EVAL_SEED, EVAL_SEED + 4))
    test = evaluate(learners.CHANNEL_TASK, "tdma:1", eval_seeds(4))
    assert got == pytest.approx(same["reward"].mean(), abs=1e-4)
    assert abs(got - test["reward"].mean()) > 0.1


def test_time_to_rule_counts_only_a_curve_that_stays(learners):
    def log(curve):
        return [{"agent_steps": str(1000 * (i + 1)), "wall_s": str(10.0 * (i + 1)),
                 "eval_return": "" if v is None else str(v)} for i, v in enumerate(curve)]

    # crosses at the 2nd evaluation, falls back, then reaches for good at the 4th
    assert learners.time_to_rule(log([-5, -1, -3, -2, None, -1]), -2.0) == (4000, 40.0)
    # rows without an evaluation are skipped, not read as below the rule
    assert learners.time_to_rule(log([None, -1, None, -1.5]), -2.0) == (2000, 20.0)
    # the last evaluation below the rule: never reached, whatever came before
    assert learners.time_to_rule(log([-1, -1, -3]), -2.0) is None
    assert learners.time_to_rule(log([None, None]), -2.0) is None


def test_acked_rule_is_a_function_of_the_current_row(learners):
    """On comm_fading-v0 ``acked(sources:0)`` sends after a delivery, never after a loss,
    stays silent 1 to 5 steps and probes at 6, read from the current row alone; its
    feed-forward twin (:func:`acked_twin`) plays the same episodes to the same returns. A
    twin probing one step early (``probe=5``) does not."""
    from netsense.benchmark.protocol import evaluate

    seeds = [10**6, 10**6 + 1, 10**6 + 2]
    rule = learners.reaction_use("comm_fading-v0", "acked(sources:0)", seeds)
    assert rule["send_delivered"] == 1.0 and rule["send_lost"] == 0.0
    assert all(rule[f"send_silent_{s}"] == 0.0 for s in range(1, 6))
    assert rule["send_silent_6"] == 1.0 and rule["share_silent_9_plus"] == 0.0
    twin = learners.reaction_use("comm_fading-v0", learners.TWIN, seeds)
    assert {k: v for k, v in twin.items() if k.startswith("send_")} == \
        {k: v for k, v in rule.items() if k.startswith("send_")}
    want = evaluate("comm_fading-v0", "acked(sources:0)", seeds)["reward"]

    def twin_of(probe):
        return lambda core, _seeds: learners.acked_twin(core, probe)

    got = evaluate("comm_fading-v0", "never", seeds, {}, actor=twin_of(6))["reward"]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    early = evaluate("comm_fading-v0", "never", seeds, {}, actor=twin_of(5))["reward"]
    assert not np.allclose(early, want)


def test_a_decision_is_worth_the_return_of_its_flip(learners):
    """:func:`decision_visits` forks the episode where one owner makes the other choice;
    the worth it gives a decision (the choice made minus the other, to the end) equals the
    difference of two whole episodes through the protocol, one with that single choice
    flipped. A scripted rule, whose memory a fork would not copy, is refused."""
    from netsense.benchmark.protocol import evaluate

    seeds = [10**6, 10**6 + 1]
    visits = learners.decision_visits("comm_fading-v0", learners.TWIN, seeds, every=50)
    assert {v[0] for v in visits} == {25, 75, 125, 175}

    def flipping(step, member, agent):
        def actor(core, _seeds):
            act, k = learners.acked_twin(core), [0]

            def flip(obs, mask):
                a = np.array(act(obs, mask))
                if k[0] == step:
                    a[member, agent] = 1 - a[member, agent]
                k[0] += 1
                return a

            return flip

        return actor

    base = evaluate("comm_fading-v0", "never", seeds, {},
                    actor=lambda core, _s: learners.acked_twin(core))["reward"]
    sent = next(v for v in visits if v[4])
    silent = next(v for v in visits if not v[4])
    for step, member, agent, _cls, _sent, worth in (sent, silent):
        flipped = evaluate("comm_fading-v0", "never", seeds, {},
                           actor=flipping(step, member, agent))["reward"]
        assert worth == pytest.approx(base[member] - flipped[member], abs=1e-9)
        others = [b for b in range(len(seeds)) if b != member]
        np.testing.assert_array_equal(flipped[others], base[others])
    with pytest.raises(ValueError, match="memory"):
        learners.decision_visits("comm_fading-v0", "acked(sources:0)", seeds)


def test_decision_visits_refuse_a_recurrent_policy(learners):
    """A fork's policy starts without the memory the recurrent policy had built."""
    pytest.importorskip("torch")
    gru = (learners.RESULTS / "memory_10m_gru" / "runs" / "comm_fading-v0" / "gru_clock"
           / "seed_0" / "policy.pt")
    with pytest.raises(ValueError, match="recurrent policy's memory"):
        learners.decision_visits("comm_fading-v0", f"learned:{gru}", [10**6])


def test_decision_values_count_only_a_clear_gain(learners, monkeypatch):
    """Per row class: the mean worth of sending over silence, whatever was chosen; the gain
    counts the choices against a mean beyond two standard errors, scaled to visits per
    episode (every 10th step, 2 episodes)."""
    lost, s9 = learners.ROW_CLASSES.index("lost"), learners.ROW_CLASSES.index("silent_9_plus")
    one = learners.ROW_CLASSES.index("silent_1")
    visits = ([(0, 0, 0, lost, True, -0.05)] * 3 + [(0, 0, 0, lost, False, 0.05)]  # send: -0.05
              + [(0, 0, 0, s9, False, -0.2), (0, 0, 0, s9, False, -0.4)]  # send: +0.2, +0.4
              + [(0, 0, 0, one, True, 1.0), (0, 0, 0, one, True, -1.0)])  # noise: no gain
    monkeypatch.setattr(learners, "decision_visits", lambda *a, **k: visits)
    v = learners.decision_values("comm_fading-v0", learners.TWIN, [0, 1], every=10)
    assert v["send_lost"] == 0.75 and v["visits_lost"] == 4 * 10 / 2
    assert v["value_lost"] == pytest.approx(-0.05) and v["value_se_lost"] == 0.0
    assert v["gain_lost"] == pytest.approx(3 * 0.05 * 10 / 2)  # the three sends were wrong
    assert v["value_silent_9_plus"] == pytest.approx(0.3)
    assert v["gain_silent_9_plus"] == pytest.approx(2 * 0.3 * 10 / 2)
    assert v["value_silent_1"] == 0.0 and v["gain_silent_1"] == 0.0
    assert v["gain_total"] == pytest.approx(v["gain_lost"] + v["gain_silent_9_plus"])
    assert v["visits_delivered"] == 0 and v["gain_delivered"] == 0.0


def test_a_rarer_message_earns_more_lifetime_credit(learners):
    """Under the lifetime reward a message's chain lasts until the receiver adopts again,
    so where the owners send rarely each message earns more; nobody else sends, and the
    team's return falls with the rate (fewer fresh estimates)."""
    pytest.importorskip("torch")
    rows = learners.credit_rates(rates=(0.5, 0.05), episodes=16)
    often, rare = rows
    assert rare["credit_per_message"] > often["credit_per_message"] > 0.0
    assert rare["team_return"] < often["team_return"]
    assert often["message_cost"] == 0.5


def test_standing_picks_the_best_reaching_learner_and_names_its_restriction(learners,
                                                                            tmp_path):
    """Per task: the one configuration at its largest budget, and the best run whose
    interval reaches the rule (a restricted learner named as such) over a better run that
    does not; runs with fewer than five seeds, sampled evaluations and warm-started
    learners do not count."""
    cols = ["task", "learner", "evaluation", "seeds", "iqm", "iqm_ci_low", "iqm_ci_high",
            "best_decentralised_spec", "best_decentralised_iqm", "reaches", "p_improvement",
            "agent_steps"]

    def folder(name, rows):
        (tmp_path / name).mkdir()
        lines = [",".join(cols)] + [",".join(str(v) for v in r) for r in rows]
        (tmp_path / name / "summary.csv").write_text("\n".join(lines) + "\n")

    t = "comm_substates-v0"
    folder("a", [(t, "mlp_news_gate", "greedy", 5, -94.3, -95.2, -93.5, "event:1", -94.2,
                  True, 0.5, 20_000_000),
                 (t, "mlp", "greedy", 5, -90.0, -99.0, -95.0, "event:1", -94.2, False, 0.4,
                  20_000_000),
                 (t, "mlp", "greedy", 3, -80.0, -81.0, -79.0, "event:1", -94.2, True, 0.9,
                  20_000_000),
                 (t, "mlp", "sampled", 5, -80.0, -81.0, -79.0, "event:1", -94.2, True, 0.9,
                  20_000_000),
                 (t, "mlp_bc_acked", "greedy", 5, -70.0, -71.0, -69.0, "event:1", -94.2,
                  True, 0.99, 20_000_000)])
    folder("b", [(t, "mlp", "greedy", 5, -108.8, -109.8, -107.9, "event:1", -94.2, False,
                  0.15, 10_000_000)])
    cfg = learners.load_config()
    rows = learners.standing(tmp_path, cfg, "mlp")
    assert [r["role"] for r in rows] == ["one configuration", "best learner"]
    one, best = rows
    assert one["folder"] == "a" and one["iqm"] == -90.0  # the larger budget, 5 seeds
    assert best["learner"] == "mlp_news_gate" and best["restriction"] == "news gate"
    assert learners.restriction(cfg["learners"]["clock_only"]) == "clock only"
    assert learners.restriction(cfg["learners"]["mlp_comm_fields"]) == "comm fields only"
    assert learners.restriction(cfg["learners"]["mlp_clock_ages"]) == ""
    assert learners.restriction(cfg["learners"]["mlp_lifetime"]) == "reward lifetime"


def test_train_runs_trains_every_task_in_one_launch_and_keeps_finished_runs(learners,
                                                                            tmp_path):
    """``train_runs`` trains the runs of several tasks with one launch (one pool for all
    of them: ``runs/summary.json`` lists every run, under ``<task>/<learner>``), writes
    each run where the evaluation looks for it, and trains no run again whose
    ``policy.pt`` exists."""
    pytest.importorskip("torch")
    import json

    tiny = {"steps": 2 * 4 * 8 * 10, "num_envs": 4, "rollout": 8, "minibatch": 16,
            "epochs": 2, "eval_interval": 1, "eval_envs": 2, "overrides": {"horizon": 12}}
    runs = [("message_cost-v1", "mlp", 0, dict(tiny, control="transmit")),
            ("comm_process_noise-v0", "mlp", 1, tiny)]
    folders = learners.train_runs(runs, tmp_path, retrain=False, progress=False)
    assert folders == [tmp_path / "runs/message_cost-v1/mlp/seed_0",
                       tmp_path / "runs/comm_process_noise-v0/mlp/seed_1"]
    assert all((d / "policy.pt").is_file() for d in folders)
    entries = json.loads((tmp_path / "runs/summary.json").read_text())
    assert [e["folder"] for e in entries] == ["message_cost-v1/mlp/seed_0",
                                              "comm_process_noise-v0/mlp/seed_1"]
    assert all(e["status"] == "ok" for e in entries)
    stamp = [(d / "policy.pt").stat().st_mtime_ns for d in folders]
    assert learners.train_runs(runs, tmp_path, retrain=False, progress=False) == folders
    assert [(d / "policy.pt").stat().st_mtime_ns for d in folders] == stamp


def test_level_points_find_the_last_visit_below_and_the_first_above(learners):
    x = np.array([1, 2, 3, 4, 5, 6])
    y = np.array([-190, -180, -188, -175, -160, -150])  # above -185 at 2, back below at 3
    assert learners.level_points(x, y, -185) == (3.0, 2.0)
    assert learners.level_points(x, y, -170) == (4.0, 5.0)
    last, first = learners.level_points(x, y, -100)  # never above
    assert last == 6.0 and np.isnan(first)
    last, first = learners.level_points(x, y, -200)  # never at or below
    assert np.isnan(last) and first == 1.0
    with pytest.raises(ValueError, match="equal length"):
        learners.level_points(x, y[:-1], -185)


def test_seed_points_read_the_last_evaluation_at_or_before_each_step(learners):
    log = [{"agent_steps": "100", "eval_return": "-5"}, {"agent_steps": "200", "eval_return": ""},
           {"agent_steps": "300", "eval_return": "-3"}, {"agent_steps": "400", "eval_return": ""}]
    got = learners.seed_points(log, [50, 100, 299, 300, 1000])
    assert np.isnan(got[0]) and got[1:] == [-5.0, -5.0, -3.0, -3.0]
    for r, m in zip(log, ["0.5", "", "0.25", ""], strict=True):
        r["eval_messages"] = m
    assert learners.seed_points(log, [100, 400], "eval_messages") == [0.5, 0.25]


def test_curve_points_command_counts_the_seeds_that_rise(learners, tmp_path):
    import csv

    rows = [{"task": "t", "learner": "m", "agent_steps": s, "iqm": v, "ci_low": v,
             "ci_high": v} for s, v in [(100, -190), (200, -170), (300, -160)]]
    learners.write_csv(tmp_path / "curves.csv", rows)
    for seed, (a, b) in enumerate([(-10, -9), (-8, -9), (-7, -6)]):
        d = tmp_path / "runs" / "t" / "m" / f"seed_{seed}"
        d.mkdir(parents=True)
        learners.write_csv(d / "log.csv", [{"agent_steps": 100, "eval_return": a},
                                           {"agent_steps": 300, "eval_return": b}])
    learners.main(["curve-points", "--out", str(tmp_path), "--levels", "-180",
                   "--at", "150", "300"])
    md = (tmp_path / "curve_points.md").read_text()
    assert "| t | m | -180 | 0.0M | 0.0M |" in md  # 100 at or below, 200 above: 0.0M each
    assert "| 2 of 3 |" in md
    with (tmp_path / "curve_points.csv").open() as fh:
        out = list(csv.DictReader(fh))
    level = next(r for r in out if r["what"] == "validation IQM")
    assert (float(level["last_at_or_below"]), float(level["first_above"])) == (100.0, 200.0)
    assert [float(r["at_300"]) for r in out if r["what"] == "per seed"] == \
        [-9.0, -9.0, -6.0]
    with pytest.raises(ValueError, match="no column 'eval_messages'"):
        learners.main(["curve-points", "--out", str(tmp_path), "--at", "150",
                       "--column", "eval_messages"])
    with pytest.raises(SystemExit, match="increasing"):
        learners.main(["curve-points", "--out", str(tmp_path), "--at", "300", "150"])
    with pytest.raises(SystemExit, match="does not exist"):
        learners.main(["curve-points", "--out", str(tmp_path / "nowhere"), "--levels", "0"])
