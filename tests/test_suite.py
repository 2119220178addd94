"""The benchmark suite: its statistics against independent computations, the references,
the framework-neutral policy file, scoring callables, files and runs folders, the command
line, and the leaderboard page against the committed table."""

from __future__ import annotations

import json
import math
import pickle
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rliable")

from netsense.benchmark import scores  # noqa: E402
from netsense.benchmark.references import (  # noqa: E402
    EpisodeValues,
    TaskReferences,
    load_references,
    references_json,
)

ROOT = Path(__file__).resolve().parents[1]
REFS = ROOT / "netsense" / "benchmark" / "data" / "suite_references.json"
TASK = "comm_announced-v0"


def _refs_with_bound(tmp_path: Path, gain: float = 100.0) -> Path:
    """The package's references with a synthetic bound: never's return + ``gain``."""
    data = json.loads(REFS.read_text())
    for entry in data["tasks"].values():
        entry["upper_bound"] = {"seeds": entry["never"]["seeds"],
                                "values": [v + gain for v in entry["never"]["returns"]]}
    path = tmp_path / "refs.json"
    path.write_text(json.dumps(data))
    return path


def _never(obs, mask):
    """No agent ever sends: choice 0 of every entry (every communication layout's 'no')."""
    return np.zeros(mask.shape[:2] + (mask.shape[-1] // 2,), dtype=np.int64)


# ----------------------------------------------------------------------------- statistics
def test_iqm_interval_matches_numpy():
    rng = np.random.default_rng(3)
    x = rng.normal(size=40) ** 3  # a long-tailed sample
    point, lo, hi = scores.iqm_interval(x)
    assert point == pytest.approx(np.sort(x)[10:30].mean(), abs=1e-12)
    # an independent percentile bootstrap of the IQM (one stratum: rows resampled)
    idx = rng.integers(0, 40, size=(4000, 40))
    boot = np.sort(x[idx], axis=1)[:, 10:30].mean(1)
    ref_lo, ref_hi = np.percentile(boot, [2.5, 97.5])
    width = ref_hi - ref_lo
    assert lo <= point <= hi
    assert abs(lo - ref_lo) < 0.15 * width and abs(hi - ref_hi) < 0.15 * width
    # a (runs, tasks) matrix: the IQM over all entries
    m = rng.normal(size=(8, 5))
    assert scores.iqm_interval(m)[0] == pytest.approx(np.sort(m.ravel())[10:30].mean())
    # reproducible, and the global generator left as it was
    state = np.random.get_state()[1].copy()  # noqa: NPY002 (the global one is the point)
    assert scores.iqm_interval(x) == (point, lo, hi)
    assert (np.random.get_state()[1] == state).all()  # noqa: NPY002


def test_normalise_by_hand():
    never = np.array([-10.0, -20.0, -5.0])
    bound = np.array([0.0, -10.0, -5.0])  # nothing to gain on the last episode
    r = np.array([[-5.0, -20.0, -5.0], [0.0, -12.0, -5.0]])
    s = scores.normalise(r, never, bound)
    assert s[:, :2] == pytest.approx(np.array([[0.5, 0.0], [1.0, 0.8]]))
    assert np.isnan(s[:, 2]).all()
    with pytest.raises(ValueError, match="below never"):
        scores.normalise(r, never, np.array([0.0, -30.0, 0.0]))
    with pytest.raises(ValueError, match="share E"):
        scores.normalise(r, never[:2], bound[:2])


def test_probability_of_improvement():
    rng = np.random.default_rng(0)
    x = np.round(rng.normal(size=50), 1)  # with ties
    assert scores.probability_of_improvement(x, x) == pytest.approx(0.5)
    assert scores.probability_of_improvement(x + 10, x) == pytest.approx(1.0)
    y = np.array([0.0, 1.0])
    # pairs (0>0: 1/2, 0>1: 0, 2>0: 1, 2>1: 1) / 4
    assert scores.probability_of_improvement(np.array([0.0, 2.0]), y) == pytest.approx(0.625)


def _ref(task, never, bound, dec, spec="event:1"):
    seeds = tuple(range(1_000_000, 1_000_000 + len(never)))
    return TaskReferences(task, "transmit", EpisodeValues(seeds, np.asarray(never)), spec,
                          EpisodeValues(seeds, np.asarray(dec)), None, None,
                          EpisodeValues(seeds, np.asarray(bound)))


def test_summarise_aggregate_by_hand():
    from netsense.benchmark.suite import reference_rows, summarise

    rng = np.random.default_rng(1)
    tasks = ("comm_process_noise-v0", TASK)
    refs, rows, norm = {}, [], []
    for t in tasks:
        never = -100 + rng.normal(size=6)
        bound = never + 50 + rng.random(6)
        dec = never + 20
        refs[t] = _ref(t, never, bound, dec)
        for seed in (0, 1, 2):
            ret = never + rng.random(6) * 50
            norm.append((ret - never) / (bound - never))
            rows += [{"task": t, "learner": "mine", "kind": "policy", "seed": seed,
                      "episode_seed": 1_000_000 + e, "return": float(v)}
                     for e, v in enumerate(ret)]
    res = summarise(reference_rows(refs, list(range(1_000_000, 1_000_006))) + rows, refs)
    agg = next(r for r in res.table if r["task"] == "aggregate")
    flat = np.sort(np.concatenate(norm))  # 36 scores
    assert agg["score"] == pytest.approx(flat[9:27].mean())
    row = next(r for r in res.table if r["task"] == TASK)
    assert row["score"] == pytest.approx(np.sort(np.concatenate(norm[3:]))[4:14].mean())
    dec = np.sort(20 / (refs[TASK].upper_bound.values - refs[TASK].never.values))
    assert row["best_decentralised_score"] == pytest.approx(dec[1:5].mean())  # trims 1 + 1


# ----------------------------------------------------------------------------- references
def test_references_load_and_refuse():
    refs = load_references()
    assert TASK in refs and refs[TASK].never.values.shape == (100,)
    data = json.loads(REFS.read_text())
    entry = data["tasks"][TASK]
    entry["upper_bound"] = {"seeds": entry["never"]["seeds"],
                            "values": [v - 1 for v in entry["never"]["returns"]]}
    with pytest.raises(ValueError, match="below never"):
        references_json(data)
    data["tasks"][TASK]["upper_bound"] = None
    data["tasks"][TASK]["never"]["returns"] = data["tasks"][TASK]["never"]["returns"][:5]
    with pytest.raises(ValueError, match="never.returns"):
        references_json(data)


# ----------------------------------------------------------------------------- scoring
def test_never_callable_scores_zero(tmp_path):
    from netsense.benchmark.suite import score

    refs = _refs_with_bound(tmp_path)
    tasks = [TASK, "comm_substates-v0"]
    res = score({"never": _never}, tasks, 3, references=refs, progress=False)
    rows = [r for r in res.table if r["learner"] == "never"]
    assert [r["task"] for r in rows] == tasks + ["aggregate"]
    for r in rows:
        assert (r["score"], r["score_ci_low"], r["score_ci_high"]) == (0.0, 0.0, 0.0)
    data = json.loads(REFS.read_text())
    for r in rows[:-1]:
        stored = data["tasks"][r["task"]]["never"]["returns"][:3]
        assert r["iqm"] == pytest.approx(np.mean(stored))  # 3 values: trims none
        assert r["best_decentralised"] == data["tasks"][r["task"]]["best_decentralised"]["spec"]
        # the bound scores 1: here never + 100 on each of the three episodes
        assert r["upper_bound_mean"] == pytest.approx(np.mean(stored) + 100.0)
        assert r["upper_bound_ci_low"] <= r["upper_bound_mean"] <= r["upper_bound_ci_high"]


def test_no_bound_is_not_normalised():
    """The tasks at scale have no upper bound (its LP does not scale to N = 50): the suite
    scores them by name, without a normalised score."""
    from netsense.benchmark.references import SCALE_TASKS
    from netsense.benchmark.suite import score
    from netsense.benchmark.suite_output import markdown_table

    refs = load_references()
    task = SCALE_TASKS[0]
    assert refs[task].upper_bound is None
    res = score({"never": _never}, [task], 2, progress=False)
    assert math.isnan(res.table[0]["score"]) and res.table[0]["score_episodes"] == 0
    assert res.table[0]["iqm"] == pytest.approx(refs[task].never.values[:2].mean())
    assert "– (no bound)" in markdown_table(res.table)


def test_scale_tasks_are_scored_only_by_name(tmp_path):
    """The references hold the tasks at scale with their best decentralised rule and the
    best centralised scheduler as the reference; the default task list is the nine."""
    from netsense.benchmark.references import SCALE_TASKS, SUITE_TASKS
    from netsense.benchmark.suite import score

    refs = load_references()
    assert tuple(refs)[:len(SUITE_TASKS)] == SUITE_TASKS
    for task in SCALE_TASKS:
        ref = refs[task]
        assert ref.best_reference.startswith("oldest:")  # a centralised scheduler
        # the frontier's ordering holds on the stored episodes: the rule beats never
        assert ref.best_decentralised_returns.values.mean() > ref.never.values.mean()
    data = json.loads(REFS.read_text())
    data["tasks"] = {t: data["tasks"][t] for t in SCALE_TASKS}
    only_scale = tmp_path / "scale.json"
    only_scale.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="none of the suite's nine tasks"):
        score({"never": _never}, None, 2, references=only_scale, progress=False)


def test_stale_references_refused(tmp_path):
    from netsense.benchmark.suite import score

    data = json.loads(REFS.read_text())
    data["tasks"][TASK]["best_decentralised"]["returns"][0] += 1.0
    path = tmp_path / "refs.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="suite_references.py"):
        score({"never": _never}, [TASK], 2, references=path, progress=False)


# ----------------------------------------------------------------------------- policy file
def _core(task=TASK):
    from netsense.benchmark.protocol import frontier_overrides
    from netsense.engine.core import BatchedCore
    from netsense.env.vector import load_model

    model, _ = load_model(task, **frontier_overrides(task))
    return BatchedCore(model, 4)


def test_policy_file_round_trip(tmp_path):
    torch = pytest.importorskip("torch")
    from netsense.benchmark.mlp_policy import read_mlp_policy, write_torch_mlp

    core = _core("comm_substates-v0")  # five send bits per agent
    torch.manual_seed(0)
    F = 3
    feats = np.random.default_rng(0).random((core.N, F)).astype(np.float32)
    K = int(sum(core.nvec))
    net = torch.nn.Sequential(torch.nn.Linear(core.layout.size + F, 32), torch.nn.Tanh(),
                              torch.nn.Sequential(torch.nn.Linear(32, 16), torch.nn.ReLU()),
                              torch.nn.Linear(16, K))
    path = write_torch_mlp(tmp_path / "p", net, task="comm_substates-v0",
                           agent_features=feats, seed=7)
    assert path.suffix == ".npz"
    pol = read_mlp_policy(path)
    assert pol.header["seed"] == 7 and pol.control == "substates"
    obs, mask = core.reset(list(range(1_000_000, 1_000_004)))
    for _ in range(5):
        x = torch.cat([torch.as_tensor(obs), torch.as_tensor(feats).expand(
            *obs.shape[:2], F)], -1)
        with torch.no_grad():
            logits = net(x)
        np.testing.assert_allclose(pol.logits(obs), logits.numpy(), atol=1e-5)
        m = torch.as_tensor(np.asarray(mask, bool)).reshape(*obs.shape[:2], -1, 2)
        want = logits.reshape(*obs.shape[:2], -1, 2).masked_fill(~m, -torch.inf).argmax(-1)
        np.testing.assert_array_equal(pol.act(obs, mask), want.numpy())
        out = core.step(pol.act(obs, mask))
        obs, mask = out.obs, out.action_mask


def test_policy_file_scored_like_the_trainers_file(tmp_path):
    """A committed policy.pt converted to the format scores the same returns."""
    pytest.importorskip("torch")
    from netsense.benchmark.mlp_policy import convert_policy
    from netsense.benchmark.suite import score

    pt = (ROOT / "experiments/results/rl/learners/budget_10m/runs" / TASK / "mlp/seed_0"
          / "policy.pt")
    npz = convert_policy(pt, tmp_path / "policy.npz")
    res = score({"pt": str(pt), "npz": str(npz)}, [TASK], 2, progress=False)
    by = {r["learner"]: r for r in res.table if r["task"] == TASK}
    assert by["pt"]["iqm"] == by["npz"]["iqm"]
    ret = {r["learner"]: r["return"] for r in res.episodes if r["kind"] == "policy"}
    assert ret["pt"] == ret["npz"]


class _Evil:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


def test_policy_file_refuses_bad_files(tmp_path):
    from netsense.benchmark.mlp_policy import read_mlp_policy, write_mlp_policy

    core = _core()
    K, O = int(sum(core.nvec)), core.layout.size
    good = [(np.zeros((O, 4)), np.zeros(4), "relu"), (np.zeros((4, K)), np.zeros(K),
                                                      "identity")]
    kw = dict(task=TASK, control="transmit", obs_dim=O, nvec=core.nvec)
    write_mlp_policy(tmp_path / "ok.npz", good, **kw)
    header = str(np.load(tmp_path / "ok.npz")["header"])

    marker = tmp_path / "pwned"
    hostile = tmp_path / "hostile.npz"
    np.savez(hostile, header=np.array(header), w0=np.array([_Evil(marker)], dtype=object),
             b0=np.zeros(4), w1=np.zeros((4, K)), b1=np.zeros(K))
    with pytest.raises(ValueError, match="refused"):
        read_mlp_policy(hostile)
    assert not marker.exists()
    pickled = tmp_path / "pickle.npz"
    pickled.write_bytes(pickle.dumps(_Evil(marker)))
    with pytest.raises(ValueError, match="not an .npz"):
        read_mlp_policy(pickled)
    assert not marker.exists()

    def bad(name, match, **arrays):
        path = tmp_path / f"{name}.npz"
        np.savez(path, **arrays)
        with pytest.raises(ValueError, match=match):
            read_mlp_policy(path)

    ws = dict(w0=np.zeros((O, 4)), b0=np.zeros(4), w1=np.zeros((4, K)), b1=np.zeros(K))
    bad("noheader", "no 'header'", **ws)
    bad("format", "format", header=np.array(header.replace("netsense-mlp-policy", "x")),
        **ws)
    bad("shape", r"layers\[1\]", header=np.array(header), **{**ws, "w1": np.zeros((5, K))})
    bad("nan", "non-finite", header=np.array(header), **{**ws, "b0": np.full(4, np.nan)})
    bad("extra", "not named", header=np.array(header), extra=np.zeros(2), **ws)
    h = json.loads(header)
    h["train_seeds"] = [0, 1_000_000]
    bad("seeds", "evaluation seeds", header=np.array(json.dumps(h)), **ws)
    h = json.loads(header)
    h["layers"][0]["activation"] = "__import__('os')"
    bad("act", "activation", header=np.array(json.dumps(h)), **ws)
    with pytest.raises(ValueError, match="activation"):
        write_mlp_policy(tmp_path / "w.npz", [(np.zeros((O, K)), np.zeros(K), "gelu")], **kw)


# ----------------------------------------------------------------------------- runs folders
def test_unfinished_run_folder_refused(tmp_path):
    from netsense.benchmark.suite import score

    run = tmp_path / "runs" / TASK / "mlp" / "seed_0"
    run.mkdir(parents=True)
    (run / "config.json").write_text("{}")  # a run killed before its final policy
    with pytest.raises(ValueError, match=str(run)):
        score({"x": str(tmp_path / "runs")}, [TASK], 2, progress=False)
    with pytest.raises(ValueError, match="no task folder"):
        score({"x": str(tmp_path)}, [TASK], 2, progress=False)


def test_runs_folder_of_policy_files(tmp_path):
    from netsense.benchmark.mlp_policy import write_mlp_policy
    from netsense.benchmark.suite import runs_folder

    core = _core()
    K, O = int(sum(core.nvec)), core.layout.size
    for s in (3, 5):
        d = tmp_path / TASK / f"seed_{s}"
        d.mkdir(parents=True)
        write_mlp_policy(d / "policy.npz", [(np.zeros((O, K)), np.zeros(K), "identity")],
                         task=TASK, control="transmit", obs_dim=O, nvec=core.nvec)
    found = runs_folder(tmp_path)
    assert list(found) == [""] and [s for s, _ in found[""][TASK]] == [3, 5]


# ----------------------------------------------------------------------------- command line
def test_cli_smoke(tmp_path, capsys):
    import csv

    from netsense.cli import main

    refs = _refs_with_bound(tmp_path)
    out = tmp_path / "out"
    code = main(["suite", "score", "none=rule:never", "rule:gated(sources:0)", "--tasks", TASK,
                 "--episodes", "2", "--references", str(refs), "--out", str(out),
                 "--no-progress"])
    assert code == 0
    with (out / "table.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["task"], r["learner"]) for r in rows] == [
        (TASK, "none"), (TASK, "rule:gated(sources:0)"), ("aggregate", "none"),
        ("aggregate", "rule:gated(sources:0)")]
    never = json.loads(REFS.read_text())["tasks"][TASK]["never"]["returns"][:2]
    assert float(rows[0]["iqm"]) == pytest.approx(np.mean(never))
    assert float(rows[0]["score"]) == 0.0
    # gated(sources:0) is this task's best decentralised rule: improvement 1/2, same score
    assert rows[1]["best_decentralised"] == "gated(sources:0)"
    assert float(rows[1]["p_improvement"]) == pytest.approx(0.5)
    assert float(rows[1]["score"]) == pytest.approx(float(rows[1]["best_decentralised_score"]))
    assert (out / "figure.png").stat().st_size > 0
    assert "| comm_announced-v0 | none |" in capsys.readouterr().out
    episodes = (out / "episodes.csv").read_text().splitlines()
    assert episodes[0] == "task,learner,kind,seed,episode_seed,return"
    # rebuilt from episodes.csv without running a policy: the same table, in the order asked
    from netsense.benchmark.suite import rescore

    again = rescore(out / "episodes.csv", refs, order=["rule:gated(sources:0)"])
    assert [r["learner"] for r in again.table] == ["rule:gated(sources:0)", "none"] * 2
    assert [float(r["score"]) for r in again.table] == pytest.approx(
        [float(rows[i]["score"]) for i in (1, 0, 3, 2)])


# ----------------------------------------------------------------------------- leaderboard
def test_leaderboard_page_equals_committed_table():
    from netsense.benchmark.suite_output import leaderboard_markdown, read_table

    table = ROOT / "experiments" / "results" / "rl" / "suite_scores" / "table.csv"
    page = (ROOT / "docs" / "leaderboard.md").read_text()
    inside = page.split("<!-- suite-table:start -->\n", 1)[1].split(
        "<!-- suite-table:end -->", 1)[0]
    assert inside == leaderboard_markdown(read_table(table))


def test_docs_example_runs(tmp_path, monkeypatch):
    """docs/suite.md's Python example (export a torch MLP, score its runs folder) runs, on
    two episodes."""
    pytest.importorskip("torch")
    text = (ROOT / "docs" / "suite.md").read_text()
    code = text.split("## From Python\n\n```python\n", 1)[1].split("```", 1)[0]
    assert "episodes=100" in code
    monkeypatch.chdir(tmp_path)
    exec(compile(code.replace("episodes=100", "episodes=2"), "suite.md", "exec"), {})
    with (tmp_path / "suite_out" / "table.csv").open() as fh:
        assert fh.read().splitlines()[1].startswith("comm_announced-v0,mine,1,2,")


def test_references_script_reads_both_spellings_and_the_bounds(tmp_path):
    """experiments/rl/suite_references.py: the lookahead references under either name, the
    best one by mean; upper bounds per task and seed; a bounds file without its columns
    refused."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "suite_references", ROOT / "experiments" / "rl" / "suite_references.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    eps = tmp_path / "episodes.csv"
    eps.write_text("scenario,policy,episode,seed,reward\n"
                   f"{TASK},reference:causal,0,1000000,-10\n"
                   f"{TASK},reference:causal,1,1000001,-12\n"
                   f"{TASK},bound:clairvoyant,0,1000000,-9\n"
                   f"{TASK},event:2,0,1000000,-5\n"
                   "comm_fading-v0,reference:causal,0,1000000,-1\n")
    refs = mod.reference_episodes(TASK, eps)
    assert refs == {"reference:causal": {1000000: -10.0, 1000001: -12.0},
                    "bound:clairvoyant": {1000000: -9.0}}
    ub = tmp_path / "ub.csv"
    ub.write_text("scenario,seed,upper_bound,solver\n"
                  f"{TASK},1000001,-3.5,x\n{TASK},1000000,-2,x\n")
    assert mod.upper_bounds(ub) == {TASK: {1000001: -3.5, 1000000: -2.0}}
    assert mod.upper_bounds(tmp_path / "missing.csv") == {}
    ub.write_text("scenario,seed,bound\n")
    with pytest.raises(ValueError, match="upper_bound"):
        mod.upper_bounds(ub)


def _script(name: str):
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, ROOT / "experiments" / "rl" /
                                                  f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_experiment_scripts_smoke(tmp_path, monkeypatch):
    """suite_references.py and suite_scores.py at smoke size: references of two episodes
    that the suite loads; scores of one task; the page's tables rewritten from the CSV."""
    from netsense.benchmark.suite_output import leaderboard_markdown, read_table

    refs = tmp_path / "refs.json"
    assert _script("suite_references").main(["--out", str(refs), "--episodes", "2"]) == 0
    assert load_references(refs)[TASK].never.values.shape == (2,)
    mod = _script("suite_scores")
    monkeypatch.setattr(mod, "LEARNERS", {"10M": mod.LEARNERS["mlp, 10M agent-steps"]})
    rules = mod.family_rules([TASK])
    import csv

    with (mod.FRONTIERS / f"frontier_{TASK}.csv").open() as fh:
        event = [r for r in csv.DictReader(fh) if r["family"] == "event"]
    best = max(event, key=lambda r: float(r["reward_mean"]))["policy"]
    assert rules["event (decentralised)"] == {TASK: f"rule:{best}"}
    keep = ("event (decentralised)", "oldest (centralised)")
    monkeypatch.setattr(mod, "family_rules", lambda tasks: {k: rules[k] for k in keep})
    page = tmp_path / "page.md"
    page.write_text(f"intro\n{mod.START}\nold\n{mod.END}\noutro\n")
    out = tmp_path / "out"
    args = ["--tasks", TASK, "--episodes", "2", "--out", str(out), "--page", str(page),
            "--no-progress"]
    assert mod.main(["score", *args]) == 0
    table = read_table(out / "table.csv")
    assert table[0]["learner"] == "10M" and table[0]["seeds"] == 5
    assert {"event (decentralised)", "oldest (centralised)"} <= {r["learner"] for r in table}
    assert page.read_text() == (f"intro\n{mod.START}\n{leaderboard_markdown(table)}"
                                f"{mod.END}\noutro\n")
    assert mod.main(["summary", *args]) == 0
    assert read_table(out / "table.csv") == table
