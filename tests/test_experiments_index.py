"""experiments/ is laid out by purpose and its index (experiments/README.md) is complete.

Every script under ``experiments/<purpose>/`` is listed in the index with the command that
runs it, every listed script exists, each script's default output folder is its mirror
``experiments/results/<purpose>/<script>/`` (read from the script's own ``RESULTS``
assignment), every results folder belongs to a listed script or command, and nothing in
``netsense/`` imports from ``experiments/``.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = ROOT / "experiments"
INDEX = EXPERIMENTS / "README.md"
PURPOSES = ("papers", "bench", "rl", "studies")


def index_rows() -> dict[str, list[str]]:
    """``{"<purpose>/<script>.py" or "results/...": cells}`` for every table row of the index
    whose first cell is a backticked script or results path."""
    rows = {}
    for line in INDEX.read_text().splitlines():
        if not line.startswith("| `"):
            continue
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        key = re.fullmatch(r"`([^`]+)`", cells[0])
        if key:
            rows[key.group(1)] = cells
    return rows


ROWS = index_rows()
SCRIPTS = sorted(p.relative_to(EXPERIMENTS).as_posix() for p in EXPERIMENTS.glob("*/*.py"))


def test_the_index_reader_reads_rows():
    assert len(ROWS) >= 20
    assert "papers/freshness_fig2.py" in ROWS and "results/rl/comm_frontier/" in ROWS


def test_scripts_live_in_a_purpose_folder():
    assert not list(EXPERIMENTS.glob("*.py")), "a script at the top of experiments/"
    folders = {p.name for p in EXPERIMENTS.iterdir() if p.is_dir()}
    assert folders == {*PURPOSES, "results"}, sorted(folders)
    assert {s.split("/")[0] for s in SCRIPTS} == set(PURPOSES)


def test_every_script_is_listed_and_every_listed_script_exists():
    listed = sorted(k for k in ROWS if k.endswith(".py"))
    missing = sorted(set(SCRIPTS) - set(listed))
    assert not missing, f"add these scripts to experiments/README.md: {missing}"
    stale = sorted(set(listed) - set(SCRIPTS))
    assert not stale, f"experiments/README.md lists scripts that do not exist: {stale}"


@pytest.mark.parametrize("script", SCRIPTS)
def test_the_index_row_has_command_time_and_outputs(script):
    _, what, command, time, writes = ROWS[script]
    assert f"python experiments/{script}" in command
    assert what and writes
    assert re.search(r"\b\d+(\.\d+)? (s|min)\b", time), f"{script}: no run time in {time!r}"


def _default_results(path: Path) -> Path | None:
    """The script's module-level ``RESULTS``, evaluated from its source (``HERE``/``ROOT``
    assignments before it included), or None if it has none."""
    scope = {"Path": Path, "__file__": str(path)}
    for node in ast.parse(path.read_text()).body:
        if (isinstance(node, ast.Assign) and len(node.targets) == 1
                and isinstance(node.targets[0], ast.Name)
                and node.targets[0].id in ("HERE", "ROOT", "RESULTS")):
            code = compile(ast.Expression(node.value), str(path), "eval")
            scope[node.targets[0].id] = eval(code, scope)  # noqa: S307 (a path expression)
    return scope.get("RESULTS")


@pytest.mark.parametrize("script", SCRIPTS)
def test_default_output_mirrors_the_script_path(script):
    path = EXPERIMENTS / script
    results = _default_results(path)
    writes = ROWS[script][4]
    if results is None:
        assert writes.startswith("print"), f"{script} writes files but has no RESULTS"
        return
    purpose, stem = script[:-3].split("/")
    assert results.resolve() == (EXPERIMENTS / "results" / purpose / stem).resolve()
    assert path.read_text().count("RESULTS") >= 2, f"{script} defines RESULTS but never uses it"


def test_every_results_folder_belongs_to_a_listed_script_or_command():
    results = EXPERIMENTS / "results"
    assert {p.name for p in results.iterdir()} <= set(PURPOSES), "results/ holds only purposes"
    owners = {s[:-3] for s in SCRIPTS}
    owners |= {k.removeprefix("results/").rstrip("/") for k in ROWS if k.startswith("results/")}
    for purpose in results.iterdir():
        loose = [p.name for p in purpose.iterdir() if not p.is_dir()]
        assert not loose, f"files directly in results/{purpose.name}/: {loose}"
        for folder in purpose.iterdir():
            name = f"{purpose.name}/{folder.name}"
            assert name in owners, f"results/{name}/ belongs to no script or command of the index"


def test_the_package_never_imports_experiments():
    for path in (ROOT / "netsense").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                names = [node.module]
            bad = [n for n in names if n.split(".")[0] == "experiments"]
            assert not bad, f"{path.relative_to(ROOT)} imports {bad}"
