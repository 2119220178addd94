"""Per-member draws on threads (netsense.pool): same numbers whatever the thread count."""

from __future__ import annotations

import threading

import numba
import numpy as np
import pytest

from netsense import pool
from netsense.envcore import BatchedCore
from netsense.scenarios import build_model, load, with_overrides


def test_each_part_covers_every_item_once_on_several_threads():
    parts, names = [], set()
    lock = threading.Lock()

    def fn(lo, hi):
        with lock:
            parts.append((lo, hi))
            names.add(threading.current_thread().name)

    pool.each_part(fn, 100, threads=3)
    parts.sort()
    assert len(parts) == 3 and parts[0][0] == 0 and parts[-1][1] == 100
    assert all(a[1] == b[0] for a, b in zip(parts[:-1], parts[1:], strict=True))
    assert threading.current_thread().name in names and len(names) >= 2


def test_each_part_runs_small_counts_inline():
    names = []
    pool.each_part(lambda lo, hi: names.append((lo, hi, threading.current_thread().name)),
                   pool.MIN_PART * 2 - 1, threads=4)
    assert names == [(0, pool.MIN_PART * 2 - 1, threading.current_thread().name)]


def test_each_part_reraises_a_failing_part_after_the_others():
    done = []

    def fn(lo, hi):
        if lo > 0:
            raise RuntimeError(f"part {lo}")
        done.append(lo)

    with pytest.raises(RuntimeError, match="part"):
        pool.each_part(fn, 64, threads=2)
    assert done == [0]
    with pytest.raises(ValueError, match="count"):
        pool.each_part(lambda lo, hi: None, -1)


def _model():
    sc = with_overrides(load("large_n20_N100-v2"), horizon=40,
                        plant={"kind": "random_structured", "n": 6, "num_agents": 8,
                               "seed": 0, "spectral_radius": 1.1},
                        graph={"kind": "markov", "num_nodes": 8, "p_fail": 0.2,
                               "p_recover": 0.5, "draws": "base",
                               "base": {"kind": "circulant", "offsets": [1, 3]}})
    return build_model(sc)


def test_core_draws_do_not_depend_on_the_thread_count():
    model = _model()
    before = numba.get_num_threads()
    out = {}
    try:
        for t in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(t)
            core = BatchedCore(model, 48, chunk=7)  # 48 members: 2 parts of 24 (threaded)
            core.reset(list(range(100, 148)))
            core._refill(np.arange(48))  # a second chunk, continuing every stream
            out[t] = (core.buf_nbr.copy(), core.buf_v.copy(), core.y.copy())
    finally:
        numba.set_num_threads(before)
    one, many = out[1], out[max(out)]
    for a, b in zip(one, many, strict=True):
        np.testing.assert_array_equal(a, b)
    # and a member equals a batch of one with its seed
    single = BatchedCore(model, 1, chunk=7)
    single.reset(117)
    single._refill(np.arange(1))
    np.testing.assert_array_equal(single.buf_nbr[0], one[0][17])
    np.testing.assert_array_equal(single.buf_v[0], one[1][17])
