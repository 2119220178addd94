"""The package's layers: imports flow one way, from the tools down to the kernels.

:data:`LAYERS` is the one statement of the order (the README's "Architecture" section is its
prose). Every import in ``netsense/`` — top-level, lazy inside a function, or under
``TYPE_CHECKING`` — is read with :mod:`ast`; an import of a module in a higher layer fails,
and so does any cycle between files.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "netsense"

#: Subpackages from the bottom up; a module may import its own layer and those below.
#: The tools above ``env`` are ordered too (``benchmark`` loads learned policies from ``rl``,
#: ``speed`` measures the benchmark's batched rollouts, ``commands`` drives them all).
LAYERS = (
    "kernels", "sensing", "systems", "graphs", "estimators", "observers", "engine", "env",
    "grid", "rl", "benchmark", "studies", "speed", "commands", "cli",
)
#: The package root re-exports the public API (lazily) and sits above everything.
ROOT_RANK = len(LAYERS)


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> set[str]:
    """The netsense modules ``name`` imports (a ``from pkg import mod`` names ``pkg.mod``)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            subs = [f"{mod}.{a.name}" for a in node.names if f"{mod}.{a.name}" in MODULES]
            if subs:
                found.update(subs)
            if len(subs) < len(node.names):
                found.add(mod)
    return {m for m in found if m.split(".")[0] == "netsense"}


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def rank(module: str) -> int:
    parts = module.split(".")
    if len(parts) == 1:
        return ROOT_RANK
    return LAYERS.index(parts[1])


def test_every_subpackage_has_a_layer():
    tops = {m.split(".")[1] for m in MODULES if "." in m}
    assert tops <= set(LAYERS), f"not in LAYERS: {sorted(tops - set(LAYERS))}"


def test_every_subpackage_says_what_it_may_import():
    for layer in LAYERS:
        init = PACKAGE / layer / "__init__.py"
        if init.exists():
            doc = ast.get_docstring(ast.parse(init.read_text())) or ""
            assert "import" in doc.lower(), f"netsense.{layer}: docstring names no import rule"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_import_goes_up_a_layer(module):
    up = sorted(m for m in GRAPH[module] if rank(m) > rank(module))
    assert not up, f"{module} (layer {rank(module)}) imports from higher layers: {up}"


def test_no_import_cycles():
    state: dict[str, int] = {}  # 1 = on the stack, 2 = done
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for d in sorted(GRAPH.get(m, ())):
            if d == m or d not in GRAPH:
                continue
            if state.get(d) == 1:
                cycle = stack[stack.index(d):] + [d]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(GRAPH):
        if m not in state:
            visit(m)


#: Inside :mod:`netsense.rl`, the training pipeline's stages in the order a run goes through
#: them (``netsense/rl/__init__.py`` documents each): a module imports only ``netsense.rl``
#: modules of earlier stages. The adapters sit on the core-only helpers; the former homes of
#: the pipeline's names (``mappo``, ``models``, ``torchrl_batched``) re-export from above.
RL_STAGES = (
    ("atomic",),
    ("run_folder",),
    ("credit", "wrappers", "policy_files"),
    ("sb3_policy",),
    ("sb3", "rllib", "torchrl"),
    ("envs",),
    ("distributions",),
    ("networks", "set_network", "memory"),
    ("config",),
    ("policy",),
    ("resume",),
    ("rollout",),
    ("advantage",),
    ("scripted",),
    ("cloning",),
    ("evaluation",),
    ("runlog",),
    ("checkpoint",),
    ("ppo", "es"),
    ("launch",),
    ("mappo", "models", "torchrl_batched"),
)


def rl_stage(module: str) -> int:
    name = module.split(".")[2]
    return next(i for i, group in enumerate(RL_STAGES) if name in group)


def test_every_rl_module_has_a_stage():
    rl = {m.split(".")[2] for m in MODULES if m.startswith("netsense.rl.")}
    staged = {name for group in RL_STAGES for name in group}
    assert rl == staged, f"not in RL_STAGES: {sorted(rl - staged)}; gone: {sorted(staged - rl)}"


@pytest.mark.parametrize("module", sorted(m for m in MODULES if m.startswith("netsense.rl.")))
def test_rl_stages_import_only_earlier_stages(module):
    rank_m = rl_stage(module)
    later = sorted(m for m in GRAPH[module] if m.startswith("netsense.rl.") and m != module
                   and rl_stage(m) >= rank_m)
    assert not later, f"{module} (stage {rank_m}) imports the same or a later stage: {later}"


def test_the_checker_sees_a_violation(tmp_path):
    """The walk resolves relative, lazy and ``from pkg import module`` imports."""
    src = tmp_path / "mod.py"
    src.write_text("def f():\n    from netsense.env import registry\n"
                   "from . import drivers\n")
    found = _imports("netsense.kernels.mod", src)
    assert found == {"netsense.env.registry", "netsense.kernels.drivers"}
    assert rank("netsense.env.registry") > rank("netsense.kernels.mod")
