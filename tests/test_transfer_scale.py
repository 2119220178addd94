"""Transfer across N (experiments/rl/transfer_scale.py): the set actor's parameters do not
depend on N, a policy file trained at N = 50 acts with valid masked actions at N = 10 and
N = 200, and the transfer table's statistics on returns whose answers are known."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("rliable")

ROOT = Path(__file__).resolve().parents[1]
#: a committed policy of the experiment (seed 0, trained at N = 50)
POLICY = (ROOT / "experiments" / "results" / "rl" / "transfer_scale" / "runs" / "seed_0"
          / "policy.pt")


@pytest.fixture(scope="module")
def transfer():
    spec = importlib.util.spec_from_file_location(
        "transfer_scale", ROOT / "experiments" / "rl" / "transfer_scale.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["transfer_scale"] = mod
    spec.loader.exec_module(mod)
    return mod


def test_set_actor_has_the_same_parameter_shapes_at_every_N(transfer) -> None:
    from netsense.rl.envs import make_core
    from netsense.rl.policy import actor_net

    config = transfer.ppo_config(0, transfer.STEPS)
    shapes = {}
    for task in ("comm_channel_k2-v0", transfer.TRAIN_TASK, "comm_channel_kofn_n1000-v0"):
        core = make_core(task, 1)
        net = actor_net(config, core, torch.device("cpu"))
        shapes[core.N] = {k: tuple(v.shape) for k, v in net.state_dict().items()}
    assert sorted(shapes) == [10, 50, 1000]
    assert shapes[10] == shapes[50] == shapes[1000]


@pytest.mark.parametrize("task", ["comm_channel_k2-v0", "comm_channel_kofn_n200-v0"])
def test_policy_trained_at_n50_acts_with_valid_actions(task: str) -> None:
    from netsense.rl.checkpoint import load_policy, read_policy
    from netsense.rl.envs import make_core

    state = read_policy(POLICY)
    assert state["trained_on"]["N"] == 50
    assert state["config"]["network"] == "set"
    core = make_core(task, 2)
    assert core.N != 50
    policy = load_policy(POLICY, core)
    obs, mask = core.reset([1_000_000, 1_000_001])
    for _ in range(3):
        act = policy.act(obs, mask)
        assert act.shape == (2, core.N, len(core.nvec))
        offsets = np.concatenate([[0], np.cumsum(core.nvec)[:-1]])
        chosen = np.take_along_axis(np.asarray(mask), act + offsets, axis=-1)
        assert (chosen > 0).all()  # every chosen action is allowed by the mask
        out = core.step(act)
        obs, mask = out.obs, out.action_mask


def test_transfer_table_statistics(transfer) -> None:
    rng = np.random.default_rng(0)
    rows = []
    for N, shift in ((10, 5.0), (50, -5.0)):
        for kind, mean, seeds in (("rule", -100.0, [""]), ("never", -190.0, [""]),
                                  ("learned", -100.0 + shift, [0, 1])):
            for s in seeds:
                for e, v in enumerate(mean + rng.normal(0, 0.1, 20)):
                    rows.append({"N": N, "task": f"t{N}", "kind": kind,
                                 "policy": "periodic:5" if kind == "rule" else kind,
                                 "seed": s, "episode_seed": e, "reward": float(v),
                                 "msgs_per_agent_step": 0.2, "mean_rel_error": 0.5})
    table, per_seed = transfer.transfer_table(rows, reps=200)
    by_n = {r["N"]: r for r in table}
    assert by_n[10]["p_learned_beats_rule"] == 1.0  # learned 5 above the rule everywhere
    assert by_n[50]["p_learned_beats_rule"] == 0.0
    assert by_n[10]["learned_ci_low"] <= by_n[10]["learned_iqm"] <= by_n[10]["learned_ci_high"]
    assert abs(by_n[50]["never_iqm"] + 190.0) < 0.1
    assert (by_n[10]["seeds"], by_n[10]["episodes"]) == (2, 20)
    assert len(per_seed) == 4
    assert "| 10 | `t10` | 2 x 20 |" in transfer.markdown(table, 1000)


def test_suite_scores_the_policy_at_n50_without_a_bound(transfer, tmp_path) -> None:
    """The suite scores the N = 50 policies on the training task by name: its IQM is the
    policy's own return on the same episodes, next to the rule of the suite's references,
    and no normalised score (no bound at this size)."""
    import math

    from netsense.benchmark.protocol import eval_seeds, evaluate, frontier_overrides
    from netsense.benchmark.references import load_references

    res = transfer.write_suite(tmp_path, {0: POLICY}, episodes=2, progress=False)
    row = next(r for r in res.table if r["task"] == transfer.TRAIN_TASK)
    ref = load_references()[transfer.TRAIN_TASK]
    assert row["best_decentralised"] == ref.best_decentralised
    assert math.isnan(row["score"])
    own = evaluate(transfer.TRAIN_TASK, f"learned:{POLICY}", eval_seeds(2),
                   frontier_overrides(transfer.TRAIN_TASK))["reward"]
    assert row["iqm"] == pytest.approx(np.mean(own))  # 2 episodes: the IQM trims none
    assert (tmp_path / "suite" / "table.csv").exists()
