"""Estimators and observers.

Distributed: :mod:`.freshness` (freshness-index observer) and :mod:`.consensus`
(consensus baselines of eq. (6)). Centralised estimators live in their own modules.
"""

from netsense.observers.consensus import ConsensusObserver
from netsense.observers.freshness import FreshnessObserver

__all__ = ["ConsensusObserver", "FreshnessObserver"]
