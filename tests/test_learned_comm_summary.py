"""The summary of experiments/rl/learned_comm.py on hand-built frontier rows: the
scripted step envelope, the message saving at equal error and the 30 % aim."""

from __future__ import annotations

import math

import pytest
from experiment_loader import load_experiment

lc = load_experiment("rl/learned_comm")


def _row(family, policy, error, msgs, reward, evaluation="scripted"):
    r = {"scenario": "toy-v0", "control": "transmit", "family": family, "policy": policy,
         "knob": policy, "evaluation": evaluation}
    for m, v in (("mean_rel_error", error), ("msgs_per_agent_step", msgs),
                 ("load_per_agent_step", msgs), ("reward", reward)):
        r.update({f"{m}_mean": v, f"{m}_ci_low": v - 0.01, f"{m}_ci_high": v + 0.01})
    return r


ROWS = [_row("always", "always", 0.30, 1.0, -120), _row("never", "never", 0.95, 0.0, -190),
        _row("periodic", "periodic:2", 0.40, 0.5, -110),
        _row("sources", "sources:0", 0.35, 0.6, -100),
        _row("whittle", "whittle:2", 0.32, 0.4, -95)]


def test_convex_hull_of_the_scripted_frontier():
    xm = "msgs_per_agent_step"
    # hull: never (0, 0.95) -> whittle (0.4, 0.32) -> always (1.0, 0.30); periodic and
    # sources lie above it
    assert lc.scripted_hull(ROWS, xm) == [(0.0, 0.95), (0.4, 0.32), (1.0, 0.30)]
    assert lc.scripted_messages(ROWS, 0.40, xm) == pytest.approx(0.4 * 0.55 / 0.63)
    assert lc.scripted_messages(ROWS, 0.31, xm) == pytest.approx(0.7)
    assert lc.scripted_messages(ROWS, 0.99, xm) == 0.0
    assert math.isnan(lc.scripted_messages(ROWS, 0.2, xm))  # no scripted point gets there
    # learned rows never count as scripted
    rows = ROWS + [_row("learned", "runs/x/ppo/seed_0/policy.pt", 0.1, 0.01, -1, "greedy")]
    assert math.isnan(lc.scripted_messages(rows, 0.2, xm))


def test_saving_at_equal_error_and_the_aim():
    good = _row("learned", "runs/x/bc_ppo/seed_1/policy.pt", 0.30, 0.6, -90, "sampled")
    bad = _row("learned", "runs/x/ppo/seed_0/policy.pt", 0.45, 0.5, -130, "greedy")
    points, sentence = lc.summarise(ROWS + [good, bad])
    by = {p["variant"]: p for p in points}
    # error 0.30: only always (1.0 message) reaches it: 40 % fewer
    assert by["bc_ppo"]["saving"] == pytest.approx(0.4)
    assert by["bc_ppo"]["saving_at_freshness_error"] == pytest.approx(0.4)
    # error 0.45: the hull between never and whittle needs 0.4 * 0.5 / 0.63 messages
    assert by["ppo"]["saving"] == pytest.approx(1 - 0.5 / (0.4 * 0.5 / 0.63))
    assert not by["ppo"]["reaches_freshness_error"]
    assert "meets the 30 % aim" in sentence and "bc_ppo seed 1" in sentence
    # upper ends: 0.61 messages against the hull at error 0.31 (0.7 messages)
    assert by["bc_ppo"]["robust_saving"] == pytest.approx(1 - 0.61 / 0.7)
    assert "1 of 2 learned points lie below the scripted frontier beyond their 95 %" in sentence


def test_aim_missed_or_void():
    bad = _row("learned", "runs/x/ppo/seed_0/policy.pt", 0.45, 0.5, -130, "greedy")
    _, sentence = lc.summarise(ROWS + [bad])
    assert "none reaches the freshness observer's error" in sentence
    assert "no learned point lies below the scripted frontier beyond its 95 %" in sentence
    # a point below the frontier in the means only, within its intervals, is not counted
    near = _row("learned", "runs/x/ppo/seed_2/policy.pt", 0.40, 0.33, -100, "sampled")
    for k in ("mean_rel_error", "msgs_per_agent_step", "load_per_agent_step"):
        near[f"{k}_ci_high"] = near[f"{k}_mean"] + 0.05
    points, sentence = lc.summarise(ROWS + [near])
    assert points[0]["saving"] > 0 and not points[0]["robust_saving"] > 0
    assert "1 do in the means alone" in sentence
    # on a channel where always collides, never reaches the freshness error: void
    rows = [_row("always", "always", 0.95, 1.0, -199), _row("never", "never", 0.94, 0.0, -189),
            _row("periodic", "periodic:5", 0.5, 0.2, -117), bad]
    _, sentence = lc.summarise(rows)
    assert "void" in sentence


def test_best_decentralised_skips_the_centralised_schedulers():
    assert lc.best_decentralised(ROWS)["policy"] == "sources:0"
