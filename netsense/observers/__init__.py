"""Layer 6 — the distributed observers of the freshness paper and their variants.

Behind one base (:mod:`.base`, ``step(measurements, graph)`` on a batch): the
freshness-index observer (:mod:`.freshness`, eqs. (7)-(14)) and the consensus baselines of
eq. (6) (:mod:`.consensus`); faulty variants and fault models (:mod:`.faults`: crashed,
stuck and lying agents, link drops); the source-node estimators that replace the
Luenberger update at a source (:mod:`.source`, :mod:`.source_estimators`,
:mod:`.source_estimators_equalized`); and :func:`~netsense.observers.run.run_observer`,
which runs any of them on a plant over given graphs and measures it (:mod:`.run`).

May import: kernels, sensing, systems, graphs, estimators.
"""

from netsense.observers.consensus import ConsensusObserver
from netsense.observers.freshness import FreshnessObserver

__all__ = ["ConsensusObserver", "FreshnessObserver"]
