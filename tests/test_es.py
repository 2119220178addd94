"""The evolution-strategy trainer (netsense.rl.es): candidates are scored exactly as the
protocol scores their greedy policy, on common training episodes drawn from the run's own
training seeds, and a run folder reads like one of the PPO trainer."""

import csv
import json
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("torchrl")
pytest.importorskip("cma")

import torch  # noqa: E402

from netsense.benchmark.protocol import eval_seeds, evaluate  # noqa: E402
from netsense.rl import es as es_mod  # noqa: E402
from netsense.rl.checkpoint import (  # noqa: E402
    load_policy,
    policy_config,
    policy_state,
    read_policy,
    write_policy,
)
from netsense.rl.config import PPOConfig, training_seeds  # noqa: E402
from netsense.rl.envs import make_core  # noqa: E402
from netsense.rl.es import ESConfig, greedy_returns, train_es  # noqa: E402
from netsense.rl.policy import actor_net  # noqa: E402

TASK = "comm_fading-v0"


def _config(**kw) -> PPOConfig:
    base = dict(scenario=TASK, seed=1, hidden=(4,), ages=(1, 4), clock=(2, 3),
                num_envs=8, steps=1, eval_interval=1, eval_envs=2, torch_threads=1)
    return PPOConfig(**{**base, **kw})


def _population(config: PPOConfig, P: int, E: int):
    core = make_core(TASK, P * E)
    return es_mod._Population(actor_net(config, core, torch.device("cpu")), P), core


def test_a_candidate_scores_what_the_protocol_scores_its_policy_file(tmp_path):
    """The return greedy_returns gives each candidate equals the protocol's greedy
    evaluation of a policy file holding those weights, episode seeds alike (the trainer
    optimises what the tables report)."""
    config = _config()
    seeds = np.asarray(eval_seeds(3))
    pop, core = _population(config, 2, len(seeds))
    weights = np.random.default_rng(0).normal(0.0, 0.7, (2, pop.dim))
    returns, sends = greedy_returns(pop, core, weights, seeds)
    assert 0.0 < sends < 1.0
    for p in range(2):
        path = tmp_path / f"cand{p}.pt"
        write_policy(path, policy_state(config, pop.load(weights[p]), 0, 0, core))
        m = evaluate(TASK, f"learned:{path}", seeds)
        assert returns[p] == pytest.approx(m["reward"].mean(), rel=1e-9, abs=1e-9)
    assert returns[0] != pytest.approx(returns[1])  # the weights matter


def test_candidates_play_the_same_episodes():
    """Common random numbers: the same weights twice in one generation score the same."""
    config = _config()
    pop, core = _population(config, 3, 2)
    w = np.zeros((2, pop.dim))
    w[0, -2:], w[1, -2:] = (-5.0, 5.0), (5.0, -5.0)  # the output bias: always, never send
    returns, sends = greedy_returns(pop, core, np.stack([w[0], w[1], w[0]]), np.array([3, 5]))
    assert returns[0] == returns[2]
    assert returns[0] != returns[1]
    assert sends == pytest.approx(2 / 3)


def test_greedy_returns_refuses_a_core_of_the_wrong_size():
    pop, core = _population(_config(), 2, 2)
    with pytest.raises(ValueError, match="members"):
        greedy_returns(pop, core, np.zeros((2, pop.dim)), np.array([1, 2, 3]))


def test_a_run_folder(tmp_path, monkeypatch):
    """Two generations: the log, checkpoints at the evaluation interval, a policy file
    with the trainer's record and no critic, agent-steps counted from the population, and
    every training episode drawn from the run's own training seeds."""
    config = _config(steps=2 * 3 * 2 * 10 * 200)  # popsize x episodes x N x H, twice
    es = ESConfig(popsize=3, episodes=2, sigma=0.3)
    drawn = []
    real = es_mod.greedy_returns

    def spy(pop, core, weights, seeds):
        drawn.extend(int(s) for s in seeds)
        return real(pop, core, weights, seeds)

    monkeypatch.setattr(es_mod, "greedy_returns", spy)
    summary = train_es(config, es, tmp_path, progress=False)
    assert summary["generations"] == 2 and summary["agent_steps"] == config.steps
    assert set(drawn) <= set(training_seeds(config))
    assert len(drawn) == 4 and len(set(drawn[:2])) == 2  # without replacement in a generation
    with (tmp_path / "log.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["agent_steps"]) for r in rows] == [12000, 24000]
    assert all(r["eval_return"] for r in rows)  # eval_interval 1
    assert (tmp_path / "checkpoint_00001.pt").exists()
    state = read_policy(tmp_path / "policy.pt")
    assert "critic" not in state
    assert state["trainer"]["algorithm"] == "sep-cma-es" and state["trainer"]["popsize"] == 3
    assert json.loads((tmp_path / "run.json").read_text())["status"] == "finished"
    # config.json is the actor's PPOConfig, as a PPO run folder's (read back the same way)
    stored = policy_config({"config": json.loads((tmp_path / "config.json").read_text())})
    assert stored == config
    assert json.loads((tmp_path / "summary.json").read_text())["es"]["popsize"] == 3
    with pytest.raises(ValueError, match="already holds a training run"):
        train_es(config, es, tmp_path, progress=False)
    # the policy file plays on the protocol's episodes
    m = evaluate(TASK, f"learned:{tmp_path / 'policy.pt'}", eval_seeds(2))
    assert np.isfinite(m["reward"]).all()


@pytest.mark.parametrize("kw, match", [
    (dict(popsize=2), "popsize"), (dict(popsize=4.0), "popsize"),
    (dict(episodes=0), "episodes"), (dict(sigma=0.0), "sigma"),
    (dict(sigma=float("nan")), "sigma")])
def test_es_config_refuses(kw, match):
    with pytest.raises(ValueError, match=match):
        ESConfig(**kw)


def test_train_es_refuses_before_writing(tmp_path):
    with pytest.raises(ValueError, match="recurrent"):
        train_es(_config(memory=8), ESConfig(), tmp_path / "a", progress=False)
    with pytest.raises(ValueError, match="num_envs"):
        train_es(_config(num_envs=8), ESConfig(episodes=9), tmp_path / "b", progress=False)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_learner_tables_name_the_algorithm():
    """experiments/rl/learners.py: an ES learner's keys build an ESConfig and stay out of
    the actor's PPOConfig; an unknown algorithm, or ES keys on a PPO learner, are refused."""
    from experiment_loader import load_experiment

    learners = load_experiment("rl/learners")
    fields = {"algorithm": "es", "popsize": 4, "episodes": 2, "hidden": [8], "steps": 10}
    assert learners.es_config(fields) == ESConfig(popsize=4, episodes=2)
    assert learners.ppo_config(TASK, 0, fields).hidden == (8,)
    assert learners.es_config({"hidden": [8]}) is None
    with pytest.raises(ValueError, match="algorithm"):
        learners.es_config({"algorithm": "sgd"})
    with pytest.raises(ValueError, match="popsize"):
        learners.es_config({"popsize": 4})


def test_a_warm_start_begins_the_search_at_the_clone(tmp_path, monkeypatch):
    """With PPOConfig.bc the search starts from the cloned weights (here a stand-in clone
    that sets every weight to 0.125), not from zero."""
    import netsense.rl.cloning as cloning

    def fake_clone(net, config, scripted, **kw):
        assert scripted == "acked(sources:0)"
        with torch.no_grad():
            for p in net.parameters():
                p.fill_(0.125)
        return {"accuracy": 1.0}

    monkeypatch.setattr(cloning, "behaviour_clone", fake_clone)
    config = _config(steps=4 * 2 * 10 * 200, bc="acked(sources:0)")
    summary = train_es(config, ESConfig(popsize=4, episodes=2, sigma=1e-9), tmp_path,
                       progress=False)
    assert summary["bc"] == {"accuracy": 1.0}
    net = load_policy(tmp_path / "policy.pt").net
    weights = torch.nn.utils.parameters_to_vector(net.parameters())
    assert torch.allclose(weights, torch.tensor(0.125), atol=1e-6)


def test_a_run_continues_another_from_its_policy_file(tmp_path):
    """``ESConfig.init``: the search starts from the weights of a policy file (``{seed}``
    replaced), and its agent-steps count first in the log; a file of another actor, a
    missing file, and init with a warm start are refused before anything is written."""
    config = _config(steps=3 * 2 * 10 * 200)
    core = make_core(TASK, 1)
    net = actor_net(config, core, torch.device("cpu"))
    with torch.no_grad():
        for p in net.parameters():
            p.fill_(0.25)
    write_policy(tmp_path / "start_1.pt", policy_state(config, net, 9, 5000, core))
    es = ESConfig(popsize=3, episodes=2, sigma=1e-9, init=str(tmp_path / "start_{seed}.pt"))
    summary = train_es(config, es, tmp_path / "run", progress=False)
    assert summary["init_agent_steps"] == 5000
    assert summary["agent_steps"] == 5000 + config.steps
    weights = torch.nn.utils.parameters_to_vector(
        load_policy(tmp_path / "run" / "policy.pt").net.parameters())
    assert torch.allclose(weights, torch.tensor(0.25), atol=1e-6)
    other = _config(hidden=(8,))
    with pytest.raises(ValueError, match="another actor"):
        train_es(other, es, tmp_path / "a", progress=False)
    with pytest.raises(ValueError, match="no policy file"):
        train_es(_config(seed=2), es, tmp_path / "b", progress=False)
    with pytest.raises(ValueError, match="give one"):
        train_es(_config(bc="acked(sources:0)"), es, tmp_path / "c", progress=False)
    assert not any((tmp_path / d).exists() for d in "abc")


def test_launch_trains_es_runs_as_train_es_does(tmp_path):
    """An ES run through the launcher (in this process and in worker processes) writes
    the weights a direct ``train_es`` call writes, and a summary entry with its budget; an
    unfinished ES run of a resumed launch starts again and ends at the same weights."""
    from netsense.rl.launch import Run, launch, make_runs

    config = _config(steps=3 * 2 * 10 * 200)  # one generation
    es = ESConfig(popsize=3, episodes=2, sigma=0.3)
    train_es(replace(config, seed=0), es, tmp_path / "direct", progress=False)
    want = read_policy(tmp_path / "direct" / "policy.pt")["actor"]
    runs = make_runs({"es": config}, [0, 1], es=es)
    assert all(r.es == es for r in runs)
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        entries = launch(runs, out, workers=workers, progress=False)
        assert [e["status"] for e in entries] == ["ok", "ok"]
        assert entries[0]["agent_steps"] == config.steps and entries[0]["eval_return"] < 0
        got = read_policy(out / "es" / "seed_0" / "policy.pt")
        assert got["trainer"]["algorithm"] == "sep-cma-es"
        for k, v in want.items():
            assert torch.equal(got["actor"][k], v), k
    # interrupted: the run's folder says running, its policy is stale
    folder = tmp_path / "w1" / "es" / "seed_0"
    (folder / "policy.pt").write_bytes(b"stale")
    (folder / "run.json").write_text(json.dumps({"status": "running"}))
    entries = launch(runs, tmp_path / "w1", resume=True, progress=False)
    assert [e["status"] for e in entries] == ["ok", "ok"]
    got = read_policy(folder / "policy.pt")["actor"]
    assert all(torch.equal(got[k], v) for k, v in want.items())
    with pytest.raises(TypeError, match="Run.es"):
        Run(config, "es", es={"popsize": 3})
