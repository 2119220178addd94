"""RLlib scale-out path: one PPO iteration, shared masked policy, local Ray instance."""

import pytest

ray = pytest.importorskip("ray")
pytest.importorskip("ray.rllib")


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray instance (one CPU) for the module: starting Ray takes seconds."""
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False,
             ignore_reinit_error=True)
    yield
    ray.shutdown()


def test_rllib_one_iteration_with_shared_masked_policy(local_ray):
    from netsense.rl.rllib import POLICY_ID, ppo_config, train

    cfg = ppo_config("fig1_scalar-v0", overrides={"horizon": 10}, train_batch_size=120,
                     minibatch_size=60, num_epochs=1)
    assert set(cfg.policies) == {POLICY_ID}
    assert cfg.policy_mapping_fn("sensor_2", None) == POLICY_ID
    # the env raises on a masked action, so a finished iteration never sampled one
    out = train(cfg, iterations=1)
    assert out[0]["env_steps"] >= 120
    assert out[0]["episode_return_mean"] is not None


def test_rllib_observation_keys_match_the_masking_module():
    from netsense.env.registry import make
    from netsense.rl.rllib import RLlibMaskedObs

    env = RLlibMaskedObs(make("fig1_scalar-v0"))
    obs, _ = env.reset(seed=0)
    space = env.observation_space("sensor_0")
    assert set(space.spaces) == {"observations", "action_mask"}
    assert all(space.contains(o) for o in obs.values())


def test_benchmark_ray_backend_matches_serial(local_ray):
    import numpy as np

    from netsense import benchmark as bm

    jobs = bm.make_jobs(["fig1_scalar-v0"], ["freshness", "random"], [0, 1],
                        overrides={"horizon": 10})
    serial = bm.execute(jobs, backend="serial", progress=False)
    remote = bm.execute(jobs, backend="ray", progress=False)
    for a, b in zip(serial, remote, strict=True):
        assert a["job"] == b["job"]
        np.testing.assert_equal(a["metrics"], b["metrics"])
