"""The full-information reference schedulers (netsense.benchmark.lookahead): an
exhaustive-search oracle on a tiny task, sequential improvement over every continuation,
determinism, and a causal reference that never reads the realised future; their place in
the protocol (rows, headroom, plot)."""

from __future__ import annotations

import csv
import itertools

import numpy as np
import pytest

from netsense.benchmark import protocol as pr
from netsense.benchmark.headroom import headroom
from netsense.benchmark.intervals import bootstrap_ci, paired_percent, seeded_global_rng
from netsense.benchmark.lookahead import LookaheadConfig, LookaheadReference, parse_reference
from netsense.engine.core import BatchedCore
from netsense.engine.fork import fork
from netsense.env.comm_policies import make_comm_policy
from netsense.env.vector import load_model

C, S = np.cos(0.3), np.sin(0.3)
#: N = 3 agents (two sources, one relay), transmit-only, noisy: messages matter and cost.
TINY = dict(plant={"kind": "matrices", "A": [[0.97 * C, -0.97 * S, 0], [0.97 * S, 0.97 * C, 0],
                                             [0, 0, 0.9]],
                   "C": [[[1, 0, 0], [0, 1, 0]], [[0, 0, 1]], []]},
            graph={"kind": "random_jsc", "num_nodes": 3, "period": 2, "extra_edge_prob": 0.2},
            noise={"process": {"kind": "gaussian", "std": 0.3},
                   "measurement": {"kind": "gaussian", "std": 0.01}},
            reward={"message_cost": 0.1})
SID = "comm_process_noise-v0"


def tiny(horizon: int):
    return load_model(SID, horizon=horizon, **TINY)[0]


def _run(model, seeds, act_of, chunk=1):
    """Episode returns (mean over agents) and the bits taken, with ``act_of(core)``."""
    core = BatchedCore(model, len(seeds), chunk=chunk)
    obs, mask = core.reset(seeds)
    act = act_of(core)
    ret, bits = np.zeros(len(seeds)), []
    for _ in range(model.horizon):
        a = act(obs, mask)
        bits.append(a.copy())
        out = core.step(a)
        obs, mask = out.obs, out.action_mask
        ret += out.reward.mean(1)
    return ret, np.stack(bits, 1)


def _returns_of_sequences(model, seed, prefix, length):
    """Return of every continuation of ``prefix`` by ``length`` patterns, each replayed
    from a fresh reset (no fork involved): ``{sequence: return}``."""
    N = model.plant.num_agents
    patterns = list(itertools.product((0, 1), repeat=N))
    out = {}
    for seq in itertools.product(patterns, repeat=length):
        core = BatchedCore(model, 1)
        core.reset([seed])
        total = 0.0
        for bits in list(prefix) + list(seq):
            total += core.step(np.array(bits, dtype=np.int64).reshape(1, N, 1)).reward.mean()
        out[tuple(seq)] = total
    return out


def test_clairvoyant_exhaustive_lookahead_equals_the_exhaustive_optimum():
    """Horizon 3, N = 3: all 8^3 transmit sequences replayed from the seed are the oracle.
    A lookahead over the realised future that enumerates every sequence to the end of the
    episode picks, at each step, a first pattern of an optimal remaining sequence, and
    its episode return is the optimum."""
    H, seed = 3, 1000003
    model = tiny(H)
    cfg = LookaheadConfig(kind="clairvoyant", horizon=H, candidates="exhaustive", depth=H,
                      continuation=("always",))
    ret, bits = _run(model, [seed], lambda core: LookaheadReference(core, cfg, [seed]).act)
    taken = [tuple(int(v) for v in bits[0, k, :, 0]) for k in range(H)]
    every = _returns_of_sequences(model, seed, [], H)
    for k in range(H):
        values = {seq[k:]: v for seq, v in every.items() if list(seq[:k]) == taken[:k]}
        best = max(values.values())
        mine = max(v for seq, v in values.items() if seq[0] == taken[k])
        assert mine == pytest.approx(best, abs=1e-12), k
    oracle = max(every.values())
    assert ret[0] == pytest.approx(oracle, abs=1e-12)
    assert oracle > min(every.values()) + 0.05  # (not trivial: the sequences differ)


@pytest.mark.parametrize("kind", ["clairvoyant", "causal"])
def test_one_step_exhaustive_choice_at_the_last_step_is_optimal(kind):
    """At the last step the bits only cost (they would be sent after the episode): both
    references pick a pattern that is optimal among all 2^N by the replayed oracle."""
    H, seed = 4, 1000001
    model = tiny(H)
    cfg = LookaheadConfig(kind=kind, horizon=1, futures=3, candidates="exhaustive",
                      continuation=("always",))
    core = BatchedCore(model, 1, chunk=1)
    obs, mask = core.reset([seed])
    prefix = [(1, 0, 1), (0, 1, 1), (1, 1, 0)]
    for bits in prefix:
        obs, mask = core.step(np.array(bits, dtype=np.int64).reshape(1, 3, 1))[:2]
    choice = tuple(int(v) for v in LookaheadReference(core, cfg, [seed]).act(obs, mask)[0, :, 0])
    values = _returns_of_sequences(model, seed, prefix, 1)
    assert values[(choice,)] == pytest.approx(max(values.values()), abs=1e-12)
    assert choice == (0, 0, 0)


def test_clairvoyant_reference_beats_every_continuation_episode_by_episode():
    """Sequential improvement: realised future, horizon to the end of the episode, each
    continuation's own action among the candidates -> the reference's return is at least each
    continuation policy's, on every episode."""
    H = 12
    model = tiny(H)
    seeds = [1000000 + i for i in range(4)]
    conts = ("event:1", "always", "never", "periodic:2", "oldest:1")
    cfg = LookaheadConfig(kind="clairvoyant", horizon=H, continuation=conts)
    ret, _ = _run(model, seeds, lambda core: LookaheadReference(core, cfg, seeds).act)
    for spec in conts:
        base, _ = _run(model, seeds, lambda core, spec=spec: make_comm_policy(spec, core).act)
        assert np.all(ret >= base - 1e-9), (spec, ret, base)
    # and strictly better than the best of them somewhere (the search does something)
    best = np.max([_run(model, seeds, lambda c, s=s: make_comm_policy(s, c).act)[0]
                   for s in conts], axis=0)
    assert np.any(ret > best + 1e-6)


@pytest.mark.parametrize("kind", ["causal", "clairvoyant"])
def test_references_are_deterministic_for_a_seed(kind):
    model = tiny(10)
    seeds = [1000000, 1000007]
    cfg = LookaheadConfig(kind=kind, horizon=4, futures=3, continuation=("event:1",), seed=5)
    r1, b1 = _run(model, seeds, lambda core: LookaheadReference(core, cfg, seeds).act)
    r2, b2 = _run(model, seeds, lambda core: LookaheadReference(core, cfg, seeds).act)
    np.testing.assert_array_equal(b1, b2)
    np.testing.assert_array_equal(r1, r2)
    if kind == "causal":  # a member's decisions depend on its own evaluation seed only
        r3, b3 = _run(model, seeds[1:], lambda core: LookaheadReference(core, cfg, seeds[1:]).act)
        np.testing.assert_array_equal(b3[0], b1[1])


def _perturb_future(core, rng):
    """A copy of ``core`` (chunk 1) whose realised future differs from step k + 1 on and
    whose present is the same: new generators, another process noise w[k] and, inside a
    random jointly connected window, other unseen graphs of the window."""
    twin = fork(core, np.arange(core.B), chunk=1)
    twin._materialise(np.arange(core.B))
    for b in range(core.B):
        kids = np.random.SeedSequence(int(rng.integers(2**32))).spawn(len(twin.rngs[b]))
        twin.rngs[b] = {n: np.random.default_rng(c) for n, c in zip(twin.rngs[b], kids,
                                                                     strict=True)}
        pos, window = twin.graph_state[b]
        if pos:
            other = window.copy()
            other[pos:] = rng.random(other[pos:].shape) < 0.5
            other[:, np.arange(core.N), np.arange(core.N)] = False
            twin.graph_state[b] = (pos, other)
    twin.buf_w[:, 0] = rng.standard_normal(twin.buf_w[:, 0].shape)
    return twin


def test_the_causal_reference_never_reads_the_realised_future(monkeypatch):
    """At every step, the causal reference decides the same on a copy whose realised future
    was replaced; the clairvoyant one does not (so the replacement matters)."""
    model = tiny(16)
    seeds = [1000002, 1000004]
    rng = np.random.default_rng(0)
    causal = LookaheadConfig(kind="causal", horizon=4, futures=2, continuation=("event:1",))
    seer = LookaheadConfig(kind="clairvoyant", horizon=4, continuation=("event:1",))
    core = BatchedCore(model, 2, chunk=1)
    obs, mask = core.reset(seeds)
    differs = 0
    for _ in range(model.horizon):
        twin = _perturb_future(core, rng)
        act = LookaheadReference(core, causal, seeds).act(obs, mask)
        np.testing.assert_array_equal(LookaheadReference(twin, causal, seeds).act(obs, mask), act)
        differs += not np.array_equal(LookaheadReference(core, seer, seeds).act(obs, mask),
                                      LookaheadReference(twin, seer, seeds).act(obs, mask))
        obs, mask = core.step(act)[:2]
    assert differs > 0
    # the test has teeth: a fork that kept the graph state (G[k+1] of the window) would
    # let the realised future in
    from netsense.graphs.processes import RandomJointlyConnected

    monkeypatch.setattr(RandomJointlyConnected, "redraw_state",
                        lambda self, rng, state, previous, graph: state)
    core = BatchedCore(model, 2, chunk=1)
    obs, mask = core.reset(seeds)
    leaked = 0
    for _ in range(model.horizon):
        twin = _perturb_future(core, rng)
        act = LookaheadReference(core, causal, seeds).act(obs, mask)
        leaked += not np.array_equal(LookaheadReference(twin, causal, seeds).act(obs, mask), act)
        obs, mask = core.step(act)[:2]
    assert leaked > 0


def test_selection_with_a_confidence_margin():
    """Candidate 0 is the base; 1 is better on average but only by luck of one future;
    2 is better on every future."""
    model = tiny(5)
    core = BatchedCore(model, 1, chunk=1)
    core.reset(0)
    q = np.array([[0.0, 12.0, 1.0], [0.0, -2.0, 1.2], [0.0, -2.5, 0.9], [0.0, -1.0, 1.1]])
    plain = LookaheadReference(core, LookaheadConfig(confidence=0.0), [0])
    careful = LookaheadReference(core, LookaheadConfig(confidence=1.0), [0])
    assert plain._choose(q) == 1 and careful._choose(q) == 2
    assert careful._choose(q[:, :2]) == 0  # nothing reliably better: keep the base
    assert careful._choose(q[:1]) == 1  # one future: the plain argmax


def test_second_round_combines_every_improving_single_flip():
    model = tiny(5)
    core = BatchedCore(model, 1, chunk=1)
    core.reset(0)
    look = LookaheadReference(core, LookaheadConfig(kind="clairvoyant"), [0])
    base = np.array([[1], [0], [1]])
    pats = np.stack([base, 1 - base, base ^ [[1], [0], [0]], base ^ [[0], [1], [0]],
                     base ^ [[0], [0], [1]]])
    conts = np.zeros(5, dtype=np.int64)
    q = np.array([[0.0, 5.0, 1.0, 2.0, -1.0]])  # flips of agents 0 and 1 gain, 2 loses
    np.testing.assert_array_equal(look._combination(pats, conts, q), [[0], [1], [1]])
    assert look._combination(pats, conts, np.array([[0.0, 5.0, 1.0, -2.0, -1.0]])) is None
    with pytest.raises(ValueError, match="rounds"):
        LookaheadConfig(rounds=3)


def test_terminal_estimate_counts_the_last_step_again():
    """Clairvoyant scores: h = 2 with a terminal of 5 steps is the h = 2 return plus 5
    times its second step (the h = 2 minus the h = 1 return)."""
    model = tiny(12)
    core = BatchedCore(model, 2, chunk=1)
    obs, mask = core.reset([5, 6])
    for _ in range(3):
        obs, mask = core.step(np.ones((2, 3, 1), dtype=np.int64))[:2]
    scores = {}
    for h, t in ((1, 0), (2, 0), (2, 5)):
        look = LookaheadReference(core, LookaheadConfig(kind="clairvoyant", horizon=h, terminal=t,
                                                 continuation=("event:1",)), [5, 6])
        look.act(obs, mask)
        scores[h, t] = look.scores
    for b in range(2):
        q1, q2, q25 = scores[1, 0][b], scores[2, 0][b], scores[2, 5][b]
        np.testing.assert_allclose(q25, q2 + 5 * (q2 - q1), rtol=1e-12)


def test_channel_candidates_swap_senders():
    model = load_model("comm_channel_k2-v0", horizon=10)[0]
    core = BatchedCore(model, 1, chunk=1)
    obs, mask = core.reset([3])
    look = LookaheadReference(core, LookaheadConfig(continuation=("whittle:2",)), [3])
    pats, _ = look.candidates(obs, mask)
    base = pats[0][0, 0, :, 0]
    senders = {tuple(np.flatnonzero(p[0, :, 0])) for p in pats[0]}
    on = np.flatnonzero(base)
    assert len(on) == 2
    swaps = {tuple(sorted({*on} - {i} | {j})) for i in on for j in range(10) if j not in on}
    assert swaps <= senders and len(swaps) == 16


def test_substates_mode_and_channel():
    for sid, over in (("comm_substates-v0", {}), ("comm_channel_k2-v0", {})):
        seeds = [1000000, 1000001]
        cfg = LookaheadConfig(kind="causal", horizon=3, futures=2, continuation=("event:1",))
        vals = pr.evaluate(sid, "reference:causal", seeds, {"horizon": 8, **over}, reference=cfg)
        base = pr.evaluate(sid, "event:1", seeds, {"horizon": 8, **over})
        assert np.isfinite(vals["reward"]).all()
        assert vals["reward"].shape == base["reward"].shape == (2,)


def test_reference_configuration_is_checked():
    for bad in ({"kind": "oracle"}, {"horizon": 0}, {"futures": 0}, {"depth": 2},
                {"candidates": "all"}, {"continuation": ()}, {"continuation": "event:2"},
                {"continuation": ("bernoulli:0.5",)}, {"continuation": ("telepathy",)},
                {"seed": -1}, {"known_ahead": -1},
                {"candidates": "exhaustive", "depth": 3, "horizon": 2}):
        with pytest.raises(ValueError):
            LookaheadConfig(**bad)
    assert parse_reference("reference:causal:sources:0").continuation == ("sources:0",)
    assert parse_reference("reference:clairvoyant").kind == "clairvoyant"
    with pytest.raises(ValueError, match="reference spec"):
        parse_reference("reference:psychic")
    for old in ("bound:causal", "bound:clairvoyant:event:2"):  # the former spelling
        with pytest.raises(ValueError, match="write 'reference:"):
            parse_reference(old)
        with pytest.raises(ValueError, match="not bounds"):
            pr.evaluate(SID, old, [0], {"horizon": 4, **TINY})
    for random_base in ("aloha:1,1", "acked(bernoulli:0.5)"):
        with pytest.raises(ValueError, match="random bits"):
            LookaheadConfig(continuation=(random_base,))
    assert LookaheadConfig(continuation=("acked(event:2)",)).continuation == ("acked(event:2)",)
    model = tiny(5)
    core = BatchedCore(model, 1, chunk=4)
    core.reset(0)
    with pytest.raises(ValueError, match="chunk=1"):
        LookaheadReference(core, LookaheadConfig(), [0])
    with pytest.raises(ValueError, match="one evaluation seed"):
        LookaheadReference(core, LookaheadConfig(kind="clairvoyant"), [0, 1])
    with pytest.raises(TypeError, match="LookaheadConfig"):
        LookaheadReference(core, {"kind": "causal"}, [0])
    full = BatchedCore(load_model("fig1_scalar-v0")[0], 1, chunk=1)
    full.reset(0)
    with pytest.raises(ValueError, match="communication-only"):
        LookaheadReference(full, LookaheadConfig(), [0])
    big = BatchedCore(load_model("comm_substates-v0")[0], 1, chunk=1)
    big.reset(0)
    with pytest.raises(ValueError, match="exhaustive"):
        LookaheadReference(big, LookaheadConfig(candidates="exhaustive"), [0])


# --------------------------------------------------------------------------- protocol
def test_seeded_global_rng_repeats_and_restores():
    """The same draws from NumPy's global generator in every block of one seed (what makes
    rliable's stratified bootstrap reproducible), and the caller's state back afterwards,
    also when the block raises."""
    np.random.seed(123)  # noqa: NPY002
    before = np.random.get_state()[1].copy()  # noqa: NPY002
    with seeded_global_rng():
        a = np.random.rand(3)  # noqa: NPY002
    assert np.array_equal(np.random.get_state()[1], before)  # noqa: NPY002
    with seeded_global_rng():
        b = np.random.rand(3)  # noqa: NPY002
    with seeded_global_rng(1):
        c = np.random.rand(3)  # noqa: NPY002
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    with pytest.raises(RuntimeError), seeded_global_rng():
        raise RuntimeError
    assert np.array_equal(np.random.get_state()[1], before)  # noqa: NPY002


def test_paired_intervals():
    rng = np.random.default_rng(1)
    ref = rng.normal(-100, 10, 40)
    bound = ref + 5 + rng.normal(0, 0.5, 40)  # a small, consistent gain over a wide spread
    mean, lo, hi = bootstrap_ci(bound - ref)
    assert 4.5 < lo < mean < hi < 5.5  # paired: far narrower than the spread of either
    pct, plo, phi = paired_percent(bound, ref)
    assert pct == pytest.approx(100 * (bound - ref).mean() / abs(ref.mean()))
    assert plo < pct < phi
    with pytest.raises(ValueError):
        paired_percent(bound, ref[:3])


def test_frontier_with_references_rows_headroom_and_plot(tmp_path):
    fams = {"periodic": (1, 3), "whittle": (1,)}
    rows = pr.run_frontier([SID], tmp_path, episodes=4, families=fams, settled_bases=(),
                           overrides={"horizon": 10, **TINY}, progress=False,
                           references=("causal", "clairvoyant"), reference_episodes=2,
                           reference_config=LookaheadConfig(horizon=3, futures=2))
    kinds = {r["policy"]: r["kind"] for r in rows}
    assert kinds["periodic:1"] == kinds["always"] == "decentralised"
    assert kinds["whittle:1"] == "centralised"
    assert kinds["reference:causal"] == kinds["reference:clairvoyant"] == "reference"
    refs = [r for r in rows if r["kind"] == "reference"]
    assert all(r["episodes"] == 2 and r["pareto"] == "" for r in refs)
    best = pr.best_scripted(rows, deterministic=True)["policy"]
    assert refs[0]["knob"].split(" + ")[0] == best
    # the reference's values are those of evaluate() on the first two seeds
    again = pr.evaluate(SID, "reference:causal", pr.eval_seeds(2), {"horizon": 10, **TINY},
                        reference=refs[0]["reference_config"])
    np.testing.assert_array_equal(again["reward"], refs[0]["values"]["reward"])
    with (tmp_path / "frontier.csv").open() as fh:
        table = list(csv.DictReader(fh))
    assert [r["kind"] for r in table][-2:] == ["reference", "reference"]
    assert table[-1]["episodes"] == "2" and table[0]["episodes"] == "4"
    heads = headroom(rows)
    assert {(h["reference"], h["best_kind"]) for h in heads} == {
        (b, k) for b in ("reference:causal", "reference:clairvoyant")
        for k in ("decentralised", "centralised")}
    for h in heads:
        best_row = next(r for r in rows if r["policy"] == h["best"])
        ref = next(r for r in rows if r["policy"] == h["reference"])
        d = ref["values"]["reward"] - best_row["values"]["reward"][:2]
        assert h["headroom_mean"] == pytest.approx(d.mean())
        assert h["headroom_ci_low"] <= h["headroom_mean"] <= h["headroom_ci_high"]
        assert best_row["kind"] == h["best_kind"]
    md = (tmp_path / "headroom.md").read_text()
    assert "full-information reference (clairvoyant)" in md and "(decentralised)" in md
    assert "bound" not in md + (tmp_path / "frontier.md").read_text()
    assert (tmp_path / f"frontier_{SID}.png").stat().st_size > 10_000


def test_plot_gives_every_series_its_own_legend_entry(tmp_path):
    from netsense.benchmark.frontier_plot import _series, _style

    def row(kind, family, policy, knob="", evaluation="scripted", label=None):
        r = {"kind": kind, "family": family, "policy": policy, "knob": knob,
             "evaluation": evaluation}
        if label:
            r["label"] = label
        return r

    rows = [row("decentralised", "always", "always"), row("decentralised", "never", "never"),
            row("decentralised", "periodic", "periodic:2", 2),
            row("centralised", "whittle", "whittle:1", 1),
            row("privileged", "oracle", "oracle(event:2)", "event:2"),
            row("decentralised", "gated", "gated(event:2)", "event:2"),
            row("reference", "reference", "reference:causal", "event:2", "lookahead"),
            row("upper_bound", "upper_bound", "upper_bound", "", "relaxation"),
            row("learned", "learned", "learned:a/s1/policy.pt", "a/s1/policy.pt", "greedy",
                "ppo"),
            row("learned", "learned", "learned:a/s2/policy.pt", "a/s2/policy.pt", "greedy",
                "ppo")]
    series = _series(rows)
    labels = [label for _, label, _ in series]
    assert len(labels) == len(set(labels)) == len(rows)  # two runs of one variant apart
    index: dict = {}
    looks = [tuple(sorted(_style(k, lab, rs, index).items())) for k, lab, rs in series]
    assert len(set(looks)) == len(looks)  # and no two series look alike
    old = [{k: v for k, v in r.items() if k != "kind"} for r in rows]  # an older CSV
    assert [k for k, _, _ in _series(old)] == [k for k, _, _ in series]


def test_frontier_command_with_references(tmp_path, capsys):
    from netsense.cli import main

    assert main(["benchmark", SID, "--frontier", "--seeds", "3", "--families", "sources",
                 "--references", "clairvoyant", "--reference-episodes", "2",
                 "--reference-horizon", "2",
                 "--override", "horizon=6", "--out", str(tmp_path), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "full-information reference (clairvoyant)" in printed
    assert "(decentralised)" in printed
    with (tmp_path / "headroom.csv").open() as fh:
        heads = list(csv.DictReader(fh))
    assert {h["best_kind"] for h in heads} == {"decentralised"}  # no scheduler ran
    assert {h["reference"] for h in heads} == {"reference:clairvoyant"}
    assert heads[0]["episodes"] == "2"


def test_comm_bounds_experiment_smoke(tmp_path):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "experiments" / "rl" / "comm_bounds.py"
    spec = importlib.util.spec_from_file_location("_exp_comm_bounds", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["--smoke", "--tasks", "comm_channel_k2-v0", "--tradeoff-task",
                     "comm_channel_k2-v0", "--out", str(tmp_path)]) == 0
    for name in ("frontier.csv", "headroom.md", "tradeoff.csv", "tradeoff.png",
                 "frontier_comm_channel_k2-v0.png"):
        assert (tmp_path / name).stat().st_size > 0
    with (tmp_path / "tradeoff.csv").open() as fh:
        trade = list(csv.DictReader(fh))
    assert len(trade) == len(mod.TRADEOFF)
    default = [t for t in trade if t["reference"] == "reference:causal" and t["horizon"] == "8"
               and t["futures"] == "8" and t["confidence"] == "1" and t["rounds"] == "2"]
    assert len(default) == 1 and float(default[0]["gain_vs_default"]) == 0
    # --keep-references: the frontier again, the references carried over unchanged
    kept = tmp_path / "kept"
    assert mod.main(["--smoke", "--tasks", "comm_channel_k2-v0", "--tradeoff-task",
                     "comm_channel_k2-v0", "--out", str(kept), "--keep-references",
                     str(tmp_path)]) == 0
    for name in ("episodes.csv", "tradeoff.csv"):
        assert (kept / name).read_text() == (tmp_path / name).read_text(), name

    def heads(folder):  # (the wall time is read back with 6 digits)
        with (folder / "headroom.csv").open() as fh:
            return [{k: v for k, v in r.items() if k != "reference_seconds_per_episode"}
                    for r in csv.DictReader(fh)]
    assert heads(kept) == heads(tmp_path)


def test_a_scenario_that_announces_the_next_graph_keeps_it_in_the_futures():
    """A scenario that announces the next graph (``comm_announced-v0``: ``known_ahead`` 1)
    hands that to the forks: every resampled future then has the realised G[k+1]."""
    from netsense.engine import fork as fork_module
    from netsense.env.vector import load_model

    model, _ = load_model("comm_announced-v0")
    assert model.known_ahead == 1
    core = BatchedCore(model, 1, chunk=1)
    obs, mask = core.reset([7])
    seen = {}

    def spy(*args, **kwargs):
        seen.update(kwargs)
        return fork(*args, **kwargs)

    ref = LookaheadReference(core, LookaheadConfig(horizon=2, futures=2), [7])
    assert ref.known_ahead == 1
    import unittest.mock

    with unittest.mock.patch.object(fork_module, "fork", spy):
        ref.act(obs, mask)
    assert seen["known_ahead"] == 1 and seen["future"] == "resampled"
