"""netsense: networked state estimation over switching directed graphs.

Core entry points (see the README for an example):

* :func:`decompose` — Lemma 1's multi-sensor observable decomposition;
* :func:`design_observer` — rate-ordered (Theorem 1) or deadbeat (Corollary 1) gains;
* :class:`FreshnessObserver` / :class:`ConsensusObserver` — the distributed observers;
* graph processes and the Assumption 1 checker in :mod:`netsense.graphs`;
* plants in :mod:`netsense.systems`;
* :func:`make` / :func:`list_scenarios` — the PettingZoo environment's scenario registry;
* :func:`set_num_threads` / :func:`get_num_threads` — threads of batched calls
  (``docs/threads.md``).
"""

from netsense.compiled import get_num_threads, set_num_threads
from netsense.decomposition import Decomposition, decompose, is_observable
from netsense.design import ObserverDesign, deadbeat_gain, design_observer, rate_gain
from netsense.graphs import (
    Gossip,
    GraphProcess,
    MarkovLinkFailures,
    PeriodicGraphs,
    RandomJointlyConnected,
    check_joint_connectivity,
    fig1_graphs,
    smallest_period,
)
from netsense.kernels import OMEGA
from netsense.observers import ConsensusObserver, FreshnessObserver
from netsense.scenarios import list_scenarios, make
from netsense.sensing import GaussianNoise, NoNoise, UniformNoise
from netsense.systems import Plant, fig1_scalar, random_structured

__version__ = "0.1.0"

__all__ = [
    "OMEGA", "ConsensusObserver", "Decomposition", "FreshnessObserver", "GaussianNoise",
    "Gossip", "GraphProcess", "MarkovLinkFailures", "NoNoise", "ObserverDesign",
    "PeriodicGraphs", "Plant", "RandomJointlyConnected", "UniformNoise",
    "check_joint_connectivity", "deadbeat_gain", "decompose", "design_observer",
    "fig1_graphs", "fig1_scalar", "get_num_threads", "is_observable", "list_scenarios",
    "make", "random_structured", "rate_gain", "set_num_threads", "smallest_period",
]
