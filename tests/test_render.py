"""Rendering: the ansi table reports the state it claims to, the image is a real image."""

from __future__ import annotations

import numpy as np

from netsense.env.policies import make_policy
from netsense.env.registry import make


def _run(env, steps):
    pol = make_policy("freshness", env)
    obs, infos = env.reset(seed=0)
    for _ in range(steps):
        obs, *_, infos = env.step(pol.act_dict(env, obs, infos))


def test_ansi_table_lists_agents_errors_and_neighbours():
    env = make("fig1_scalar-v0", render_mode="ansi")
    _run(env, 3)
    text = env.render()
    lines = text.splitlines()
    assert "k = 3/30" in lines[0] and "messages = 9" in lines[0]
    rows = [ln.split() for ln in lines[2:]]
    assert [r[0] for r in rows] == ["sensor_0", "sensor_1", "sensor_2"]
    # G[3] is graph (b): 0 -> 2, 2 -> 1, 2 -> 0 (fig1_graphs); neighbours listed per row
    assert text.splitlines()[2].endswith("[2]") and text.splitlines()[4].endswith("[0]")
    # deadbeat freshness: every error is 0 after 3 steps, every index finite
    assert all(float(r[1]) == 0.0 for r in rows) and all(r[2] == "3/3" for r in rows)


def test_ansi_summarises_large_networks():
    env = make("large_n20_N100-v0", render_mode="ansi", horizon=3)
    _run(env, 1)
    text = env.render()
    assert "90 more agents" in text and len(text.splitlines()) == 13


def test_rgb_array_is_an_image_that_changes_with_the_state():
    env = make("fig1_scalar-v0", render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    _run(env, 4)
    later = env.render()
    assert first.dtype == np.uint8 and first.ndim == 3 and first.shape[2] == 3
    assert first.shape == later.shape and not np.array_equal(first, later)
    assert later.std() > 5  # not a blank canvas
    env.close()


def test_render_without_mode_returns_none():
    env = make("fig1_scalar-v0")
    env.reset(seed=0)
    assert env.render() is None


def test_ansi_marks_faulty_agents_and_leaves_them_out_of_the_mean():
    env = make("fault_crash-v0", render_mode="ansi", horizon=5)
    _run(env, 3)
    lines = env.render().splitlines()
    assert "faulty" in lines[0]
    names = [ln.split()[0] for ln in lines[2:]]
    assert names[4] == "sensor_4*" and sum(n.endswith("*") for n in names) == 1
    err = env.core.errors[0]
    mean = float(lines[0].split("mean error = ")[1].split()[0])
    assert mean == float(f"{np.delete(err, 4).mean():.3g}")
