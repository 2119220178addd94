"""docs/scale.md's sweep over N: the list it builds, and that list (shrunk) trained through
the launcher, with actors whose parameter shapes do not depend on N."""

from dataclasses import replace
from pathlib import Path

import pytest

pytest.importorskip("torchrl")

ROOT = Path(__file__).resolve().parents[1]


def _sweep_runs():
    text = (ROOT / "docs" / "scale.md").read_text()
    section = text.split("## Many runs, or a sweep over N, on a cluster")[1]
    block = section.split("```python\n")[1].split("```")[0]
    ns = {"__name__": "docs_example"}  # not __main__: builds the runs, launches nothing
    exec(compile(block, "docs/scale.md", "exec"), ns)
    return ns["runs"]


def test_the_sweep_is_every_size_times_five_seeds():
    runs = _sweep_runs()
    assert len(runs) == 15
    assert [r.folder for r in runs[:2]] == ["n50/seed_0", "n50/seed_1"]
    assert {r.config.scenario for r in runs} == {
        f"comm_channel_kofn_n{n}-v0" for n in (50, 200, 1000)}
    assert all(r.config.network == "set" and r.config.algo == "ippo" for r in runs)


def test_the_sweep_trains_at_every_size_with_one_actor_shape(tmp_path):
    """One run per size, shrunk to one short iteration: each trains, and the actors
    trained at N = 50, 200 and 1,000 hold the same parameters by name and shape, so any
    of them acts at any size."""
    import torch

    from netsense.rl.launch import launch

    runs = [r for r in _sweep_runs() if r.config.seed == 0]
    small = [replace(r, config=replace(r.config, steps=1, num_envs=2, rollout=4,
                                       minibatch=8, eval_envs=1, eval_interval=1,
                                       overrides={"horizon": 8}))
             for r in runs]
    summary = launch(small, tmp_path, progress=False)
    assert [e["status"] for e in summary] == ["ok"] * 3, summary
    shapes = []
    for r in small:
        actor = torch.load(tmp_path / r.folder / "policy.pt", weights_only=True)["actor"]
        shapes.append({k: tuple(v.shape) for k, v in actor.items()})
    assert shapes[0] == shapes[1] == shapes[2]
