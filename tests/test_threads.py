"""Threads of the compiled drivers (docs/threads.md): who runs threaded, the thread-count
knob, fork-based workers and a package that cannot write numba's cache."""

from __future__ import annotations

import gc
import warnings

import numpy as np
import pytest

import netsense.drivers  # noqa: F401  (every module that builds drivers, imported
import netsense.graphs  # noqa: F401  before the drivers are collected)
import netsense.observation  # noqa: F401
import netsense.rewards  # noqa: F401
import netsense.sensing.noise  # noqa: F401
from netsense import compiled
from netsense.policies import make_policy
from netsense.scenarios import list_scenarios, make


def _count_threaded_builds(monkeypatch) -> dict[str, int]:
    """Replace the threaded build of every driver of the package by a counting wrapper;
    returns the counts (by driver name), filled as drivers run threaded."""
    counts: dict[str, int] = {}
    drivers = [o for o in gc.get_objects() if isinstance(o, compiled.Driver)]
    assert len(drivers) > 10  # the package's drivers were found

    for d in drivers:
        def counted(*args, _build=d.parallel, _name=d.parallel.py_func.__name__):
            counts[_name] = counts.get(_name, 0) + 1
            return _build(*args)
        monkeypatch.setattr(d, "parallel", counted)
    return counts


def _episode(sid: str) -> None:
    env = make(sid, horizon=4 if sid.startswith("large") else 12)
    pol = make_policy("freshness", env)
    obs, infos = env.reset(seed=3)
    while env.agents:
        obs, _, _, _, infos = env.step(pol.act_dict(env, obs, infos))


@pytest.mark.parametrize("sid", list_scenarios())
def test_the_single_env_never_runs_a_threaded_driver(sid, monkeypatch):
    # every work threshold at zero: only the member count may keep B = 1 serial
    monkeypatch.setattr(compiled, "PARALLEL_WORK", 0)
    counts = _count_threaded_builds(monkeypatch)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _episode(sid)
    assert counts == {}


@pytest.mark.parametrize("sid", ["large_n20_N100-v0", "large_n20_N100-v2"])
def test_the_single_large_env_stays_serial_at_the_default_thresholds(sid, monkeypatch):
    # N = 100: the observation pass and the policy touch more than PARALLEL_WORK elements
    counts = _count_threaded_builds(monkeypatch)
    _episode(sid)
    assert counts == {}


def test_a_threaded_build_is_counted(monkeypatch):
    # the counter itself sees a threaded call (a batch of many members)
    from netsense import kernels

    monkeypatch.setattr(compiled, "PARALLEL_WORK", 0)
    counts = _count_threaded_builds(monkeypatch)
    tau = np.zeros((64, 4, 4), dtype=np.int64)
    kernels.advance_indices(tau, np.zeros_like(tau))
    assert counts == {f"advance_all_parallel_{compiled.inlined_digest()}": 1}
