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


DOCS = Path(__file__).parents[1] / "docs"


def test_files_named_in_the_docs_exist():
    """Every repository path written in backticks in docs/ and the README exists."""
    root = Path(__file__).parents[1]
    texts = [p.read_text() for p in sorted(DOCS.glob("*.md"))] + [
        (root / "README.md").read_text()]
    named = {m for t in texts for m in re.findall(
        r"`((?:netsense|experiments|tests|docs)/[\w/.*-]+)`", t)}
    assert named  # the pattern finds paths at all
    missing = sorted(p for p in named if not list(root.glob(p)))
    assert not missing, missing


def test_env_page_example_offers_only_policies_that_run_on_its_scenario():
    from netsense.env.policies import make_policy

    text = (DOCS / "env.md").read_text()
    block = next(b for b in re.findall(r"```python\n(.*?)```", text, flags=re.S)
                 if "make_policy" in b)
    scenario = re.search(r'make\("([\w-]+)"', block).group(1)
    offered = re.search(r"# also: ([\w, ]+)", block).group(1).split(", ")
    env = make(scenario)
    for name in ["freshness", *offered]:
        make_policy(name, env)  # raises for a policy the scenario refuses


def test_task_cards_state_what_the_registry_holds():
    """docs/tasks.md has one card per task of the benchmark suite, in the suite's order, and
    each card's control mode, message and substate costs, channel capacity and horizon are
    the scenario file's (a full-control scenario is scored in ``transmit`` mode)."""
    from netsense.benchmark.references import SUITE_TASKS
    from netsense.env.registry import load

    text = (DOCS / "tasks.md").read_text()
    cards = re.split(r"^### `([\w-]+)`.*$", text[text.index("## The cards"):
                                                 text.index("## Calibration")], flags=re.M)
    ids, bodies = cards[1::2], cards[2::2]
    assert tuple(ids) == SUITE_TASKS
    for task, body in zip(ids, bodies, strict=True):
        sc = load(task)
        mode = sc.control.get("mode", "transmit")
        assert re.search(rf"`{mode}` mode", body), (task, mode)
        assert re.search(r"`c = ([\d.]+)` per message", body).group(1) == \
            f"{sc.reward.message_cost:g}", task
        c_s = re.search(r"`c_s = ([\d.]+)`", body)
        assert (float(c_s.group(1)) if c_s else 0.0) == sc.reward.substate_cost, task
        k = re.search(r"`K = (\d+)`", body)
        assert (int(k.group(1)) if k else None) == (sc.channel or {}).get("capacity"), task
        assert re.search(r"`H = (\d+)` steps", body).group(1) == str(sc.horizon), task
