"""Source estimators from scenario files (issue 5 item 4, issue 7 item 5) and multi-rate
arrivals (issue 6 item 3): the scenario's ``[source_estimator]`` is what the core runs, a
batch member with a stateful source equals a single run (also after partial resets), and
the environment under the freshness policy equals the library observer with the same
source estimator."""

from __future__ import annotations

import numpy as np
import pytest

import netsense as ns
from netsense.engine.core import BatchedCore
from netsense.env.policies import make_policy
from netsense.env.registry import build_model, load, load_file, make, with_overrides
from netsense.observers.source_estimators import KFIOSource, RSEIOSource
from netsense.observers.source_estimators_equalized import EqualizedSource
from netsense.sensing.delays import DelayLanguage
from netsense.sensing.multirate import MultiRateArrivals


def _episode_error(env, seed):
    pol = make_policy("freshness", env)
    obs, infos = env.reset(seed=seed)
    errs = []
    while env.agents:
        obs, _, _, _, infos = env.step(pol.act_dict(env, obs, infos))
        errs.append(np.mean([infos[a]["error"] for a in env.possible_agents]))
    return float(np.mean(errs[len(errs) // 2:]))


def test_scenarios_build_their_source_estimators():
    assert type(make("drops_kfio-v0").core.source) is KFIOSource
    src = make("delayed_equalized-v0").core.source
    assert type(src) is EqualizedSource
    assert src.language == DelayLanguage.each_delayed_at_most(1, 3)
    assert type(make("fig1_scalar-v0").core.source).__name__ == "LuenbergerSource"
    rse = make("drops_kfio-v0", source_estimator={"kind": "rseio", "Q": 1e-4, "R": 1e-2,
                                                  "mu": 0.9, "dA": np.zeros((1, 6, 6))})
    assert type(rse.core.source) is RSEIOSource and rse.core.source.mu == 0.9
    # two cores of one model never share an estimator object
    model = build_model(load("drops_kfio-v0"))
    assert BatchedCore(model).source is not BatchedCore(model).source


def test_kfio_sources_beat_the_fixed_gain_in_drops_kfio():
    """Same seeds (same plant, noise, drops, graphs): KFIO's mean error over the second
    half of the episode is below that of eq. (7)'s fixed gain in each of three episodes."""
    for seed in range(3):
        e_kfio = _episode_error(make("drops_kfio-v0"), seed)
        e_fixed = _episode_error(make("drops_kfio-v0",
                                      source_estimator={"kind": "luenberger"}), seed)
        assert e_kfio < e_fixed, seed


@pytest.mark.parametrize("sid", ["drops_kfio-v0", "delayed_equalized-v0"])
def test_stateful_source_member_equals_single_run_across_partial_reset(sid):
    """Member b of a batch equals a single environment with its seed, also after member 1
    alone is reset mid-episode (its filter / equalized estimator and delay channel restart;
    the others' continue). Kalman-type filters are batched matrix products, equal to
    rounding; the equalized source is per member, equal bit for bit."""
    B = 3
    core = BatchedCore(build_model(load(sid)), B)
    obs, mask = core.reset([10, 20, 30])
    pol = make_policy("freshness", core)
    ref = [make(sid) for _ in range(B)]
    ref_obs = [r.reset(seed=s)[0] for r, s in zip(ref, [10, 20, 30], strict=True)]
    for k in range(25):
        if k == 9:
            obs, mask = core.reset([0, 99, 0], members=np.array([False, True, False]))
            ref_obs[1] = ref[1].reset(seed=99)[0]
        act = pol.act(obs, mask)
        out = core.step(act)
        obs, mask = out.obs, out.action_mask
        for b in range(B):
            ref_obs[b], *_ = ref[b].step({a: act[b, i]
                                          for i, a in enumerate(ref[b].possible_agents)})
            np.testing.assert_allclose(core.Z[b], ref[b].core.Z[0], rtol=0, atol=1e-12,
                                       err_msg=f"k={k} b={b}")
            np.testing.assert_array_equal(core.tau[b], ref[b].core.tau[0])
    assert core.k.tolist() == [25, 16, 25]


def _against_observer(sid, source, seed, steps, **over):
    env = make(sid, **over)
    core = env.core
    observer = ns.FreshnessObserver(core.model.design, source_estimator=source)
    source_rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(7)[6])
    observer.reset(rng=source_rng)  # the member's "source" stream, as the core passes it
    pol = make_policy("freshness", env)
    obs, infos = env.reset(seed=seed)
    env.dropped = 0
    for k in range(steps):
        env.dropped += int((~core.y_arrived[0]).sum())
        observer.step(core.y[0].copy(), core.adjacency[0].copy(),
                      arrived=core.y_arrived[0].copy())
        obs, *_, infos = env.step(pol.act_dict(env, obs, infos))
        np.testing.assert_allclose(core.Z[0], observer.z_estimates, rtol=0, atol=1e-12,
                                   err_msg=f"k={k}")
        np.testing.assert_array_equal(core.tau[0], observer.indices)
    return env, observer


def test_env_with_kfio_source_equals_freshness_observer_with_kfio_source():
    # messages always arrive here (the observer has no per-link drops); measurements
    # still drop in bursts, so the filters really skip updates
    env, _ = _against_observer("drops_kfio-v0", KFIOSource(Q=1e-4, R=1e-2, P0=1.0), 4, 40,
                               arrivals={"message": {"kind": "always"}})
    assert env.dropped > 0


def test_env_with_equalized_source_equals_observer_and_keeps_its_bounds():
    lang = DelayLanguage.each_delayed_at_most(1, 3)
    env, obs = _against_observer("delayed_equalized-v0", EqualizedSource(lang, eta_v=0.05),
                                 2, 30)
    # decoupled unstable modes: each source's guarantee holds once its error is within
    # mu_1 (after the first block), whatever the delays drawn
    core = BatchedCore(env.model, 16)
    o, m = core.reset(0)
    pol = make_policy("freshness", core)
    for k in range(30):
        out = core.step(pol.act(o, m))
        o, m = out.obs, out.action_mask
        err = np.abs(core.Z[:, [0, 1], [0, 1]] - core.x @ core.T)
        if k >= 3:
            assert np.all(err <= core.source.bounds[:, :2] + 1e-9), k


def test_multirate_measurements_follow_each_sensors_period_and_phase():
    env = make("multirate-v0", horizon=24)
    spec = load("multirate-v0").arrivals["measurement"]
    assert isinstance(env.model.measurement_arrivals, MultiRateArrivals)
    P, ph = np.array(spec["periods"]), np.array(spec["phases"])
    pol = make_policy("freshness", env)
    obs, infos = env.reset(seed=0)
    for k in range(24):
        want = (k >= ph) & ((k - ph) % P == 0)  # sensor i reports at ph_i + j P_i
        np.testing.assert_array_equal(env.core.y_arrived[0], want, err_msg=f"k={k}")
        obs, *_, infos = env.step(pol.act_dict(env, obs, infos))


def test_multirate_via_arrival_from_dict_and_message_channels():
    from netsense.sensing.drops import arrival_from_dict

    m = arrival_from_dict({"kind": "multirate", "periods": [1, 2], "jitter": 0})
    assert isinstance(m, MultiRateArrivals) and m.periods == (1, 2)
    # message arrivals: one period per sender (last axis of the (N, N) channel array)
    env = make("fig1_scalar-v0", arrivals={"message": {"kind": "multirate",
                                                        "periods": [1, 2, 3]}})
    env.reset(seed=0)
    got = []
    for _ in range(6):
        got.append(env.core.buf_msg[0, env.core.ptr[0]].copy())
        env.step({a: np.zeros(4, int) for a in env.possible_agents})
    got = np.stack(got)  # (K, i, l)
    for k in range(6):
        np.testing.assert_array_equal(got[k], np.broadcast_to(k % np.array([1, 2, 3]) == 0,
                                                              (3, 3)))


@pytest.mark.parametrize("section, field", [
    ("[source_estimator]\nkind='kalman'\n", "source_estimator.kind"),
    ("[source_estimator]\nkind='kfio'\nR=0.1\n", "source_estimator.Q"),
    ("[source_estimator]\nkind='kfio'\nQ=-1.0\nR=0.1\n", "source_estimator.Q"),
    ("[source_estimator]\nkind='kfio'\nQ=1.0\nR=[1.0]\n", "source_estimator.R"),
    ("[source_estimator]\nkind='kfio'\nQ=1.0\nR=1.0\nmu=0.5\n", "source_estimator.mu"),
    ("[source_estimator]\nkind='rseio'\nQ=1.0\nR=1.0\nmu=1.5\n", "source_estimator.mu"),
    ("[source_estimator]\nkind='equalized'\neta_v=0.1\n", "source_estimator.language"),
    ("[source_estimator]\nkind='equalized'\neta_v=0.1\nlanguage={kind='any'}\n",
     "source_estimator.language.kind"),
    ("[source_estimator]\nkind='equalized'\neta_v=0.1\n"
     "language={kind='each_delayed_at_most', T=3}\n", "source_estimator.language.m"),
    ("[source_estimator]\nkind='equalized'\neta_v=-0.1\n"
     "language={kind='each_delayed_at_most', m=1, T=3}\n", "source_estimator.eta_v"),
    ("[[faults]]\nkind='meteor'\n", "faults[0].kind"),
    ("[[faults]]\nkind='link_drops'\narrivals={kind='bernoulli', p=0.5}\n",
     "faults[0].kind"),
    ("[[faults]]\nkind='crash'\nagents=[1]\n[[faults]]\nkind='crash'\nagents=[7]\n",
     "faults[1].agents"),
    ("[[faults]]\nkind='stuck_sensor'\nagents=[0]\nmode='melted'\n", "faults[0].mode"),
    ("[[faults]]\nkind='liar'\nagents=[0]\n[[faults]]\nkind='liar'\nagents=[1]\n",
     "faults"),
    ("[arrivals]\nmeasurement={kind='multirate', periods=[2, 2]}\n", "arrivals.measurement"),
])
def test_malformed_sections_name_file_and_field(tmp_path, section, field):
    path = tmp_path / "broken_v0.toml"
    path.write_text("horizon = 5\n[plant]\nkind='fig1_scalar'\n[graph]\nkind='fig1'\n"
                    + section)
    with pytest.raises(ValueError) as info:
        build_model(load_file(path))
    msg = str(info.value)
    assert "broken_v0.toml" in msg and f"'{field}" in msg, msg


def test_sections_round_trip_through_to_dict():
    for sid in ("drops_kfio-v0", "delayed_equalized-v0", "fault_liar-v0", "fault_crash-v0"):
        sc = load(sid)
        again = with_overrides(sc, horizon=sc.horizon)
        assert again.to_dict() == sc.to_dict()
        assert type(sc).from_dict(sid, sc.to_dict()).to_dict() == sc.to_dict()


def test_rseio_source_with_mu_one_is_kfio_in_the_environment():
    """Theorem 1 with mu = 1 is KFIO: the same episode with either source; mu < 1 differs."""
    base = {"Q": 1e-4, "R": 1e-2, "dA": np.full((1, 6, 6), 0.1)}
    runs = {}
    for name, spec in (("kfio", {"kind": "kfio", "Q": 1e-4, "R": 1e-2}),
                       ("rseio1", {"kind": "rseio", "mu": 1.0, **base}),
                       ("rseio05", {"kind": "rseio", "mu": 0.5, **base})):
        env = make("drops_kfio-v0", horizon=30, source_estimator=spec)
        _episode_error(env, 1)
        runs[name] = env.core.Z[0].copy()
    np.testing.assert_allclose(runs["rseio1"], runs["kfio"], rtol=0, atol=1e-12)
    assert np.abs(runs["rseio05"] - runs["kfio"]).max() > 1e-4


def test_equalized_designs_are_solved_once_per_model_and_survive_pickling(monkeypatch):
    import pickle

    import netsense.observers.source_estimators_equalized as eqmod

    env = make("delayed_equalized-v0")
    pickled = pickle.dumps(env)

    def no_lp(*args, **kwargs):
        raise AssertionError("an equalized design LP was solved again")

    monkeypatch.setattr(eqmod, "design_equalized", no_lp)
    make("delayed_equalized-v0").reset(seed=0)  # cached model: copies of the prototype
    clone = pickle.loads(pickled)  # new design object, same content: no new LP either
    clone.reset(seed=1)
    assert clone.core.source._design_key == env.core.source._design_key
