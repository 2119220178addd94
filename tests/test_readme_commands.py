"""Every ``netsense`` command in the README's ```bash blocks runs, as written.

The commands are read from README.md at test time, so the README cannot show a command
that fails (or one too slow for the suite: then the README must change). Each block's
commands run in order in one fresh directory (a block may train a policy and then
benchmark it). A command is skipped, with the reason, only when it needs an optional extra
that is not installed (``tests/test_ci_extras.py`` fails CI if one is missing there) or a
running Ray cluster (``--address``).
"""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

#: Modules a command needs, by what it contains.
RL_STACK = ("stable_baselines3", "sb3_contrib", "supersuit", "torch")
TORCHRL_STACK = ("torch", "torchrl", "tensordict")


def readme_blocks(text: str) -> list[list[list[str]]]:
    """The ``netsense`` commands (argv lists) of each ```bash block that has any.

    Continuation lines (trailing backslash) are joined and ``# comments`` dropped; a line
    may chain commands with ``&&`` (``pip install -e . && netsense demo``)."""
    blocks = []
    for body in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        joined = re.sub(r"\\\n", " ", body)
        cmds = []
        for line in joined.splitlines():
            words = shlex.split(line, comments=True)
            part: list[str] = []
            for w in [*words, "&&"]:
                if w == "&&":
                    if part and part[0] == "netsense":
                        cmds.append(part)
                    part = []
                else:
                    part.append(w)
        if cmds:
            blocks.append(cmds)
    return blocks


def needs(argv: list[str]) -> tuple[list[str], str | None]:
    """``(modules the command imports, reason it cannot run here or None)``."""
    mods: list[str] = []
    if argv[1] == "train":
        # the batched TorchRL trainer unless --backend sb3
        torchrl = not ("--backend" in argv and argv[argv.index("--backend") + 1] == "sb3")
        mods += TORCHRL_STACK if torchrl else RL_STACK
    learned = [a.split(":", 1)[1] for a in argv if a.startswith("learned:")]
    learned += [argv[i + 1] for i, a in enumerate(argv[:-1]) if a == "--learned"]
    for path in learned:
        mods += TORCHRL_STACK if path.endswith(".pt") else RL_STACK
    if "--backend" in argv and argv[argv.index("--backend") + 1] == "ray":
        mods.append("ray")
        if "--address" in argv:
            return mods, "needs a running Ray cluster (--address)"
    return mods, None


BLOCKS = readme_blocks(README.read_text())


def test_the_readme_shows_netsense_commands():
    assert BLOCKS, "the README should show how to run netsense"
    assert any(cmd[:2] == ["netsense", "demo"] for b in BLOCKS for cmd in b)


def test_the_parser_reads_continuations_chains_and_comments():
    text = ("```bash\npip install -e . && netsense demo   # the demo\n"
            "netsense train a-v0 --steps 5 \\\n    --override 'reward={\"x\": 1}'\n```\n"
            "```bash\npython -m pytest -q\n```\n")
    assert readme_blocks(text) == [[["netsense", "demo"],
                                    ["netsense", "train", "a-v0", "--steps", "5",
                                     "--override", 'reward={"x": 1}']]]


@pytest.mark.parametrize("block", BLOCKS, ids=[" / ".join(" ".join(c[:2]) for c in b)
                                               for b in BLOCKS])
def test_readme_block_runs(block, tmp_path):
    env = dict(os.environ, MPLBACKEND="Agg",
               PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    for argv in block:
        mods, reason = needs(argv)
        missing = [m for m in mods if importlib.util.find_spec(m) is None]
        if reason or missing:
            pytest.skip(f"{shlex.join(argv)}: {reason or 'not installed: ' + ', '.join(missing)}")
        res = subprocess.run([sys.executable, "-m", "netsense.cli", *argv[1:]], cwd=tmp_path,
                             env=env, capture_output=True, text=True, timeout=600)
        assert res.returncode == 0, (f"`{shlex.join(argv)}` exited {res.returncode}:\n"
                                     f"{res.stdout[-2000:]}\n{res.stderr[-3000:]}")
