"""Asynchronous multi-rate sensing: report pattern, stacking, and equivalence with OSE."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from netsense.estimators import online_analysis as oa
from netsense.estimators.online import ose_step
from netsense.sensing.arrivals import ArrivalModel, ArrivalSampler
from netsense.sensing.multirate import (
    MultiRateArrivals,
    MultiRateSensing,
    Sensor,
    multirate_from_dict,
)


def test_periodic_pattern_matches_hand_listing():
    model = MultiRateArrivals(periods=(2, 3, 5), phases=(1, 0, 4))
    assert isinstance(model, ArrivalModel)
    s = model.sampler(np.random.default_rng(0), (3,))
    assert isinstance(s, ArrivalSampler)
    got = np.array([s.next() for _ in range(10)])
    expected_steps = [{1, 3, 5, 7, 9}, {0, 3, 6, 9}, {4, 9}]
    for i, steps in enumerate(expected_steps):
        assert set(np.flatnonzero(got[:, i])) == steps
    np.testing.assert_array_equal(got, model.schedule(10))


def test_jitter_keeps_one_report_per_period_and_drops_thin_reports():
    model = MultiRateArrivals(periods=(10, 7), phases=(3, 0), jitter=4)
    s = model.sampler(np.random.default_rng(1), (50, 2))      # 50 independent copies
    got = np.array([s.next() for _ in range(700)])              # (700, 50, 2)
    for i, (P, ph) in enumerate(zip(model.periods, model.phase_tuple, strict=True)):
        for j in range(60):                     # report j lies in [ph + jP, ph + jP + 4]
            lo = ph + j * P
            window = got[lo: lo + model.jitter + 1, :, i]
            assert np.all(window.sum(axis=0) == 1)
        assert got[:, :, i].sum(axis=0).max() <= 700 // P + 1
    drop = MultiRateArrivals(periods=(1,), drop_prob=0.3)
    d = drop.sampler(np.random.default_rng(2), (4000, 1))
    frac = np.mean([d.next().mean() for _ in range(5)])
    assert frac == pytest.approx(0.7, abs=0.02)                 # ~5 sigma at n = 20000


def test_sampler_pickles_mid_stream():
    s = MultiRateArrivals(periods=(3, 4), jitter=2, drop_prob=0.1).sampler(
        np.random.default_rng(3), (5, 2))
    for _ in range(7):
        s.next()
    clone = pickle.loads(pickle.dumps(s))
    for _ in range(20):
        np.testing.assert_array_equal(s.next(), clone.next())


def test_dict_round_trip_and_errors_name_the_field():
    model = MultiRateArrivals(periods=(60, 3600), phases=(5, 100), jitter=2, drop_prob=0.05)
    assert multirate_from_dict(model.to_dict()) == model
    bad = [
        ({"periods": [0, 2]}, "periods"),
        ({"periods": [2, 3], "phases": [0]}, "phases"),
        ({"periods": [2, 3], "phases": [0, 3]}, "phases"),
        ({"periods": [2, 3], "jitter": 2}, "jitter"),
        ({"periods": [2, 3], "drop_prob": 1.0}, "drop_prob"),
        ({"periods": [2], "rate": 3}, "rate"),
        ({"phases": [0]}, "periods"),
        ({"kind": "bernoulli", "periods": [2]}, "kind"),
        ({"periods": 5}, "periods"),
    ]
    for spec, field in bad:
        with pytest.raises(ValueError, match=field):
            multirate_from_dict(spec)
    with pytest.raises(ValueError, match="number of sensors"):
        model.sampler(np.random.default_rng(0), (3,))


def _sensing(rng, N=5):
    sensors = (
        Sensor(A=rng.standard_normal((2, N)), Q=[0.5, 0.2], b=[1.0, -1.0], name="s0"),
        Sensor(A=rng.standard_normal((1, N)), Q=[[0.3]], name="s1"),
        Sensor(A=rng.standard_normal((3, N)), Q=np.diag([0.1, 0.2, 0.4]) + 0.05, name="s2"),
    )
    return MultiRateSensing(sensors, MultiRateArrivals(periods=(2, 3, 4), phases=(0, 1, 3)))


def test_stack_selects_reported_sensors_in_order():
    rng = np.random.default_rng(4)
    sens = _sensing(rng)
    A, Q, b = sens.stack([True, False, True])
    np.testing.assert_array_equal(A, np.vstack([sens.sensors[0].A, sens.sensors[2].A]))
    np.testing.assert_array_equal(Q[:2, :2], sens.sensors[0].Q)
    np.testing.assert_array_equal(Q[2:, 2:], sens.sensors[2].Q)
    np.testing.assert_array_equal(Q[:2, 2:], 0.0)
    np.testing.assert_array_equal(b, [1.0, -1.0, 0.0, 0.0, 0.0])
    A0, Q0, b0 = sens.stack([False, False, False])
    assert A0.shape == (0, 5) and Q0.shape == (0, 0) and b0.shape == (0,)


def test_padded_batch_step_equals_stacked_step():
    rng = np.random.default_rng(5)
    sens = _sensing(rng)
    R = 6
    reported = rng.random((R, 3)) < 0.5
    x = rng.standard_normal((R, sens.N))
    x_prev = rng.standard_normal((R, sens.N))
    y_all = sens.measure_all(x, rng)
    y, A, Q, b = sens.padded(reported, y_all)
    batched = ose_step(x_prev, y, A, 0.3, Q, b)
    rows = sens.row_mask(reported)
    for r in range(R):
        As, Qs, bs = sens.stack(reported[r])
        one = ose_step(x_prev[r], y_all[r, rows[r]], As, 0.3, Qs, bs)
        np.testing.assert_allclose(batched[r], one, atol=1e-12)


def test_measurement_noise_has_the_sensor_covariance():
    rng = np.random.default_rng(6)
    sens = _sensing(rng)
    x = np.zeros((40000, sens.N))
    y = sens.measure_all(x, rng) - sens.b_full
    np.testing.assert_allclose(np.cov(y.T), sens.Q_full, atol=0.02)


def test_tau_of_the_pattern_with_coordinate_sensors():
    # sensor i measures coordinate i: every window of max(period) steps sees all of them
    I = np.eye(3)
    model = MultiRateArrivals(periods=(2, 3, 5), phases=(0, 2, 1))
    sens = MultiRateSensing(tuple(Sensor(A=I[[i]], Q=[1.0]) for i in range(3)), model)
    pattern = model.schedule(40)
    seq = [sens.stack(m)[0] for m in pattern]
    assert oa.smallest_tau(seq) == model.tau_bound() == 5


def test_sensor_validation():
    with pytest.raises(ValueError, match="positive definite"):
        Sensor(A=np.ones((1, 2)), Q=[0.0])
    with pytest.raises(ValueError, match="Q must have shape"):
        Sensor(A=np.ones((2, 2)), Q=[1.0])
    with pytest.raises(ValueError, match="b must have shape"):
        Sensor(A=np.ones((1, 2)), Q=[1.0], b=[1.0, 2.0])
    with pytest.raises(ValueError, match="columns"):
        MultiRateSensing((Sensor(A=np.ones((1, 2)), Q=[1.0]), Sensor(A=np.ones((1, 3)),
                                                                     Q=[1.0])),
                         MultiRateArrivals(periods=(1, 1)))
    with pytest.raises(ValueError, match="2 sensors"):
        MultiRateSensing((Sensor(A=np.ones((1, 2)), Q=[1.0]), Sensor(A=np.ones((1, 2)),
                                                                     Q=[1.0])),
                         MultiRateArrivals(periods=(1,)))
