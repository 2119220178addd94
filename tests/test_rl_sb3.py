"""SB3 + SuperSuit + MaskablePPO: masks reach the learner, and a short train-then-benchmark
run gives a finite error without a single masked action."""

import numpy as np
import pytest

pytest.importorskip("sb3_contrib")
pytest.importorskip("supersuit")

import gymnasium  # noqa: E402
from pettingzoo.utils.env import ParallelEnv  # noqa: E402

from netsense import benchmark as bm  # noqa: E402
from netsense.cli import main  # noqa: E402
from netsense.env.registry import make  # noqa: E402
from netsense.rl.sb3 import LearnedPolicy, TrainConfig, make_vec_env, train  # noqa: E402
from netsense.rl.wrappers import MaskedFlatObs, flat_mask, mask_allows  # noqa: E402


class ToyMaskedEnv(ParallelEnv):
    """Two agents; choice 2 of the first action entry pays 1 but is masked on odd steps.

    Stepping a masked action raises, so a run that finishes never took one.
    """

    metadata = {"name": "toy_masked_v0", "render_modes": []}
    render_mode = None

    def __init__(self, horizon: int = 6) -> None:
        self.possible_agents = ["sensor_0", "sensor_1"]
        self.agents = []
        self.horizon = horizon
        self._obs = gymnasium.spaces.Dict({
            "observation": gymnasium.spaces.Box(-1, 1, (2,), np.float32),
            "action_mask": gymnasium.spaces.MultiBinary(5)})
        self._act = gymnasium.spaces.MultiDiscrete([3, 2])

    def observation_space(self, agent):
        return self._obs

    def action_space(self, agent):
        return self._act

    def _mask(self):
        m = np.ones(5, np.int8)
        m[2] = self.k % 2 == 0
        return m

    def _observe(self):
        o = np.array([self.k / self.horizon, self.k % 2], np.float32)
        return {a: {"observation": o, "action_mask": self._mask()} for a in self.agents}

    def reset(self, seed=None, options=None):
        self.agents, self.k = list(self.possible_agents), 0
        return self._observe(), {a: {} for a in self.agents}

    def step(self, actions):
        mask = self._mask()
        for a, act in actions.items():
            if not mask[act[0]]:
                raise ValueError(f"masked action {act} of {a} at step {self.k}")
        rew = {a: float(act[0] == 2) for a, act in actions.items()}
        self.k += 1
        done = self.k >= self.horizon
        obs = self._observe()
        self.agents = [] if done else self.agents
        return (obs, rew, dict.fromkeys(rew, False), dict.fromkeys(rew, done),
                {a: {} for a in rew})


def test_flat_mask_forms_and_mask_allows():
    nvec = np.array([3, 2])
    flat = np.array([1, 0, 1, 1, 0], bool)
    np.testing.assert_array_equal(flat_mask(flat, nvec), flat)
    np.testing.assert_array_equal(flat_mask([[1, 0, 1], [1, 0]], nvec), flat)
    np.testing.assert_array_equal(flat_mask(np.array([[1, 0, 1], [1, 0, 9]]), nvec), flat)
    with pytest.raises(ValueError, match="action mask"):
        flat_mask(np.ones(4), nvec)
    assert mask_allows(flat, [2, 0], nvec) and not mask_allows(flat, [1, 0], nvec)
    assert not mask_allows(flat, [0, 1], nvec) and not mask_allows(flat, [3, 0], nvec)


def test_vec_env_serves_masks_from_observations():
    venv = make_vec_env(env_fn=ToyMaskedEnv, num_vec_envs=2, seed=0)
    obs = venv.reset()
    assert obs.shape == (4, 2 + 5) and venv.num_envs == 4
    masks = np.stack(venv.env_method("action_masks"))
    np.testing.assert_array_equal(masks, np.tile([1, 1, 1, 1, 1], (4, 1)).astype(bool))
    venv.step(np.zeros((4, 2), int))
    assert not np.stack(venv.env_method("action_masks"))[:, 2].any()  # odd step: masked
    assert venv.has_attr("action_masks")


def test_maskable_ppo_learns_the_masked_toy_and_never_breaks_a_mask(tmp_path):
    res = train(TrainConfig("toy", steps=2048, n_steps=32, batch_size=64, num_vec_envs=2,
                            learning_rate=3e-3), tmp_path, env_fn=ToyMaskedEnv,
                progress=False)
    assert res.mask_violations == 0 and res.actions_checked >= 2048
    assert (tmp_path / "policy.zip").exists() and (tmp_path / "training_curve.png").exists()
    # best return is 3 (choice 2 on the three even steps); random play gets ~1
    assert res.curve[-1]["mean_episode_reward"] > res.curve[0]["mean_episode_reward"]


def test_torch_threads_are_set_only_when_given(tmp_path):
    """``TrainConfig.torch_threads`` goes to ``torch.set_num_threads`` (one by default);
    ``None`` leaves the process's setting as it was."""
    import torch

    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        small = {"steps": 64, "n_steps": 32, "batch_size": 64, "num_vec_envs": 2}
        train(TrainConfig("toy", torch_threads=None, **small), tmp_path / "a",
              env_fn=ToyMaskedEnv, progress=False)
        assert torch.get_num_threads() == 2
        train(TrainConfig("toy", **small), tmp_path / "b", env_fn=ToyMaskedEnv,
              progress=False)
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


def test_train_then_benchmark_fig1(tmp_path):
    out = tmp_path / "run"
    assert main(["train", "fig1_scalar-v0", "--backend", "sb3", "--steps", "1500",
                 "--out", str(out),
                 "--n-steps", "64", "--batch-size", "64", "--num-envs", "2",
                 "--override", "horizon=12", "--no-progress"]) == 0
    rows = (out / "training_curve.csv").read_text().strip().splitlines()
    assert rows[0] == "timesteps,episodes,mean_episode_reward,wall_s" and len(rows) > 1
    policy = out / "policy.zip"
    # masks respected at inference: the env raises on a masked action, and we check each
    env = make("fig1_scalar-v0", horizon=12)
    wrapped, learned = MaskedFlatObs(env), LearnedPolicy(policy)
    obs, _ = wrapped.reset(seed=5)
    steps = 0
    while env.agents:
        acts = learned.act(obs, wrapped)
        for a, act in acts.items():
            assert mask_allows(wrapped.last_masks[a], act, wrapped.nvec)
        obs, *_ = wrapped.step(acts)
        steps += 1
    assert steps == 12
    results, rows = bm.run_benchmark(["fig1_scalar-v0"], ["learned:" + str(policy),
                                                          "freshness"], [0, 1],
                                     overrides={"horizon": 12}, backend="serial",
                                     progress=False)
    learned_row = next(r for r in rows if r["policy"] == "learned")
    assert np.isfinite(learned_row["mean_rel_error_mean"])
    assert np.isfinite(learned_row["final_rel_error_mean"])
    assert 0.0 <= learned_row["msgs_per_agent_step_mean"] <= 1.0
    # the batched backend: learned jobs fall back to per-episode runs, freshness batches
    batched, _ = bm.run_benchmark(["fig1_scalar-v0"], ["learned:" + str(policy), "freshness"],
                                  [0, 1], overrides={"horizon": 12}, progress=False)
    assert [r["job"] for r in batched] == [r["job"] for r in results]
    for a, b in zip(batched, results, strict=True):
        np.testing.assert_allclose(a["curve"], b["curve"], rtol=1e-12, atol=1e-12)
        assert a["metrics"]["msgs_per_agent_step"] == b["metrics"]["msgs_per_agent_step"]


def test_learned_policy_path_must_exist(tmp_path):
    with pytest.raises(ValueError, match="no learned policy"):
        LearnedPolicy(tmp_path / "missing.zip")
