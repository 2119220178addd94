"""The compiled kernels (numba): the fused step, the drivers, and their reference forms.

What must hold: ``apply_actions`` (the environment's one-pass step) gives bit for bit what
the public kernels give one after the other; the serial and the threaded variant of every
driver agree bit for bit; every batch member equals a ``B = 1`` call; validation reports
the first bad entry in C order; the Markov slot tables equal the two-state recursion
written out in numpy; observations equal the layout written out in numpy.
"""

from __future__ import annotations

import numpy as np
import pytest

from netsense.engine import observation
from netsense.engine.core import BatchedCore
from netsense.env.registry import build_model, load
from netsense.graphs.processes import MarkovLinkFailures
from netsense.kernels import jit as compiled
from netsense.kernels import update as kernels

OMEGA = kernels.OMEGA


def _random_step(seed: int, B: int = 3, N: int = 6, D: int = 3, avg_p: float = 0.2):
    """Inputs of one step with empty slots, omega indices, averages and own blocks."""
    rng = np.random.default_rng(seed)
    model = build_model(load("random_structured_n20_N10-v0"))
    dec = model.design.decomposition
    N, n = dec.num_agents, dec.n
    Z = rng.standard_normal((B, N, n))
    tau = rng.integers(-1, 6, size=(B, N, N))
    tau[:, np.arange(N), np.arange(N)] = 0
    nbr = np.full((B, N, D), -1, dtype=np.int64)
    for b in range(B):
        for i in range(N):
            k = rng.integers(0, D + 1)
            nbr[b, i, :k] = np.sort(rng.choice([x for x in range(N) if x != i], k, False))
    msg = (nbr >= 0) & (rng.random((B, N, D)) < 0.8)
    ok = np.concatenate([np.ones((B, N, 1), bool), msg, np.ones((B, N, 1), bool)], 2)
    choice = np.zeros((B, N, N), dtype=np.int64)
    for b in range(B):
        for i in range(N):
            allowed = np.flatnonzero(ok[b, i])
            for j in range(N):
                if j == i:
                    continue
                c = rng.choice(allowed)
                choice[b, i, j] = c if c != D + 1 or rng.random() < avg_p else 0
    y = rng.standard_normal((B, N, 2))
    arrived = rng.random((B, N)) < 0.7
    C = rng.standard_normal((N, 2, n))
    L = np.zeros((N, n, 2))
    for i in range(N):
        rows = np.flatnonzero(dec.block_of == i)
        L[i, rows] = rng.standard_normal((rows.size, 2))
    return dict(Z=Z, tau=tau, choice=choice, nbr=nbr, msg=msg, dec=dec, y=y,
                arrived=arrived, C=C, L=L, z_true=rng.standard_normal((B, n)))


def _composed(s):
    """The step from the public kernels, one after the other (the observers' path)."""
    dec, Z, tau, choice, nbr, msg = s["dec"], s["Z"], s["tau"], s["choice"], s["nbr"], \
        s["msg"]
    B, N, _ = tau.shape
    D = nbr.shape[2]
    own = np.broadcast_to(np.arange(N)[None, :, None], choice.shape)
    safe = np.where(nbr >= 0, nbr, np.arange(N)[None, :, None])
    adopted = np.take_along_axis(safe, np.clip(choice - 1, 0, D - 1), axis=2)
    src = np.where((choice >= 1) & (choice <= D), adopted, own)
    avg = choice == D + 1
    tau_next = np.where(avg, kernels.average_indices(tau, nbr, msg),
                        kernels.advance_indices(tau, src))
    Z_sel = kernels.gather_substates(Z, src, dec.block_of)
    Z_sel = np.where(avg[:, :, dec.block_of], kernels.uniform_mix(Z, nbr, msg), Z_sel)
    corr = kernels.innovation_correction(Z, s["y"], s["arrived"], s["C"], s["L"])
    Z_next = kernels.propagate(Z_sel, Z, dec.A_diag, dec.A_lower) + corr
    err = np.sqrt(((Z_next - s["z_true"][:, None, :]) ** 2).sum(-1))
    return Z_next, tau_next, err, corr


def _fused(s, **kw):
    """The fused step on valid actions; the plant is the identity (x_next = x = z_true)."""
    dec = s["dec"]
    B, N, _ = s["choice"].shape
    act = np.concatenate([s["choice"], np.ones((B, N, 1), np.int64)], axis=2)
    n = s["Z"].shape[2]
    out = kernels.apply_actions(
        s["Z"], s["tau"], act, s["nbr"], s["msg"], dec.block_of.astype(np.int64),
        np.ascontiguousarray(dec.A_lower.T), np.ascontiguousarray(dec.A_diag.T), x=s["z_true"],
        A_T=np.eye(n), T=np.eye(n), **kw)
    assert list(out.status) == [-1] * 6 and not out.masked.any()
    np.testing.assert_array_equal(out.x_next, s["z_true"])
    return out.Z_next, out.tau_next, out.err


@pytest.mark.parametrize("seed", range(4))
def test_fused_step_equals_public_kernels_bit_for_bit(seed):
    s = _random_step(seed)
    Z_ref, tau_ref, err_ref, corr = _composed(s)
    assert (s["choice"] == len(s["nbr"][0, 0]) + 1).any()  # averages are exercised
    for kw in ({"luenberger": (s["y"], s["arrived"], s["C"], s["L"])}, {"corr": corr}):
        Z_next, tau_next, err = _fused(s, **kw)
        np.testing.assert_array_equal(tau_next, tau_ref)
        np.testing.assert_array_equal(Z_next, Z_ref)
        np.testing.assert_allclose(err, err_ref, rtol=1e-12)


def test_propagate_is_the_block_triangular_product():
    s = _random_step(7)
    dec, Z = s["dec"], s["Z"]
    Z_sel = Z[:, ::-1]  # any other estimates
    ref = Z_sel @ dec.A_diag.T + Z @ dec.A_lower.T
    np.testing.assert_allclose(kernels.propagate(Z_sel, Z, dec.A_diag, dec.A_lower), ref,
                               rtol=1e-12, atol=1e-12)


def test_serial_and_threaded_drivers_agree(monkeypatch):
    s = _random_step(3, B=9)
    kw = {"luenberger": (s["y"], s["arrived"], s["C"], s["L"])}
    monkeypatch.setattr(compiled, "PARALLEL_WORK", 1 << 62)
    serial = _fused(s, **kw) + _composed(s)
    monkeypatch.setattr(compiled, "PARALLEL_WORK", 0)
    threaded = _fused(s, **kw) + _composed(s)
    for a, b in zip(serial, threaded, strict=True):
        np.testing.assert_array_equal(a, b)


def test_driver_threads_only_from_its_work_and_member_thresholds():
    from netsense.graphs.processes import MARKOV_THREADED_RUNS, _markov_slots

    d = compiled.Driver(lambda x: None, min_runs=4)
    big = compiled.PARALLEL_WORK
    assert d.at(big - 1, runs=4) is d.serial
    assert d.at(big, runs=3) is d.serial  # enough work, too few members
    assert d.at(big, runs=4) == d._threaded
    e = compiled.Driver(lambda x: None)  # default: two members, never one
    assert e.at(1 << 40, runs=1) is e.serial
    assert e.at(big, runs=2) == e._threaded
    with pytest.raises(TypeError):
        e.at(big)  # every call site says how many members it runs
    # the Markov slot pass: serial below its member threshold at any work
    assert _markov_slots.at(1 << 40, runs=MARKOV_THREADED_RUNS - 1) is _markov_slots.serial
    assert _markov_slots.at(1 << 40, runs=MARKOV_THREADED_RUNS) == _markov_slots._threaded


def test_every_member_equals_a_single_member_call():
    s = _random_step(5, B=5)
    kw = {"luenberger": (s["y"], s["arrived"], s["C"], s["L"])}
    full = _fused(s, **kw)
    for b in range(5):
        one = {k: (v[b:b + 1] if isinstance(v, np.ndarray) and v.shape[:1] == (5,) else v)
               for k, v in s.items()}
        part = _fused(one, luenberger=(one["y"], one["arrived"], one["C"], one["L"]))
        for a, p in zip(full, part, strict=True):
            np.testing.assert_array_equal(a[b], p[0])
    x = np.random.default_rng(0).standard_normal((7, 9))
    M = np.random.default_rng(1).standard_normal((9, 4))
    out = kernels.vecmat(x, M)
    np.testing.assert_allclose(out, x @ M, rtol=1e-12, atol=1e-12)
    for b in range(7):
        np.testing.assert_array_equal(kernels.vecmat(x[b:b + 1], M)[0], out[b])


def test_check_actions_reports_the_first_bad_entry_in_c_order():
    B, N, D = 2, 4, 2
    msg = np.ones((B, N, D), bool)
    msg[1, 2, 1] = False
    act = np.zeros((B, N, N + 1), dtype=np.int64)
    act[1, 2, 0] = 2  # slot 1 of agent 2 in member 1: no message -> masked
    act[1, 3, 3] = 1  # own substate, not keep -> masked (later in C order)
    choice = np.empty((B, N, N), np.int64)
    masked = np.empty((B, N, N), bool)
    st = kernels.check_actions(act, msg, choice, masked)
    assert list(st) == [-1, -1, -1, 1, 2, 0]
    assert masked.sum() == 2 and masked[1, 3, 3] and choice[1, 2, 0] == 0
    act[1, 0, N] = 2  # transmit bit out of range
    act[0, 3, 1] = D + 2  # choice out of range, earlier in C order
    st = kernels.check_actions(act, msg, choice, masked)
    assert list(st[:3]) == [0, 3, 1]
    assert kernels.gain_rows(np.array([[[0.0], [1.0], [0.0]], [[0.0], [0.0], [0.0]]])
                             ).tolist() == [[1, 2], [0, 0]]


def _markov_reference(proc, rngs, K, states, D):
    """The two-state recursion and slot compaction in plain numpy (per run, per step)."""
    ei, el = np.nonzero(proc.base)
    out = np.full((len(rngs), K, proc.num_nodes, D), -1, dtype=np.int64)
    final = []
    for m, (rng, st) in enumerate(zip(rngs, states, strict=True)):
        up = np.asarray(st, bool)[ei, el]
        u = proc._edge_uniforms(rng, (K,))
        for k in range(K):
            for i in range(proc.num_nodes):
                ls = el[(ei == i) & up]
                out[m, k, i, :ls.size] = ls
            up = np.where(up, u[k] >= proc.p_fail, u[k] < proc.p_recover)
        end = np.zeros(proc.base.shape, bool)
        end[ei, el] = up
        final.append(end)
    return out, final


@pytest.mark.parametrize("draws", ["all", "base"])
def test_markov_slot_tables_equal_the_recursion(draws):
    base = np.zeros((9, 9), bool)
    for off in (1, 2, 5):
        base[np.arange(9), (np.arange(9) + off) % 9] = True
    proc = MarkovLinkFailures(base, 0.3, 0.4, draws=draws)
    seeds = [11, 12, 13]
    st = [proc.initial_state(np.random.default_rng(s)) for s in seeds]
    nbr, new = proc.sample_slots_many([np.random.default_rng(s) for s in seeds], 20, st, 3)
    st2 = [proc.initial_state(np.random.default_rng(s)) for s in seeds]
    ref, final = _markov_reference(proc, [np.random.default_rng(s) for s in seeds], 20, st2,
                                   3)
    assert (nbr >= 0).any() and (nbr < 0).any()
    np.testing.assert_array_equal(nbr, ref)
    for a, b in zip(new, final, strict=True):
        np.testing.assert_array_equal(a, b)


def test_fill_refuses_outputs_it_cannot_write_in_place():
    core = BatchedCore(build_model(load("link_failures-v0")), 2)
    obs, mask = core.reset(0)
    good_o, good_m = np.empty_like(obs), np.empty_like(mask)
    for o, m, what in ((obs.astype(np.float64), good_m, "obs must be"),
                       (np.empty_like(obs)[:, ::-1], good_m, "obs must be"),
                       (good_o, np.empty(mask.shape, bool), "mask must be"),
                       (good_o, np.empty(mask.shape[::-1], np.int8).T, "mask must be"),
                       (good_o[:, :, :-1].copy(), good_m, "obs must have shape"),
                       (np.empty((3, *obs.shape[1:]), np.float32), good_m, "obs must have"),
                       (good_o, good_m[:, :-1].copy(), "mask must have shape"),
                       (good_o, np.empty((*mask.shape[:2], mask.shape[2] + 1), np.int8),
                        "mask must have shape")):
        with pytest.raises(ValueError, match=what):
            core._fill(o, m)
    core._fill(good_o, good_m)  # the same state observed again: the same arrays
    np.testing.assert_array_equal(good_o, obs)
    np.testing.assert_array_equal(good_m, mask)


def test_mask_table_rows_equal_the_slot_by_slot_rule(monkeypatch):
    """The masks copied from the per-pattern table equal the masks written slot by slot
    (the path taken when the table would be too large), member by member, under link
    drops; a buffer reused with other own columns rebuilds its table."""
    core = BatchedCore(build_model(load("link_failures-v0")), 6)
    core.reset(2)
    act = np.zeros((core.B, core.N, core.M + 1), np.int64)
    act[:, ::2, core.M] = 1  # half the agents transmit; links drop some of their messages
    for _ in range(5):
        core.step(act)
    assert core.msg.any() and not core.msg.all()

    def masks(work, own):
        m = np.full((core.B, core.N, core.mask_size), 9, np.int8)
        observation.fill(np.empty((1, 1, 1), np.float32), m, core._obs_starts, core.k, 50.0,
                         core.y, core.y_arrived, core.tau, core.Z, core.nbr, core.msg, True,
                         observations=False, own=own, work=work)
        return m

    key = (core.B, core.N, core.M, core.mask_size)
    with_table = observation.FillBuffers(*key)
    assert with_table.mask_table.shape == (core.N, 2 ** core.D, core.mask_size)
    monkeypatch.setattr(observation, "MASK_TABLE_BYTES", 0)
    without = observation.FillBuffers(*key)
    assert without.mask_table.shape[0] == 0
    own = np.arange(core.N)
    other = np.roll(own, 1)
    other[0] = -1  # agent 0 owns no substate: all its choices open
    for o in (own, other, own):  # the table follows the own columns it is given
        a, b = masks(with_table, o), masks(without, o)
        np.testing.assert_array_equal(a, b)
        assert (a != 9).all()
    assert not np.array_equal(masks(with_table, own), masks(with_table, other))


def test_observations_equal_the_layout_written_out():
    model = build_model(load("link_failures-v0"))
    core = BatchedCore(model, 3)
    core.reset(4)
    rng = np.random.default_rng(0)
    for _ in range(5):  # a few steps so indices, slots and messages vary
        core.step(np.zeros((3, core.N, core.N + 1), dtype=np.int64)
                  + np.array([0] * core.N + [1]))
    core.Z[0, 1] = [np.inf] + [0.0] * (core.n - 1)  # a blown-up estimate gets repaired
    core.Z[1] = rng.standard_normal(core.Z[1].shape) * 1e3
    core._obs = None
    obs, mask = core.observe()
    L, H, N, D = core.layout, float(core.horizon), core.N, core.D
    tau = core.tau
    for b in range(3):
        for i in range(N):
            o = obs[b, i]
            assert o[L.time][0] == np.float32(core.k[b] / H)
            yv = core.y[b, i] * core.y_arrived[b, i]
            np.testing.assert_allclose(o[L.y], np.sign(yv) * np.log1p(np.abs(yv)), rtol=1e-6)
            np.testing.assert_array_equal(o[L.own_omega], tau[b, i] < 0)
            np.testing.assert_array_equal(
                o[L.own_age], (np.maximum(tau[b, i], 0) / H).astype(np.float32))
            z = core.Z[b, i]
            nz = np.linalg.norm(z)
            if np.isfinite(nz):
                np.testing.assert_allclose(o[L.z_dir], z / (nz or 1.0), rtol=1e-6, atol=1e-7)
            else:
                assert o[L.z_lognorm][0] == 1e3 and np.isfinite(o).all()
            for d in range(D):
                l, got = core.nbr[b, i, d], core.msg[b, i, d]
                assert o[L.slot_arrived][d] == got
                assert o[L.slot_id][d] == np.float32((l + 1) / N if l >= 0 else 0.0)
                om = o[L.slot_omega].reshape(D, N)[d]
                age = o[L.slot_age].reshape(D, N)[d]
                if got:
                    np.testing.assert_array_equal(om, tau[b, l] < 0)
                    np.testing.assert_array_equal(
                        age, (np.maximum(tau[b, l], 0) / H).astype(np.float32))
                else:
                    assert (om == 1).all() and (age == 0).all()
            W = D + 2
            m = mask[b, i, :N * W].reshape(N, W)
            for j in range(N):
                want = [1] + [0 if j == i else int(g) for g in core.msg[b, i]] + [int(j != i)]
                assert m[j].tolist() == want
            assert mask[b, i, N * W:].tolist() == [1, 1]
    assert kernels.slot_messages(core.nbr, core.transmit).shape == core.nbr.shape


def test_fused_validation_agrees_with_check_actions():
    s = _random_step(9, B=4)
    dec, choice = s["dec"], s["choice"]
    B, N, M = choice.shape
    D = s["nbr"].shape[2]
    rng = np.random.default_rng(2)
    act = np.concatenate([choice, np.ones((B, N, 1), np.int64)], axis=2)
    act[..., :M] = np.where(rng.random((B, N, M)) < 0.3, rng.integers(0, D + 2, (B, N, M)),
                            act[..., :M])  # some of these are masked
    n = s["Z"].shape[2]
    for bad in (None, (2, 3, M)):
        if bad is not None:
            act[bad] = 5  # an out-of-range transmit bit, later in C order
        ref_choice = np.empty((B, N, M), np.int64)
        ref_masked = np.empty((B, N, M), bool)
        st = kernels.check_actions(act, s["msg"], ref_choice, ref_masked)
        out = kernels.apply_actions(
            s["Z"], s["tau"], act, s["nbr"], s["msg"], dec.block_of.astype(np.int64),
            np.ascontiguousarray(dec.A_lower.T), np.ascontiguousarray(dec.A_diag.T),
            x=s["z_true"], A_T=np.eye(n), T=np.eye(n), corr=np.zeros(s["Z"].shape))
        assert ref_masked.any() and (st[3:] >= 0).all()
        np.testing.assert_array_equal(out.masked, ref_masked)
        np.testing.assert_array_equal(out.status, st)
        assert (st[0] >= 0) == (bad is not None)


def test_reused_step_buffers_give_fresh_results_and_clear_their_records():
    """apply_actions(work=...) writes its outputs into the buffers and sets its own
    records per member: garbage left in them, or a refused step before, changes nothing."""
    s = _random_step(5, B=4)
    dec, choice = s["dec"], s["choice"]
    B, N, M = choice.shape
    n = s["Z"].shape[2]
    act = np.concatenate([choice, np.ones((B, N, 1), np.int64)], axis=2)
    args = (s["Z"], s["tau"], act, s["nbr"], s["msg"], dec.block_of.astype(np.int64),
            np.ascontiguousarray(dec.A_lower.T), np.ascontiguousarray(dec.A_diag.T))
    kw = dict(x=s["z_true"], A_T=np.eye(n), T=np.eye(n),
              luenberger=(s["y"], s["arrived"], s["C"], s["L"]))
    ref = kernels.apply_actions(*args, **kw)
    work = kernels.StepBuffers(B, N, n, M, s["nbr"].shape[2], n, 2, s["tau"].dtype)
    for a in (work.Z_next, work.err, work.x_next, *work.scratch):
        a.fill(np.nan) if a.dtype.kind == "f" else a.fill(1)
    work.first.fill(7)  # a stale record must not be reported
    bad = act.copy()
    bad[1, 2, M] = 5  # refused: out of range
    assert kernels.apply_actions(*args[:2], bad, *args[3:], work=work, **kw).status[0] == 1
    out = kernels.apply_actions(*args, work=work, **kw)
    assert out.Z_next is work.Z_next and list(out.status) == [-1] * 6
    for got, want in zip(out, ref, strict=True):
        np.testing.assert_array_equal(got, want)
    with pytest.raises(ValueError, match="this call needs"):
        kernels.apply_actions(*args, work=kernels.StepBuffers(B, N, n, M, 4, n, 2), **kw)
    with pytest.raises(ValueError, match="overlap the inputs"):
        kernels.apply_actions(work.Z_next, *args[1:], work=work, **kw)


def test_core_state_lives_in_two_alternating_buffer_sets():
    """The core's state arrays are its working buffers: a step writes the set the state
    is not in, so the state of step k is intact until step k + 2 (documented)."""
    core = BatchedCore(build_model(load("random_structured_n20_N10-v0")), 3)
    core.reset(0)
    act = np.zeros((3, core.N, core.M + 1), np.int64)
    core.step(act)
    Z1, Z1_copy = core.Z, core.Z.copy()
    core.step(act)
    assert core.Z is not Z1 and not np.shares_memory(core.Z, Z1)
    np.testing.assert_array_equal(Z1, Z1_copy)  # one step later: still step 1's state
    core.step(act)
    assert core.Z is Z1  # two steps later: the same buffer, rewritten


def test_markov_slots_write_into_a_given_int16_buffer():
    base = np.zeros((9, 9), bool)
    for off in (1, 2, 5):
        base[np.arange(9), (np.arange(9) + off) % 9] = True
    proc = MarkovLinkFailures(base, 0.3, 0.4, draws="base")
    seeds = [3, 4]
    st = [proc.initial_state(np.random.default_rng(s)) for s in seeds]
    ref, _ = proc.sample_slots_many([np.random.default_rng(s) for s in seeds], 12, st, 3)
    st = [proc.initial_state(np.random.default_rng(s)) for s in seeds]
    buf = np.full((2, 12, 9, 3), 99, np.int16)
    got, _ = proc.sample_slots_many([np.random.default_rng(s) for s in seeds], 12, st, 3,
                                    out=buf)
    assert got is buf
    np.testing.assert_array_equal(buf, ref)
    with pytest.raises(ValueError, match="out must be"):
        proc.sample_slots_many([np.random.default_rng(0)], 12, st[:1], 3,
                               out=np.zeros((1, 12, 9, 3)))



@pytest.mark.parametrize("bad", ["fewer_states", "more_states", "degree", "state_shape",
                                 "out_shape", "out_narrow"])
@pytest.mark.parametrize("draws", ["base", "all"])
def test_markov_slot_sampling_rejects_bad_arguments_before_drawing(bad, draws):
    """The compiled pass has no bounds checks: mismatched inputs must raise first, with
    every generator untouched."""
    proc = MarkovLinkFailures(_ring(9), 0.3, 0.4, draws=draws)
    rngs = [np.random.default_rng(s) for s in (3, 4)]
    st = [proc.initial_state(np.random.default_rng(s)) for s in (3, 4)]
    before = [r.bit_generator.state for r in rngs]
    kw, D = {}, 3
    if bad == "fewer_states":
        st = st[:1]
    elif bad == "more_states":
        st = st + st[:1]
    elif bad == "degree":
        D = 2
    elif bad == "state_shape":
        st = [s_[:-1] for s_ in st]
    elif bad == "out_shape":
        kw["out"] = np.zeros((2, 12, 9, 2), np.int64)
    else:
        kw["out"] = np.zeros((2, 12, 300, 3), np.int8)  # int8 cannot hold ids up to 299
        proc = MarkovLinkFailures(_ring(300), 0.3, 0.4, draws=draws)
        st = [proc.initial_state(np.random.default_rng(s)) for s in (3, 4)]
        before = [r.bit_generator.state for r in rngs]
    with pytest.raises(ValueError, match="states must|max_degree|link state|out must"):
        proc.sample_slots_many(rngs, 12, st, D, **kw)
    assert [r.bit_generator.state for r in rngs] == before

def _ring(N, offsets=(1, 2, 5)):
    base = np.zeros((N, N), bool)
    for off in offsets:
        base[np.arange(N), (np.arange(N) + off) % N] = True
    return base


def test_compiled_uniform_draws_continue_each_generators_stream():
    # 256 runs x 40 steps x 27 edges: the threaded build draws
    from netsense.graphs.processes import MARKOV_THREADED_RUNS
    from netsense.kernels.jit import PARALLEL_WORK, bit_streams

    proc = MarkovLinkFailures(_ring(9), 0.3, 0.4, draws="base")
    seeds = list(range(100, 100 + MARKOV_THREADED_RUNS))
    K, E = 40, int(proc.base.sum())
    assert len(seeds) * K * E >= PARALLEL_WORK
    rngs = [np.random.default_rng(s) for s in seeds]
    assert bit_streams(rngs) is not None
    st = [proc.initial_state(np.random.default_rng(s)) for s in seeds]
    nbr, new = proc.sample_slots_many(rngs, K, st, 3)
    ref_rngs = [np.random.default_rng(s) for s in seeds]
    ref, final = _markov_reference(proc, ref_rngs, K, st, 3)  # numpy's own draws
    np.testing.assert_array_equal(nbr, ref)
    for m in range(len(seeds)):
        np.testing.assert_array_equal(new[m], final[m])
        assert rngs[m].random() == ref_rngs[m].random()  # left where rng.random left it


def test_mixed_or_repeated_generators_are_drawn_through_numpy():
    from netsense.kernels.jit import bit_streams

    proc = MarkovLinkFailures(_ring(9), 0.3, 0.4, draws="base")

    def mixed():
        return [np.random.default_rng(1), np.random.Generator(np.random.MT19937(2))]

    one = np.random.default_rng(3)
    assert bit_streams(mixed()) is None and bit_streams([one, one]) is None
    assert bit_streams([]) is None
    st = [proc.initial_state(np.random.default_rng(s)) for s in (7, 8)]
    nbr, _ = proc.sample_slots_many(mixed(), 10, st, 3)
    np.testing.assert_array_equal(nbr, _markov_reference(proc, mixed(), 10, st, 3)[0])
    # one generator for both runs: run 0 takes its first 10 steps, run 1 the next 10
    nbr, _ = proc.sample_slots_many([one, one], 10, st, 3)
    ref = np.random.default_rng(3)
    np.testing.assert_array_equal(nbr, _markov_reference(proc, [ref, ref], 10, st, 3)[0])


def test_threaded_drivers_called_from_several_python_threads_under_workqueue():
    # numba's workqueue layer (the README's choice for busy machines) aborts the process
    # on concurrent parallel calls; the drivers' lock must serialise them, and every
    # thread must get its own, correct result
    import os
    import subprocess
    import sys

    code = """
import numpy as np, numba
from concurrent.futures import ThreadPoolExecutor
from netsense.kernels import jit as compiled
import tests.test_kernels_compiled as t
steps = [t._random_step(40 + k, B=6) for k in range(4)]
kws = [{"luenberger": (s["y"], s["arrived"], s["C"], s["L"])} for s in steps]
compiled.PARALLEL_WORK = 1 << 62
expect = [t._fused(s, **kw) for s, kw in zip(steps, kws)]
compiled.PARALLEL_WORK = 0
def run(k):
    return [t._fused(steps[k], **kws[k]) for _ in range(20)]
with ThreadPoolExecutor(4) as ex:
    got = list(ex.map(run, range(4)))
for k in range(4):
    for rep in got[k]:
        for a, b in zip(rep, expect[k]):
            np.testing.assert_array_equal(a, b)
print(numba.threading_layer())
"""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = {**os.environ, "NUMBA_THREADING_LAYER": "workqueue",
           "PYTHONPATH": os.pathsep.join([root, os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=root,
                         capture_output=True, text=True, timeout=600, check=False)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.split()[-1] == "workqueue"


def test_slot_messages_follow_neighbour_transmit_and_link():
    rng = np.random.default_rng(4)
    B, N, D = 5, 7, 3
    nbr = rng.integers(-1, N, size=(B, N, D))
    transmit = rng.random((B, N)) < 0.6
    link = rng.random((B, N, N)) < 0.7
    b, i, d = np.nonzero(nbr >= 0)
    expect = np.zeros((B, N, D), bool)
    expect[b, i, d] = transmit[b, nbr[b, i, d]]
    np.testing.assert_array_equal(kernels.slot_messages(nbr, transmit), expect)
    expect[b, i, d] &= link[b, i, nbr[b, i, d]]
    np.testing.assert_array_equal(kernels.slot_messages(nbr, transmit, link), expect)


def test_gaussian_sample_many_continues_each_generators_stream():
    # 300 runs x (48, 7, 3): the threaded build draws; every value and every generator's
    # final position must be what numpy's own standard_normal gives run by run
    from netsense.kernels.jit import PARALLEL_WORK
    from netsense.sensing.noise import GaussianNoise

    noise, shape, seeds = GaussianNoise(0.37), (48, 7, 3), range(500, 800)
    assert len(seeds) * int(np.prod(shape)) >= PARALLEL_WORK
    rngs = [np.random.default_rng(s) for s in seeds]
    out = np.full((len(seeds), *shape), np.nan)
    assert noise.sample_many(rngs, shape, out) is out
    for m, s in enumerate(seeds):
        ref = np.random.default_rng(s)
        np.testing.assert_array_equal(out[m], 0.37 * ref.standard_normal(shape))
        assert rngs[m].random() == ref.random()  # left where numpy would leave it
    # the ziggurat's rare branches (the tail, idx 0, and the wedges) are in the stream:
    # ~0.7 % of draws take them, so a stream of 2e5 exercises both many times
    many = np.empty((2, 100_000))
    GaussianNoise(1.0).sample_many([np.random.default_rng(1), np.random.default_rng(2)],
                                   (100_000,), many)
    np.testing.assert_array_equal(many[1], np.random.default_rng(2).standard_normal(100_000))
    assert np.abs(many).max() > 3.6541528853610088  # beyond the ziggurat's base: the tail


def test_gaussian_sample_many_falls_back_and_checks_out():
    from netsense.sensing.noise import GaussianNoise, UniformNoise

    noise = GaussianNoise(2.0)
    mixed = [np.random.default_rng(1), np.random.Generator(np.random.MT19937(2))]
    out = np.empty((2, 5))
    noise.sample_many(mixed, (5,), out)
    ref = [np.random.default_rng(1), np.random.Generator(np.random.MT19937(2))]
    np.testing.assert_array_equal(out, [noise.sample(r, (5,)) for r in ref])
    one, ref = np.random.default_rng(3), np.random.default_rng(3)  # one generator twice
    noise.sample_many([one, one], (5,), out)
    np.testing.assert_array_equal(out, [noise.sample(ref, (5,)), noise.sample(ref, (5,))])
    u = UniformNoise(0.5)  # the generic path: member by member through sample()
    u.sample_many([np.random.default_rng(4)], (5,), out[:1])
    np.testing.assert_array_equal(out[0], u.sample(np.random.default_rng(4), (5,)))
    for bad in (np.empty((2, 4)), np.empty((2, 5), np.float32), np.empty((5, 2)).T):
        with pytest.raises(ValueError, match="C-contiguous float64 array of shape"):
            noise.sample_many([np.random.default_rng(5), np.random.default_rng(6)], (5,), bad)


def test_observation_log1p_is_log1p_to_a_few_ulps():
    # the observation's log1p (Goldberg's formula) against libm's over 600 decades, the
    # subnormals and the special values; float32 roundings agree except at boundaries
    from netsense.engine.observation import _log1p

    rng = np.random.default_rng(0)
    x = np.concatenate([10.0 ** rng.uniform(-320, 308, 200_000), rng.uniform(0, 4, 200_000),
                        [0.0, 5e-324, 2.0**-53, 2.0**-52, 1e-8, 0.75, 1.0, 1.7e308]])
    got = np.array([_log1p(v) for v in x])
    ref = np.log1p(x)
    np.testing.assert_allclose(got, ref, rtol=6 * np.finfo(float).eps, atol=0)
    assert np.mean(got.astype(np.float32) != ref.astype(np.float32)) < 1e-5
    assert _log1p(np.inf) == np.inf and np.isnan(_log1p(np.nan))


def test_usable_slots_are_present_neighbours_that_transmitted():
    rng = np.random.default_rng(5)
    B, N, D = 6, 7, 3
    nbr = rng.integers(0, N, size=(B, N, D))
    valid = rng.random((B, N, D)) < 0.7
    transmit = rng.random((B, N)) < 0.5
    got = kernels.usable_slots(np.where(valid, nbr, 99), valid, transmit)  # junk in holes
    want = np.array([[[valid[b, i, d] and transmit[b, nbr[b, i, d]] for d in range(D)]
                      for i in range(N)] for b in range(B)])
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(kernels.usable_slots(nbr, valid), valid)


def _freshness_oracle(tau, nbr, use):
    """Eqs. (8)-(13) written out per agent and substate: among the usable slots whose
    neighbour's index is not omega, the freshest (first slot on ties); adopted iff the
    own index is omega or strictly staler."""
    B, N, M = tau.shape
    slot = np.full((B, N, M), -1)
    src = np.broadcast_to(np.arange(N)[None, :, None], (B, N, M)).copy()
    for b in range(B):
        for i in range(N):
            for j in range(M):
                cand = [(tau[b, nbr[b, i, d], j], d) for d in range(nbr.shape[2])
                        if use[b, i, d] and tau[b, nbr[b, i, d], j] != OMEGA]
                if not cand:
                    continue
                t, d = min(cand)  # smallest index, then smallest slot
                if tau[b, i, j] == OMEGA or t < tau[b, i, j]:
                    slot[b, i, j], src[b, i, j] = d, nbr[b, i, d]
    return src, slot


@pytest.mark.parametrize("seed", range(4))
def test_freshness_choice_equals_the_rule_written_out(seed, monkeypatch):
    s = _random_step(seed, B=6)
    rng = np.random.default_rng(seed)
    tau = rng.integers(-1, 3, size=s["tau"].shape)  # few values: many ties and omegas
    nbr = s["nbr"]
    transmit = rng.random(tau.shape[:2]) < 0.7
    use = kernels.usable_slots(nbr, nbr >= 0, transmit)
    src_ref, slot_ref = _freshness_oracle(tau, nbr, use)
    assert (slot_ref >= 0).any() and (slot_ref > 0).any()  # adoptions from later slots too
    for work in (1 << 62, 0):  # serial, then threaded
        monkeypatch.setattr(compiled, "PARALLEL_WORK", work)
        src, slot = kernels.freshness_choice(tau, nbr, nbr >= 0, transmit)
        np.testing.assert_array_equal(slot, slot_ref)
        np.testing.assert_array_equal(src, src_ref)


def test_driver_cache_names_follow_the_rules_they_inline():
    """numba's disk cache only checks the driver's own file: the drivers' names carry a
    digest of the row functions' modules, so editing a rule recompiles every driver."""
    import hashlib
    from pathlib import Path

    from netsense.kernels import drivers

    here = Path(compiled.__file__).parent
    h = hashlib.sha256()
    for name in ("rules.py", "jit.py", "lanes.py"):  # rows, streams, vector code
        h.update((here / name).read_bytes())
    digest = h.hexdigest()[:12]
    assert compiled.inlined_digest() == digest
    for d in (drivers.apply_all, observation._fill):
        for build in (d.serial, d.parallel):
            assert build.py_func.__qualname__.endswith(f"_{digest}")


@pytest.mark.parametrize("what", ["batch", "valid", "transmit", "node"])
def test_freshness_choice_rejects_slots_that_do_not_fit(what):
    s = _random_step(0, B=2)
    tau, nbr = s["tau"], s["nbr"].copy()
    valid = nbr >= 0
    transmit = None
    if what == "batch":
        nbr, valid = nbr[:1], valid[:1]
    elif what == "valid":
        valid = valid[..., :1]
    elif what == "transmit":
        transmit = np.ones((2, 1), bool)
    else:
        nbr[valid] = tau.shape[1]  # one past the last agent
    match = {"batch": "nbr must have shape", "valid": "valid must have shape",
             "transmit": "transmit must", "node": "nbr must hold indices in 0..9"}[what]
    with pytest.raises(ValueError, match=match):
        kernels.freshness_choice(tau, nbr, valid, transmit)
