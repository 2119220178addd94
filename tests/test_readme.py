"""Every Python example in the README runs (doc examples that never run rot)."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_blocks_run():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks, "the README should carry at least one Python example"
    for code in blocks:
        exec(compile(code, str(README), "exec"), {})
