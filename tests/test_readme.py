"""Every Python example in the README and in docs/ runs (doc examples that never run rot)."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = sorted((ROOT / "docs").glob("*.md"))
#: Optional stacks (extras) a docs example may import; tests/test_ci_extras.py makes sure CI
#: has them all, so these skips never hide a failure there.
OPTIONAL = ("torch", "torchrl", "tensordict", "stable_baselines3", "sb3_contrib", "supersuit",
            "ray", "opendssdirect")


def _blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S)


def test_readme_python_blocks_run():
    blocks = _blocks(README)
    assert blocks, "the README should carry at least one Python example"
    for code in blocks:
        exec(compile(code, str(README), "exec"), {})


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_docs_python_blocks_run(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples that write files write them here
    for code in _blocks(page):
        for module in OPTIONAL:
            if re.search(rf"\b(import|from) {module}\b", code):
                pytest.importorskip(module, reason=f"{page.name} needs {module} (an extra)")
        if re.search(r"\b(import|from) netsense\.rl\b", code):  # the trainer: torch's extra
            pytest.importorskip("torch", reason=f"{page.name} needs netsense.rl (torch)")
        exec(compile(code, str(page), "exec"), {})


def test_readme_is_a_front_door():
    """Short, in short paragraphs: measurements and notes live in docs/ (its tables and code
    blocks are not paragraphs)."""
    text = README.read_text()
    assert len(text.splitlines()) <= 215
    prose = re.sub(r"```.*?```", "", text, flags=re.S)
    prose = re.sub(r"<!-- table:.*?<!-- /table -->", "", prose, flags=re.S)  # generated
    for par in re.split(r"\n\s*\n", prose):
        if not par.lstrip().startswith("|"):
            assert len(par.split()) <= 85, f"a README paragraph of {len(par.split())} words"


@pytest.mark.parametrize("page", [README, *PAGES], ids=["README.md", *[p.name for p in PAGES]])
def test_user_facing_text_has_no_history_markers(page):
    text = page.read_text()
    assert not re.search(r"\bissue \d+", text), "internal issue numbers in the README"
    commit = r"\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b"
    assert not re.search(commit, text), "commit hashes in the README"


def test_readme_quick_start_prints_what_the_readme_shows(capsys):
    """The quick start's output block is its real output."""
    text = README.read_text()
    section = text[text.index("## Quick start"):]
    code = re.search(r"```python\n(.*?)```", section, flags=re.S).group(1)
    shown = re.search(r"\nprints\n\n```\n(.*?)```", section, flags=re.S).group(1)
    exec(compile(code, "README-quick-start", "exec"), {})
    assert capsys.readouterr().out == shown


@pytest.mark.parametrize("page", [README, *PAGES], ids=["README.md", *[p.name for p in PAGES]])
def test_the_lookahead_searches_are_references_not_bounds(page):
    """The lookahead searches are achieved returns that other policies beat: the pages call
    them full-information references, and the superseded gap figures stay out."""
    text = page.read_text()
    assert not re.search(r"(causal|clairvoyant) bound|gap closed", text, flags=re.I)
