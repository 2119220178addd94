"""Load a script of ``experiments/`` as a module (the scripts are not a package)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"


def load_experiment(name: str) -> ModuleType:
    """``experiments/<purpose>/<script>.py`` (``name = "<purpose>/<script>"``) imported as the
    module ``_exp_<purpose>_<script>``."""
    path = EXPERIMENTS / f"{name}.py"
    if not path.is_file():
        raise FileNotFoundError(f"no experiment script {path}")
    spec = importlib.util.spec_from_file_location("_exp_" + name.replace("/", "_"), path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up here
    spec.loader.exec_module(mod)
    return mod


def import_experiment(name: str) -> ModuleType:
    """``experiments/<purpose>/<script>.py`` imported under its own name ``<script>`` (its
    folder put on ``sys.path``), so that worker processes can import it too."""
    import importlib

    purpose, script = name.split("/")
    folder = str(EXPERIMENTS / purpose)
    if folder not in sys.path:
        sys.path.insert(0, folder)
    return importlib.import_module(script)
