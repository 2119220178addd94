"""The communication tasks at scale: the oscillator-bank plant, the geometric graph, the
K-of-N channel, their scenario files and cards, and the experiment script's outputs."""

from __future__ import annotations

import re
from pathlib import Path

import networkx as nx
import numpy as np
import pytest

from netsense.engine.core import BatchedCore
from netsense.env.registry import Scenario, build_model, build_plant, list_scenarios, load
from netsense.graphs.geometric import geometric_edges, geometric_layout
from netsense.graphs.mobility import disk_graph
from netsense.systems.plants import OSCILLATOR_THETAS, oscillator_bank

KOFN = ("comm_channel_kofn_n50-v0", "comm_channel_kofn_n200-v0", "comm_channel_kofn_n1000-v0")
SPATIAL = ("comm_spatial_n50-v0", "comm_spatial_n200-v0")
DOCS = Path(__file__).parents[1] / "docs"


# ----------------------------------------------------------------------------- the plant
def test_oscillator_bank_is_block_diagonal_with_the_stated_spectral_radius():
    p, rho = 4, 0.97
    P = oscillator_bank(28, agents_per_oscillator=p, spectral_radius=rho)
    m = 28 // p
    assert P.n == 2 * m and P.num_agents == 28
    mask = np.kron(np.eye(m, dtype=bool), np.ones((2, 2), dtype=bool))
    assert not P.A[~mask].any()  # nothing couples two oscillators
    for j in range(m):
        th = OSCILLATOR_THETAS[j % len(OSCILLATOR_THETAS)]
        R = rho * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        np.testing.assert_allclose(P.A[2 * j:2 * j + 2, 2 * j:2 * j + 2], R, atol=1e-15)
    np.testing.assert_allclose(np.abs(np.linalg.eigvals(P.A)), rho, atol=1e-12)
    for i, Ci in enumerate(P.C):  # agent p j measures block j, the others nothing
        if i % p:
            assert Ci.shape == (0, P.n)
        else:
            want = np.zeros((2, P.n))
            want[:, 2 * (i // p):2 * (i // p) + 2] = np.eye(2)
            np.testing.assert_array_equal(Ci, want)


def test_oscillator_bank_at_n10_is_the_plant_of_comm_process_noise():
    ref = build_plant(load("comm_process_noise-v0"))
    P = oscillator_bank(10)
    np.testing.assert_allclose(P.A, ref.A, atol=1e-6)  # the file's six digits
    for a, b in zip(P.C, ref.C, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("sid", KOFN + SPATIAL)
def test_scale_tasks_share_the_five_oscillators(sid):
    P = build_plant(load(sid))
    N = P.num_agents
    assert int(re.search(r"_n(\d+)-", sid).group(1)) == N
    np.testing.assert_allclose(P.A, oscillator_bank(10).A)
    assert [i for i, r in enumerate(P.output_sizes) if r] == [j * N // 5 for j in range(5)]


# ----------------------------------------------------------------------------- the graph
def test_geometric_layout_links_exactly_the_pairs_within_the_radius():
    N, r, seed = 80, 0.18, 5
    pos, adj = geometric_layout(N, r, seed)
    assert pos.shape == (N, 2) and ((pos >= 0) & (pos <= 1)).all()
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    want = (d <= r) & ~np.eye(N, dtype=bool)
    np.testing.assert_array_equal(adj, want)
    np.testing.assert_array_equal(adj, disk_graph(pos, r))  # the mobility rule agrees
    G = nx.random_geometric_graph(N, r, seed=seed)  # networkx's own draw
    np.testing.assert_allclose(pos, [G.nodes[v]["pos"] for v in range(N)])
    assert {frozenset(e) for e in G.edges()} == {frozenset((i, l)) for i, l in
                                                 zip(*np.nonzero(adj), strict=True)}
    edges = geometric_edges(N, r, seed)  # both directions of every link, l -> i
    assert sorted(map(tuple, edges)) == sorted((int(l_), int(i)) for i, l_ in
                                               zip(*np.nonzero(adj), strict=True))


def test_geometric_layout_is_one_layout_per_seed():
    a, b = geometric_layout(50, 0.25, 1), geometric_layout(50, 0.25, 1)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert not np.array_equal(a[0], geometric_layout(50, 0.25, 2)[0])


@pytest.mark.parametrize("sid", SPATIAL)
def test_spatial_tasks_fade_links_of_a_connected_geometric_graph(sid):
    sc = load(sid)
    base = sc.graph["base"]
    _, adj = geometric_layout(sc.graph["num_nodes"], base["radius"], base["seed"])
    assert nx.is_connected(nx.from_numpy_array(adj.astype(int)))
    graphs = build_model(sc).graphs
    seq = graphs.sequence(40, 7)
    assert not (seq & ~adj).any()  # only base links are ever up
    assert (seq != seq[:1]).any() and seq.any()  # and they switch


# ----------------------------------------------------------------------------- the channel
def _core_after(sid: str, senders: int, seed: int = 3) -> BatchedCore:
    """A core of ``sid`` (horizon 4) one step after ``senders`` agents set their bit."""
    core = BatchedCore(build_model(_short(sid)), 1)
    core.reset([seed])
    bits = np.zeros((1, core.N, 1), dtype=np.int64)
    bits[0, :senders] = 1
    core.step(bits)
    return core


def _short(sid: str, horizon: int = 4) -> Scenario:
    from netsense.env.registry import with_overrides

    return with_overrides(load(sid), horizon=horizon)


@pytest.mark.parametrize("sid", KOFN[:2])
def test_kofn_channel_loses_every_message_beyond_k(sid):
    K = load(sid).channel["capacity"]
    assert K == int(re.search(r"_n(\d+)-", sid).group(1)) // 5
    over = _core_after(sid, K + 1)
    assert over.transmit.sum() == K + 1 and over.collided[0]
    assert not over.msg.any()
    ok = _core_after(sid, K)
    assert ok.transmit.sum() == K and not ok.collided[0]
    assert ok.msg.any()  # senders with an up out-link deliver
    sender = ok.nbr[0]  # (N, D): the in-neighbour in each slot, -1 for none
    assert not ok.msg[0][(sender >= K) | (sender < 0)].any()  # only the K senders


def test_scale_realisations_are_deterministic_per_seed():
    model = build_model(_short("comm_spatial_n50-v0", 12))

    def run(seed):
        core = BatchedCore(model, 1)
        core.reset([seed])
        out, adj = [], []
        for _ in range(12):
            r = core.step(np.ones((1, core.N, 1), dtype=np.int64))
            out.append(r.reward.copy())
            adj.append(core.adjacency.copy())
        return np.array(out), np.array(adj), core.x.copy()

    a, b, c = run(11), run(11), run(12)
    for u, v in zip(a, b, strict=True):
        np.testing.assert_array_equal(u, v)
    assert not np.array_equal(a[1], c[1]) and not np.array_equal(a[2], c[2])


# ----------------------------------------------------------------------------- bad input
def _raw(sid: str) -> dict:
    return load(sid).to_dict()


def test_bad_parameters_fail_naming_the_field_before_anything_is_built(monkeypatch):
    import netsense.systems.plants as plants

    def refuse(*a, **k):
        raise AssertionError("built before the parameters were checked")

    monkeypatch.setattr(plants, "Plant", refuse)
    monkeypatch.setattr(nx, "random_geometric_graph", refuse)
    with pytest.raises(ValueError, match="num_agents must be a multiple of "
                                         "agents_per_oscillator = 4"):
        oscillator_bank(30, agents_per_oscillator=4)
    with pytest.raises(ValueError, match="spectral_radius"):
        oscillator_bank(10, spectral_radius=-1)
    with pytest.raises(ValueError, match="radius"):
        geometric_layout(10, -0.1, 0)
    raw = _raw("comm_channel_kofn_n50-v0")
    raw["plant"]["num_agents"] = 52  # agents_per_oscillator = 10
    with pytest.raises(ValueError, match=r"field 'plant\.num_agents'.*multiple"):
        Scenario.from_dict("x-v0", raw)
    raw = _raw("comm_channel_kofn_n50-v0")
    raw["channel"]["capacity"] = 51
    with pytest.raises(ValueError, match=r"field 'channel\.capacity'.*<= the number of "
                                         r"agents N = 50"):
        Scenario.from_dict("x-v0", raw)
    raw = _raw("comm_spatial_n50-v0")
    raw["graph"]["base"]["radius"] = -0.2
    with pytest.raises(ValueError, match=r"field 'graph\.base\.radius'"):
        Scenario.from_dict("x-v0", raw)
    raw["graph"]["base"] = {"kind": "geometric", "radius": 0.2, "sede": 1}
    with pytest.raises(ValueError, match=r"field 'graph\.base\.sede'"):
        Scenario.from_dict("x-v0", raw)


# ----------------------------------------------------------------------------- docs, script
def test_every_scale_task_is_registered_and_has_a_card():
    """docs/tasks.md's "Tasks at scale" has one card per task, each stating the file's
    ``N``, capacity ``K``, message cost and horizon."""
    assert set(KOFN + SPATIAL) <= set(list_scenarios())
    text = (DOCS / "tasks.md").read_text()
    sec = text[text.index("## Tasks at scale"):]
    sec = sec[: sec.index("\n## ", 5)] if "\n## " in sec[5:] else sec
    cards = re.split(r"^### `([\w-]+)`.*$", sec, flags=re.M)
    bodies = dict(zip(cards[1::2], cards[2::2], strict=True))
    assert set(bodies) == set(KOFN + SPATIAL)
    for sid, body in bodies.items():
        sc = load(sid)
        assert re.search(r"`N = (\d+)`", body).group(1) == str(sc.graph["num_nodes"]), sid
        k = re.search(r"`K = (\d+)`", body)
        assert (int(k.group(1)) if k else None) == (sc.channel or {}).get("capacity"), sid
        assert re.search(r"`c = ([\d.]+)` per message", body).group(1) == \
            f"{sc.reward.message_cost:g}", sid
        assert re.search(r"`H = (\d+)` steps", body).group(1) == str(sc.horizon), sid


def test_scale_tasks_script_writes_its_outputs(tmp_path, monkeypatch):
    from experiment_loader import load_experiment

    mod = load_experiment("rl/scale_tasks")
    fams = mod.scale_families("comm_channel_kofn_n200-v0")
    assert "tdma" in fams and "oldest" not in fams
    assert "tdma" not in mod.scale_families("comm_spatial_n50-v0")
    assert mod.scheduler_families("comm_channel_kofn_n200-v0") == {"oldest": (40,),
                                                                   "whittle": (40,)}
    assert mod.scheduler_families("comm_channel_kofn_n1000-v0") == {"oldest": (200,)}
    assert mod.scheduler_families("comm_spatial_n50-v0")["whittle"] == (10,)
    monkeypatch.setattr(mod, "scale_families", lambda sc: {"periodic": (5,)})
    monkeypatch.setattr(mod, "scheduler_families", lambda sc: {"oldest": (10,)})
    monkeypatch.setattr(mod, "ORACLE_BASES", ("sources:0",))
    summary = mod.main(["--scenarios", "comm_channel_kofn_n50-v0", "--episodes", "2",
                        "--horizon", "3", "--out", str(tmp_path), "--no-progress"])
    assert [r["what"] for r in summary] == list(mod.WHAT)
    assert {r["policy"] for r in summary} >= {"always", "never", "oldest:10",
                                              "oracle(sources:0)"}
    assert all(r["episodes"] == 2 and r["horizon"] == 3 for r in summary)
    for name in ("summary.csv", "summary.md", "scale_tasks.png", "frontier.csv",
                 "frontier_comm_channel_kofn_n50-v0.csv"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert not list(tmp_path.glob("*.tmp*"))  # written atomically, nothing left over
