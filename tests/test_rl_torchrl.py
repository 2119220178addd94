"""TorchRL's PettingZooWrapper (the path BenchMARL uses) loads and steps the env."""

import pytest

pytest.importorskip("torchrl")
torch = pytest.importorskip("torch")


def test_torchrl_random_masked_rollout():
    from netsense.rl.torchrl import make_torchrl_env

    env = make_torchrl_env("random_structured_n20_N10-v0", horizon=15, seed=0)
    assert list(env.group_map) == ["sensor"] and len(env.group_map["sensor"]) == 10
    torch.manual_seed(0)
    # random actions drawn from the masked spec; the env raises on a masked action
    td = env.rollout(15)
    assert td["sensor", "action"].shape == (15, 10, 11)
    assert td["next", "sensor", "reward"].shape == (15, 10, 1)
    assert bool(td["next", "done"][-1])
    assert torch.isfinite(td["next", "sensor", "reward"]).all()


@pytest.mark.parametrize("sid,width", [("comm_channel_k2-v0", 1), ("comm_substates-v0", 5)])
def test_torchrl_communication_modes(sid, width):
    """Transmit bits and per-substate bits (whose mask TorchRL takes as (M, 2)); the env
    raises on a masked bit, so a finished rollout took none."""
    from netsense.rl.torchrl import make_torchrl_env

    env = make_torchrl_env(sid, horizon=12, seed=0)
    torch.manual_seed(0)
    td = env.rollout(12)
    assert td["sensor", "action"].shape == (12, 10, width)
    assert bool(td["next", "done"][-1])
    assert torch.isfinite(td["next", "sensor", "reward"]).all()
