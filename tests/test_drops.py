"""Arrival models (netsense.sensing.drops): statistics against closed forms, pickling, specs.

Statistical checks use a fixed seed and a tolerance of 4 standard errors of the estimator
(for Markov samples the standard error includes the autocorrelation inflation
``(1 + rho) / (1 - rho)``, ``rho = 1 - p_gb - p_bg``).
"""

import pickle

import numpy as np
import pytest

from netsense.sensing.arrivals import AlwaysArrive, ArrivalModel, ArrivalSampler
from netsense.sensing.drops import BernoulliArrivals, GilbertElliottArrivals, arrival_from_dict


def draw(model, steps, channels, seed=0):
    s = model.sampler(np.random.default_rng(seed), (channels,))
    return np.stack([s.next() for _ in range(steps)])      # (steps, channels)


def drop_bursts(arrived):
    """Lengths of completed runs of drops (bounded by arrivals on both sides) per channel."""
    out = []
    for col in arrived.T:
        d = np.diff(np.r_[0, (~col).astype(int), 0])
        starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
        lengths = ends - starts
        if len(lengths) and starts[0] == 0:
            lengths = lengths[1:]
        if len(lengths) and ends[-1] == len(col):
            lengths = lengths[:-1]
        out.append(lengths)
    return np.concatenate(out)


def test_bernoulli_rate_and_bursts():
    m = BernoulliArrivals(0.8)
    a = draw(m, 2000, 100)
    assert a.dtype == bool and a.shape == (2000, 100)
    n = a.size
    assert abs((~a).mean() - m.loss_rate) < 4 * np.sqrt(0.8 * 0.2 / n)
    b = drop_bursts(a)
    sd = np.sqrt(0.2) / 0.8                      # geometric(0.8) burst length
    assert abs(b.mean() - m.mean_burst_length) < 4 * sd / np.sqrt(b.size)


def test_gilbert_stationary_loss_rate_and_mean_burst():
    p_gb, p_bg = 0.05, 0.25
    m = GilbertElliottArrivals(p_gb, p_bg)
    assert m.loss_rate == pytest.approx(p_gb / (p_gb + p_bg))
    assert m.mean_burst_length == pytest.approx(4.0)
    a = draw(m, 4000, 100, seed=1)
    pi, rho = m.loss_rate, 1 - p_gb - p_bg
    se = np.sqrt(pi * (1 - pi) * (1 + rho) / (1 - rho) / a.size)
    assert abs((~a).mean() - pi) < 4 * se
    b = drop_bursts(a)
    assert abs(b.mean() - 4.0) < 4 * np.sqrt(1 - p_bg) / p_bg / np.sqrt(b.size)
    # bursts are much longer than Bernoulli ones at the same loss rate (1/(1-pi) = 1.2)
    assert b.mean() > 3 * BernoulliArrivals(1 - pi).mean_burst_length


def test_gilbert_elliott_partial_losses():
    m = GilbertElliottArrivals(0.1, 0.3, loss_good=0.1, loss_bad=0.8)
    expected = 0.75 * 0.1 + 0.25 * 0.8
    assert m.loss_rate == pytest.approx(expected)
    a = draw(m, 4000, 50, seed=2)
    se = np.sqrt(expected * (1 - expected) * (1 + 0.6) / (1 - 0.6) / a.size)
    assert abs((~a).mean() - expected) < 4 * se
    with pytest.raises(ValueError, match="closed form only"):
        _ = m.mean_burst_length


def test_gilbert_start_state():
    first = GilbertElliottArrivals(0.1, 0.2, start="bad").sampler(
        np.random.default_rng(0), (1000,)).next()
    assert not first.any()
    first = GilbertElliottArrivals(0.1, 0.2, start="good").sampler(
        np.random.default_rng(0), (1000,)).next()
    assert first.all()


@pytest.mark.parametrize("model", [BernoulliArrivals(0.6), GilbertElliottArrivals(0.2, 0.4)])
def test_samplers_pickle_and_resume(model):
    assert isinstance(model, ArrivalModel)
    s = model.sampler(np.random.default_rng(3), (4, 2))
    assert isinstance(s, ArrivalSampler)
    for _ in range(5):
        s.next()
    clone = pickle.loads(pickle.dumps(s))
    for _ in range(20):
        np.testing.assert_array_equal(s.next(), clone.next())


@pytest.mark.parametrize("model", [BernoulliArrivals(0.8), AlwaysArrive(),
                                   GilbertElliottArrivals(0.1, 0.5, 0.05, 0.9, "bad")])
def test_dict_round_trip(model):
    assert arrival_from_dict(model.to_dict()) == model


@pytest.mark.parametrize("spec, match", [
    ([0.8], "must be a dict"),
    ({"kind": "markov"}, "field 'kind'"),
    ({"kind": "bernoulli"}, "missing field 'p'"),
    ({"kind": "bernoulli", "p": 1.5}, r"BernoulliArrivals.p must be a number in \[0, 1\]"),
    ({"kind": "bernoulli", "p": "0.8"}, "BernoulliArrivals.p"),
    ({"kind": "bernoulli", "p": 0.8, "q": 1}, r"unknown field\(s\) \['q'\]"),
    ({"kind": "gilbert_elliott", "p_good_to_bad": 0.1}, "missing field 'p_bad_to_good'"),
    ({"kind": "gilbert_elliott", "p_good_to_bad": 0.1, "p_bad_to_good": 0.2,
      "loss_bad": -1}, "GilbertElliottArrivals.loss_bad"),
    ({"kind": "gilbert_elliott", "p_good_to_bad": 0.0, "p_bad_to_good": 0.0},
     "must not both be 0"),
    ({"kind": "gilbert_elliott", "p_good_to_bad": 0.1, "p_bad_to_good": 0.2,
      "start": "worst"}, "GilbertElliottArrivals.start"),
])
def test_bad_specs_name_the_field(spec, match):
    with pytest.raises(ValueError, match=match):
        arrival_from_dict(spec)
