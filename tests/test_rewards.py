"""The compiled step tail (rewards, transmit flags, episode flags) against numpy formulas."""

import numpy as np
import pytest

from netsense.engine.model import RewardConfig
from netsense.engine.rewards import finish_step


def _numpy_tail(x, err, act, M, silenced, alive, rw, lim, k, horizon):
    """The reward of RewardConfig's docstring, written with whole-array numpy operations."""
    scale = np.maximum(np.linalg.norm(x, axis=1), rw.error_floor)
    raw = err / scale[:, None]
    e = np.fmin(raw, rw.error_clip)
    mean = e[:, alive].mean(1, keepdims=True)
    r = -rw.error_weight * ((1 - rw.team_weight) * e + rw.team_weight * mean)
    r[:, ~alive] = 0.0
    tx = (act[..., M] != 0) & ~silenced
    r -= rw.message_cost * tx
    term = np.zeros(len(x), bool) if lim is None else ~(raw[:, alive].max(1) <= lim)
    trunc = (k >= horizon) & ~term
    return r, raw, e, tx, term, trunc


@pytest.mark.parametrize("lim", [None, 2.0])
@pytest.mark.parametrize("team", [0.0, 0.3, 1.0])
def test_finish_step_matches_numpy_formulas_with_blowups_and_faults(lim, team):
    rng = np.random.default_rng(1)
    B, N, n, M = 300, 7, 4, 5
    x = rng.standard_normal((B, n)) * rng.choice([1e-5, 1.0, 10.0], size=(B, 1))
    err = np.abs(rng.standard_normal((B, N))) * 3
    err[rng.random((B, N)) < 0.05] = np.nan  # inf - inf in a blown-up estimate
    err[rng.random((B, N)) < 0.05] = np.inf
    x[0] = np.inf  # a blown-up plant: ||x|| = inf
    x[1, 0] = np.nan  # and one that went inf - inf
    act = rng.integers(0, 3, size=(B, N, M + 1))
    act[..., M] = rng.integers(0, 2, size=(B, N))
    silenced = rng.random((B, N)) < 0.2
    alive = np.array([True, True, False, True, True, True, False])
    rw = RewardConfig(error_weight=1.5, team_weight=team, message_cost=0.2,
                      error_floor=1e-3, error_clip=4.0)
    k = rng.integers(0, 12, size=B)
    sent0 = rng.integers(0, 5, size=B)
    sent = sent0.copy()
    got = finish_step(x, err, act, M, silenced, alive, rw, lim, k, 10, sent)
    want = _numpy_tail(x, err, act, M, silenced, alive, rw, lim, k, 10)
    for g, w, name in zip(got, (want[0], want[1], want[2], want[3], want[4], want[5]),
                          ("reward", "raw", "errors", "transmit", "terminated", "truncated"),
                          strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-12, atol=0, err_msg=name)
    np.testing.assert_array_equal(sent, sent0 + want[3].sum(1))
    assert np.isnan(got.raw_errors).any() and got.terminated.any() == (lim is not None)


def test_finish_step_without_crashes_transmits_every_set_bit():
    B, N, M = 4, 3, 2
    act = np.zeros((B, N, M + 1), np.int64)
    act[:, 1, M] = 1
    sent = np.zeros(B, np.int64)
    out = finish_step(np.ones((B, 2)), np.zeros((B, N)), act, M, None, np.ones(N, bool),
                      RewardConfig(message_cost=0.5), None, np.zeros(B, np.int64), 5, sent)
    np.testing.assert_array_equal(out.transmit, act[..., M] == 1)
    np.testing.assert_array_equal(out.reward, -0.5 * (act[..., M] == 1))
    np.testing.assert_array_equal(sent, np.ones(B))


@pytest.mark.parametrize("which", ["x", "act", "alive", "k", "sent", "silenced", "err"])
def test_finish_step_names_a_misshapen_array_and_writes_nothing(which):
    B, N, M = 3, 4, 2
    args = {"x": np.ones((B, 2)), "err": np.zeros((B, N)),
            "act": np.ones((B, N, M + 1), np.int64), "alive": np.ones(N, bool),
            "k": np.zeros(B, np.int64), "sent": np.zeros(B, np.int64),
            "silenced": np.zeros((B, N), bool)}
    args[which] = args[which][:-1] if which != "err" else np.zeros(B)
    sent = args["sent"].copy()
    name = {"sent": "messages_sent"}.get(which, which)
    with pytest.raises(ValueError, match=name):
        finish_step(args["x"], args["err"], args["act"], M, args["silenced"], args["alive"],
                    RewardConfig(), None, args["k"], 5, args["sent"])
    np.testing.assert_array_equal(args["sent"], sent[:len(args["sent"])])


def test_finish_step_writes_into_given_arrays_and_refuses_wrong_ones():
    rng = np.random.default_rng(3)
    B, N, M = 5, 4, 2
    x, err = rng.standard_normal((B, 3)), np.abs(rng.standard_normal((B, N)))
    act = rng.integers(0, 2, size=(B, N, M + 1))
    args = (x, err, act, M, None, np.ones(N, bool), RewardConfig(), 3.0,
            np.full(B, 2), 5)
    ref = finish_step(*args, np.zeros(B, np.int64))
    out = type(ref)(*(np.full(a.shape, np.nan) if a.dtype.kind == "f" else
                      np.zeros(a.shape, bool) for a in ref))
    got = finish_step(*args, np.zeros(B, np.int64), out)
    for g, o, w in zip(got, out, ref, strict=True):
        assert g is o
        np.testing.assert_array_equal(g, w)
    sent = np.zeros(B, np.int64)
    for bad in (out._replace(errors=np.zeros((B, N + 1))),
                out._replace(transmit=np.zeros((B, N))),
                out._replace(raw_errors=np.zeros((N, B)).T)):
        with pytest.raises(ValueError, match="out[.]"):
            finish_step(*args, sent, bad)
    assert not sent.any()  # nothing counted before the refusal


@pytest.mark.parametrize("field", ["error_weight", "team_weight", "message_cost",
                                   "error_floor", "error_clip"])
@pytest.mark.parametrize("value", [float("nan"), float("inf"), "1"])
def test_reward_config_rejects_non_numbers(field, value):
    with pytest.raises(ValueError, match=f"reward.{field}"):
        RewardConfig(**{field: value})
