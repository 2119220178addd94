"""Equalized observer as a source node's local estimator inside the distributed observer,
with the source's data arriving through a delay channel."""

import numpy as np
import pytest

from netsense.estimators.equalized import EqualizedRecoveryEstimator
from netsense.observers.freshness import FreshnessObserver
from netsense.observers.source_estimators_equalized import EqualizedSource
from netsense.sensing.delays import DelayLanguage
from netsense.systems.design import design_observer
from netsense.systems.plants import Plant

ETA = 0.05


def setup(seed):
    plant = Plant(A=[[1.1, 0.3], [0.0, 0.9]], C=(np.array([[1.0, 0.0]]), np.zeros((0, 2))))
    design = design_observer(plant)
    lang = DelayLanguage.each_delayed_at_most(1, 3)
    src = EqualizedSource(lang, eta_v=ETA)
    obs = FreshnessObserver(design, source_estimator=src)
    return plant, design, src, obs, np.random.default_rng(seed)


def test_source_errors_stay_within_bounds_and_match_standalone():
    plant, design, src, obs, rng = setup(0)
    d = src.designs(design)[0]
    T = design.decomposition.T
    adj = np.array([[False, True], [True, False]])
    for run in range(8):
        x = rng.normal(size=2)
        z_hat0 = T.T @ x - d.mu1 * rng.choice([-1.0, 1.0], size=2)
        obs.reset(T @ z_hat0, rng=np.random.default_rng(run))
        # the same arrivals fed to a standalone estimator on (A_bar, C_bar)
        ref = EqualizedRecoveryEstimator(d)
        ref.reset(z_hat0)
        twin = d.problem.language.channel().sampler(np.random.default_rng(run))
        ys = {}
        for k in range(12):
            y = plant.C[0] @ x + ETA * rng.choice([-1.0, 1.0], size=1)
            ys[k] = y
            obs.step([y, np.zeros(0)], adj)
            z_ref = ref.step({i: ys[i] for i in twin.next()})
            x = plant.A @ x
            err = np.abs(obs.z_estimates[0] - T.T @ x).max()
            assert err <= src.bounds[0, 0] + 1e-7
            np.testing.assert_allclose(obs.z_estimates[0], z_ref, atol=1e-9)
    assert np.isnan(src.bounds[0, 1])


def test_source_rejects_bad_configuration():
    lang = DelayLanguage.each_delayed_at_most(1, 3)
    with pytest.raises(ValueError, match="eta_v"):
        EqualizedSource(lang, eta_v=-1.0)
    with pytest.raises(ValueError, match="language"):
        EqualizedSource("0101", eta_v=0.1)
    with pytest.raises(ValueError, match="horizon"):
        EqualizedSource(lang, eta_v=0.1, channel=DelayLanguage.from_words(["00"]).channel())


def test_environment_core_runs_with_delayed_equalized_source():
    import dataclasses
    from functools import partial

    from netsense.engine.core import BatchedCore
    from netsense.env.policies import FreshnessPolicy
    from netsense.env.registry import build_model, load

    lang = DelayLanguage.each_delayed_at_most(1, 3)
    model = dataclasses.replace(build_model(load("fig1_scalar-v0")),
                                source_estimator=partial(EqualizedSource, lang, eta_v=ETA))
    core = BatchedCore(model, batch_size=2)
    obs, mask = core.reset(seed=3)
    policy = FreshnessPolicy(core.layout)
    for _ in range(24):
        out = core.step(policy.act(obs, mask))
        obs, mask = out.obs, out.action_mask
    # the source's error contracts every horizon (|Xi_T| < 1 for the scalar a = 2 plant),
    # so after 8 horizons it is inside the guaranteed level although x0 ~ N(0, 1)
    err = np.abs(core.estimates[:, 0, 0] - core.x[:, 0])
    assert np.all(err <= core.source.bounds[:, 0] + 1e-9)
