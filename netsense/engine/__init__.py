"""Layer 7 — what a scenario compiles to, and the batched step that runs it.

:class:`~netsense.engine.model.CoreModel` is a scenario turned into arrays (plant, design,
graph process, sensing, faults, reward, observation layout); :class:`~netsense.engine.
core.BatchedCore` steps ``B`` copies of it at once through the rules of
:mod:`netsense.kernels`, then builds observations and masks (:mod:`.observation`) and
rewards (:mod:`.rewards`). No PettingZoo or Gymnasium here: :mod:`netsense.env` wraps it.

May import every layer below: kernels, sensing, systems, graphs, estimators, observers.
"""

from netsense.engine.core import BatchedCore, StepResult
from netsense.engine.model import CoreModel, ObsLayout, RewardConfig

__all__ = ["BatchedCore", "CoreModel", "ObsLayout", "RewardConfig", "StepResult"]
