"""The environment's documentation tells the truth: the observation table in the env
docstring matches the layout, and the README example runs."""

from __future__ import annotations

import re
from pathlib import Path

import netsense.env.pettingzoo_env as env_module
from netsense.engine.core import ObsLayout
from netsense.env.registry import make


def test_observation_table_matches_layout_order_and_sizes():
    doc = env_module.__doc__
    table = doc[doc.index("Observation Space"):doc.index("Rewards\n")]
    rows = re.findall(r"^``(\w+)``\s+(D x M|\w+)\s", table, flags=re.M)
    env = make("random_structured_n20_N10-v0")
    L: ObsLayout = env.layout
    assert [name for name, _ in rows] == [name for name, _, _ in L.table()]
    sizes = {"1": 1, "r": L.r, "M": L.M, "n": L.n, "D": L.D, "D x M": L.D * L.M}
    for (name, size), (_, start, stop) in zip(rows, L.table(), strict=True):
        assert stop - start == sizes[size], name
    assert L.size == 3 + L.r + L.n + 2 * L.M + 2 * L.D + 2 * L.D * L.M


def test_readme_env_example_runs():
    """The README's env example (the block that steps an env) runs to the horizon."""
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    code = next(b for b in blocks if "while env.agents" in b)
    scope: dict = {}
    exec(compile(code, "README-env", "exec"), scope)
    assert scope["env"].agents == []  # ran to the horizon
