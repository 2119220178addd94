"""The RL experiment configs agree with the code, and the scripts run at smoke size."""

import inspect
from pathlib import Path

import pytest
from experiment_loader import load_experiment

ROOT = Path(__file__).resolve().parents[1]
EXP = ROOT / "experiments"


_load = load_experiment


def test_rllib_config_keys_are_ppo_config_arguments():
    cfg = _load("rl/rllib_example").load_config()
    from netsense.rl import rllib

    params = set(inspect.signature(rllib.ppo_config).parameters)
    assert set(cfg) - {"iterations"} <= params
    from netsense.env.registry import list_scenarios

    assert cfg["scenario"] in list_scenarios()


def test_train_config_covers_the_benchmark_scenarios():
    pytest.importorskip("sb3_contrib")
    configs = _load("rl/train_maskable_ppo").load_configs()
    bench = _load("rl/benchmark_maskable_ppo")
    assert set(configs) == set(bench.SCENARIOS)
    for scenario, cfg in configs.items():
        assert cfg.scenario == scenario
        assert cfg.overrides["reward"]["team_weight"] == 1.0
    # v1 trains on cost / N (see the config's comment); the others on the scenario's cost
    assert configs["message_cost-v1"].overrides["reward"]["message_cost"] == 0.01


def test_train_and_benchmark_scripts_smoke(tmp_path):
    pytest.importorskip("sb3_contrib")
    pytest.importorskip("supersuit")
    train = _load("rl/train_maskable_ppo")
    assert train.main(["--smoke", "--only", "fig1_scalar-v0", "--out", str(tmp_path),
                       "--no-progress"]) == 0
    assert (tmp_path / "fig1_scalar-v0" / "policy.zip").exists()
    bench = _load("rl/benchmark_maskable_ppo")
    out = tmp_path / "bench"
    assert bench.main(["--seeds", "1", "--scenarios", "fig1_scalar-v0", "--train-dir",
                       str(tmp_path), "--out", str(out), "--backend", "serial",
                       "--override", "horizon=8", "--no-progress"]) == 0
    table = (out / "summary.md").read_text()
    assert "| fig1_scalar-v0 | learned |" in table and "| fig1_scalar-v0 | kf_oracle |" in table


@pytest.mark.parametrize("scenario", ["fig1_scalar-v0", "random_structured_n20_N10-v0",
                                      "message_cost-v0", "message_cost-v1"])
def test_committed_policies_still_fit_their_scenarios(scenario):
    """The committed policies act in the current env (else retrain: the layout changed)."""
    pytest.importorskip("sb3_contrib")
    import numpy as np

    from netsense.benchmark import rollout
    from netsense.env.registry import make
    from netsense.rl.sb3 import LearnedPolicy
    from netsense.rl.wrappers import MaskedFlatObs

    path = EXP / "results" / "rl" / "train_maskable_ppo" / scenario / "policy.zip"
    space = MaskedFlatObs(make(scenario)).observation_space("sensor_0")
    assert LearnedPolicy(path).model.observation_space.shape == space.shape
    rec = rollout(scenario, f"learned:{path}", 1000, {"horizon": 10})
    assert np.all(np.isfinite(rec.errors))
