"""In CI every optional stack the suite exercises must really be installed.

Tests of optional integrations use ``pytest.importorskip`` so that a light local install
(``pip install -e ".[test-core]"``) still runs; this check stops CI from passing by
silently skipping them. CI also runs the core suite in a second, light environment
(``NETSENSE_CI_LIGHT=1``, see ``.ci/run``): there the check is the reverse, so that
environment really tests the core without the heavy stacks (and on the newest Gymnasium,
which Ray's pin keeps out of the full one).
"""

import importlib.util
import os

import pytest

EXTRAS = ["sb3_contrib", "supersuit", "stable_baselines3", "ray.rllib", "torchrl",
          "opendssdirect", "torch", "rliable", "sklearn", "cma"]

IN_CI = os.environ.get("CI", "").lower() in ("1", "true")
LIGHT = os.environ.get("NETSENSE_CI_LIGHT", "") == "1"


def _installed(module: str) -> bool:
    top = module.split(".")[0]
    return importlib.util.find_spec(top) is not None and (
        top == module or importlib.util.find_spec(module) is not None)


@pytest.mark.skipif(not IN_CI or LIGHT, reason="only enforced in CI's full environment")
@pytest.mark.parametrize("module", EXTRAS)
def test_optional_stack_installed_in_ci(module):
    assert _installed(module), f"{module} is not installed: its tests would only skip"


@pytest.mark.skipif(not LIGHT, reason="only in CI's light environment (NETSENSE_CI_LIGHT=1)")
@pytest.mark.parametrize("module", EXTRAS)
def test_light_environment_has_no_optional_stack(module):
    assert not _installed(module), f"{module} is installed in the light environment"
