"""In CI every optional stack the suite exercises must really be installed.

Tests of optional integrations use ``pytest.importorskip`` so that a light local install
still runs; this check stops CI from passing by silently skipping them.
"""

import importlib
import os

import pytest

EXTRAS = ["sb3_contrib", "supersuit", "stable_baselines3", "ray.rllib", "torchrl",
          "opendssdirect", "torch"]


@pytest.mark.skipif(os.environ.get("CI", "").lower() not in ("1", "true"),
                    reason="only enforced in CI (CI=true)")
@pytest.mark.parametrize("module", EXTRAS)
def test_optional_stack_installed_in_ci(module):
    importlib.import_module(module)
