"""netsense: networked state estimation over switching directed graphs.

Core entry points (see the README for an example):

* :func:`decompose` — Lemma 1's multi-sensor observable decomposition;
* :func:`design_observer` — rate-ordered (Theorem 1) or deadbeat (Corollary 1) gains;
* :class:`FreshnessObserver` / :class:`ConsensusObserver` — the distributed observers;
* graph processes and the Assumption 1 checker in :mod:`netsense.graphs`;
* plants in :mod:`netsense.systems`;
* :func:`make` / :func:`list_scenarios` — the PettingZoo environment's scenario registry;
* :class:`BatchedCore` / :class:`BatchedEnv` — ``B`` environments stepped at once;
* :class:`NumericalError` / :class:`NumericalWarning` — a state or estimate that stopped
  being finite (``docs/errors.md``: what raises what);
* :func:`set_num_threads` / :func:`get_num_threads` — threads of batched calls
  (``docs/threads.md``).

The package is layered (README, "Architecture"): ``kernels`` < ``sensing`` < ``systems`` <
``graphs`` < ``estimators`` < ``observers`` < ``engine`` < ``env`` < the tools. The names
below are loaded on first use, so ``import netsense`` stays cheap and a deep import (say
``netsense.graphs``) does not pull in the environment.
"""

from __future__ import annotations

import importlib
import os
from typing import TYPE_CHECKING, Any

# OpenMP's workers spin after each threaded call by default: on a core another process
# uses, every call then waits for the spinning worker's time slice (steps up to 29x slower
# measured, docs/threads.md). Passive workers sleep at once. libgomp reads the policy once,
# when it loads: at numba's first threaded call, or earlier when torch is imported (the
# training stack). So it is set here, at the package's import and before any of its
# modules imports torch, unless the user chose a policy.
if "OMP_WAIT_POLICY" not in os.environ and "GOMP_SPINCOUNT" not in os.environ:
    os.environ["OMP_WAIT_POLICY"] = "passive"

__version__ = "0.1.0"

#: Public name -> module that defines it.
_EXPORTS = {
    "OMEGA": "netsense.kernels.rules",
    "get_num_threads": "netsense.kernels.jit",
    "set_num_threads": "netsense.kernels.jit",
    "NumericalError": "netsense.kernels.checks",
    "NumericalWarning": "netsense.kernels.checks",
    "Decomposition": "netsense.systems.decomposition",
    "decompose": "netsense.systems.decomposition",
    "is_observable": "netsense.systems.decomposition",
    "ObserverDesign": "netsense.systems.design",
    "deadbeat_gain": "netsense.systems.design",
    "design_observer": "netsense.systems.design",
    "rate_gain": "netsense.systems.design",
    "Plant": "netsense.systems.plants",
    "fig1_scalar": "netsense.systems.plants",
    "random_structured": "netsense.systems.plants",
    "GaussianNoise": "netsense.sensing.noise",
    "NoNoise": "netsense.sensing.noise",
    "UniformNoise": "netsense.sensing.noise",
    "Gossip": "netsense.graphs.processes",
    "GraphProcess": "netsense.graphs.processes",
    "MarkovLinkFailures": "netsense.graphs.processes",
    "PeriodicGraphs": "netsense.graphs.processes",
    "RandomJointlyConnected": "netsense.graphs.processes",
    "check_joint_connectivity": "netsense.graphs.processes",
    "fig1_graphs": "netsense.graphs.processes",
    "smallest_period": "netsense.graphs.processes",
    "ConsensusObserver": "netsense.observers.consensus",
    "FreshnessObserver": "netsense.observers.freshness",
    "BatchedCore": "netsense.engine.core",
    "CoreModel": "netsense.engine.model",
    "NetSenseEnv": "netsense.env.pettingzoo_env",
    "list_scenarios": "netsense.env.registry",
    "make": "netsense.env.registry",
    "BatchedEnv": "netsense.env.vector",
    "AgentVectorEnv": "netsense.env.vector",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    """Load a public name from its module on first use (PEP 562)."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'netsense' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))


if TYPE_CHECKING:  # static checkers see the eager form
    from netsense.engine.core import BatchedCore
    from netsense.engine.model import CoreModel
    from netsense.env.pettingzoo_env import NetSenseEnv
    from netsense.env.registry import list_scenarios, make
    from netsense.env.vector import AgentVectorEnv, BatchedEnv
    from netsense.graphs.processes import (
        Gossip,
        GraphProcess,
        MarkovLinkFailures,
        PeriodicGraphs,
        RandomJointlyConnected,
        check_joint_connectivity,
        fig1_graphs,
        smallest_period,
    )
    from netsense.kernels.checks import NumericalError, NumericalWarning
    from netsense.kernels.jit import get_num_threads, set_num_threads
    from netsense.kernels.rules import OMEGA
    from netsense.observers.consensus import ConsensusObserver
    from netsense.observers.freshness import FreshnessObserver
    from netsense.sensing.noise import GaussianNoise, NoNoise, UniformNoise
    from netsense.systems.decomposition import Decomposition, decompose, is_observable
    from netsense.systems.design import ObserverDesign, deadbeat_gain, design_observer, rate_gain
    from netsense.systems.plants import Plant, fig1_scalar, random_structured
