"""experiments/rl/learnability.py: the smoke run's outputs, disjoint seeds, and a pipeline
that learns a bit which is a function of one observation field exactly."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from experiment_loader import load_experiment

from netsense.benchmark import protocol as pr

pytest.importorskip("sklearn")
exp = load_experiment("rl/learnability")


def _observations(task="comm_process_noise-v0", episodes=6, horizon=30):
    """Real observations (E, T, N, F) of ``always`` on ``task``, and the core's layout."""
    from netsense.engine.core import BatchedCore
    from netsense.env.comm_policies import make_comm_policy
    from netsense.env.vector import load_model

    model, _ = load_model(task, horizon=horizon)
    core = BatchedCore(model, episodes)
    pol = make_comm_policy("always", core)
    obs, mask = core.reset(list(range(episodes)))
    seq = []
    for _ in range(horizon):
        seq.append(obs.copy())
        out = core.step(pol.act(obs, mask))
        obs, mask = out.obs, out.action_mask
    return np.stack(seq, axis=1), core.layout


def _record(obs, bits):
    E, T, N, _ = obs.shape
    return {"obs": obs, "bits": bits[..., None].astype(np.int8),
            "mask": np.ones((E, T, N, 2), np.int8), "live": np.ones((E, T), bool)}


def test_smoke_run_writes_the_documented_outputs(tmp_path):
    rows = exp.main(["--smoke", "--tasks", "comm_process_noise-v0", "--out", str(tmp_path),
                     "--no-progress"])
    for name in ("learnability.csv", "learnability.md", "learnability.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    with (tmp_path / "learnability.csv").open(newline="") as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames) == exp.COLUMNS
        read = list(reader)
    assert len(read) == len(rows) == 1
    r = read[0]
    train = range(int(r["train_seed_first"]), int(r["train_seed_last"]) + 1)
    evaluation = range(int(r["eval_seed_first"]), int(r["eval_seed_last"]) + 1)
    assert len(train) == int(r["episodes"]) == 2 and len(evaluation) == 2
    assert not set(train) & set(pr.eval_seeds()) and not set(train) & set(evaluation)
    assert max(train) < pr.TRAIN_SEED_LIMIT
    assert int(r["train_episodes"]) + int(r["val_episodes"]) + int(r["test_episodes"]) == 2
    for f in ("a", "b"):
        assert 0.0 <= float(r[f"balanced_accuracy_{f}"]) <= 1.0
        assert r[f"model_{f}"] in (*exp.MODELS, "constant")
        assert np.isfinite(float(r[f"clone_return_mean_{f}"]))
        assert r[f"recovered_{f}"] == "nan"  # a 12-step horizon: no comparable reference
    assert 0.0 <= float(r["positive_share"]) <= 1.0
    assert int(r["agent_steps"]) == 2 * 12 * 10
    table = (tmp_path / "learnability.md").read_text()
    for col in ("balanced acc. (a)", "balanced acc. (b)", "clone return (a)",
                "bound return", "best decentralised", "headroom recovered"):
        assert col in table
    assert "| comm_process_noise-v0 | 2 |" in table


def test_training_seeds_are_never_evaluation_seeds():
    assert exp.TRAIN_SEED0 + 10_000 <= pr.TRAIN_SEED_LIMIT <= pr.EVAL_SEED0


def test_a_bit_that_is_one_observation_field_is_learned_exactly():
    """Bits equal to one binary field of the agent's own observation: (a) is learned with
    balanced accuracy 1.0; bits equal to the field one step earlier: (b), with history."""
    obs, layout = _observations()
    field = obs[..., layout.slot_arrived.start] > 0.5  # (E, T, N): a message in slot 0
    assert 0.1 < field.mean() < 0.9
    train, val, test = exp.split_episodes(obs.shape[0])
    rec = _record(obs, field)
    X, y, episode = exp.samples(rec, 1)
    fit = exp.fit_classifier(X, y, episode, train, val, test)
    assert fit["balanced_accuracy"] == 1.0
    lagged = np.zeros_like(field)
    lagged[:, 1:] = field[:, :-1]
    X, y, episode = exp.samples(_record(obs, lagged), exp.HISTORY)
    fit = exp.fit_classifier(X, y, episode, train, val, test)
    assert fit["balanced_accuracy"] == 1.0


def test_episodes_not_steps_are_held_out():
    train, val, test = exp.split_episodes(30)
    assert (len(train), len(val), len(test)) == (18, 6, 6)
    assert not set(train) & set(test) and not set(val) & set(test)
    train, val, test = exp.split_episodes(2)
    assert list(train) == [0] and list(test) == [1] and not len(val)
    obs = np.arange(3 * 4 * 2 * 1, dtype=np.float32).reshape(3, 4, 2, 1)
    X, y, episode = exp.samples(_record(obs, np.ones(obs.shape[:3], bool)), 1)
    np.testing.assert_array_equal(episode, np.repeat(np.arange(3), 8))


def test_substate_samples_are_the_features_the_clone_builds():
    """In ``substates`` mode a sample is the agent's features then its bit's one-hot, as
    :func:`with_substate` builds them for the acting clone; forced bits are left out."""
    rng = np.random.default_rng(0)
    E, T, N, F, W = 2, 5, 3, 4, 3
    obs = rng.normal(size=(E, T, N, F)).astype(np.float32)
    mask = np.ones((E, T, N, 2 * W), np.int8)
    mask[0, 1, 2, 3] = 0  # bit 1 of agent 2 at step 1 cannot be 1
    rec = {"obs": obs, "mask": mask, "bits": rng.integers(0, 2, (E, T, N, W)),
           "live": np.ones((E, T), bool)}
    X, y, episode = exp.samples(rec, 2)
    full = exp.with_substate(np.moveaxis(exp.stack_history(np.moveaxis(obs, 1, 0), 2), 0, 1),
                             W)
    keep = exp.free_bits(mask)
    assert keep.sum() == E * T * N * W - 1 == len(y)
    np.testing.assert_array_equal(X, full[keep])
    np.testing.assert_array_equal(y, rec["bits"][keep])


def test_history_is_newest_first_and_zero_before_the_episode():
    seq = np.arange(1, 4, dtype=np.float32)[:, None]  # (T=3, F=1)
    np.testing.assert_array_equal(exp.stack_history(seq, 2), [[1, 0], [2, 1], [3, 2]])


def test_the_clone_acts_on_the_same_features_it_was_trained_on():
    """In closed loop, a stand-in classifier that returns the stacked features' field of
    the previous step transmits exactly when that field was set one step earlier, and
    never where the mask forbids it."""
    task, seeds = "comm_process_noise-v0", [5, 6]
    layout = _observations(episodes=1, horizon=2)[1]
    col = layout.size + layout.slot_arrived.start  # the field in the second stacked block

    class Previous:
        def predict(self, X):
            return (X[:, col] > 0.5).astype(int)

    seen = []

    def actor(core, s):
        act = exp.clone_actor(Previous(), exp.HISTORY, 1)(core, s)

        def wrapped(obs, mask):
            bits = act(obs, mask)
            seen.append((obs[..., layout.slot_arrived.start] > 0.5, bits[..., 0], mask))
            return bits
        return wrapped

    pr.evaluate(task, "clone:test", seeds, {"horizon": 15}, actor=actor)
    assert len(seen) == 15
    for k in range(1, 15):
        prev, (_, bits, mask) = seen[k - 1][0], seen[k]
        on, off = mask[..., 1] > 0, mask[..., 0] > 0
        np.testing.assert_array_equal(bits, np.where(on & off, prev, on))
    assert not seen[0][1].any()  # zeros before the episode start


def test_recovered_is_the_fraction_of_the_headroom():
    assert exp.recovered(-95.0, -90.0, -100.0) == pytest.approx(0.5)
    assert exp.recovered(-100.0, -90.0, -100.0) == 0.0
    assert np.isnan(exp.recovered(-95.0, -100.0, -100.0))
