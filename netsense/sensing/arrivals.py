"""Arrival processes: which measurements (or messages) reach their receiver at each step.

An :class:`ArrivalModel` is a frozen description (e.g. "Bernoulli with p = 0.8"); calling
``model.sampler(rng, shape)`` returns a stateful, picklable :class:`ArrivalSampler` whose
``next()`` yields one boolean array of ``shape`` per time step (``True`` = arrived).
Concrete models live in :mod:`netsense.sensing.drops` (Bernoulli, Gilbert-Elliott) and
:mod:`netsense.sensing.multirate` (periodic multi-rate reporting); environments and
estimators consume only this interface.
"""

from __future__ import annotations

import numpy as np


class ArrivalSampler:
    """Stateful draw of arrival indicators; one boolean array of ``shape`` per step."""

    def next(self) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def redraw(self, rng: np.random.Generator) -> ArrivalSampler:
        """A sampler that continues from the state before the last :meth:`next` as if
        that step had been drawn with ``rng``: the last step's arrivals are kept (they
        were seen), the randomness of its transition to the next state is redrawn, and
        later steps draw from ``rng`` (the resampled futures of
        :mod:`netsense.engine.fork`). This sampler is not changed."""
        raise NotImplementedError(f"{type(self).__name__} cannot redraw its future")


class ArrivalModel:
    """Frozen description of an arrival process."""

    def sampler(self, rng: np.random.Generator, shape: tuple[int, ...]) -> ArrivalSampler:
        raise NotImplementedError  # pragma: no cover - interface

    def to_dict(self) -> dict:
        raise NotImplementedError  # pragma: no cover - interface


class _AlwaysSampler(ArrivalSampler):
    def __init__(self, shape: tuple[int, ...]) -> None:
        self.shape = shape

    def next(self) -> np.ndarray:
        return np.ones(self.shape, dtype=bool)

    def redraw(self, rng: np.random.Generator) -> ArrivalSampler:
        return _AlwaysSampler(self.shape)


class AlwaysArrive(ArrivalModel):
    """Every measurement arrives at every step (the papers' default)."""

    def sampler(self, rng: np.random.Generator, shape: tuple[int, ...]) -> ArrivalSampler:
        return _AlwaysSampler(tuple(shape))

    def to_dict(self) -> dict:
        return {"kind": "always"}

    def __eq__(self, other: object) -> bool:
        return isinstance(other, AlwaysArrive)

    def __hash__(self) -> int:
        return hash("AlwaysArrive")
