"""Additive noise models for process and measurement noise.

Every model draws from a caller-supplied :class:`numpy.random.Generator`, so that all
randomness in a run flows from one seed. ``sample(rng, shape)`` returns an array of the
requested shape whose last axis is the noise dimension.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class NoiseModel:
    """Base class: zero-mean additive noise with a documented bound or covariance."""

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...],
               out: np.ndarray | None = None) -> np.ndarray:
        """Draw noise of ``shape``; with ``out`` (float64, C-contiguous, that shape) write
        it there and return ``out`` (the same numbers as without)."""
        raise NotImplementedError

    @property
    def bound(self) -> float:
        """Infinity-norm bound on one draw (``inf`` for unbounded noise)."""
        raise NotImplementedError

    def to_dict(self) -> dict:
        raise NotImplementedError


@dataclass(frozen=True)
class NoNoise(NoiseModel):
    """No noise: every draw is exactly zero."""

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...],
               out: np.ndarray | None = None) -> np.ndarray:
        if out is None:
            return np.zeros(shape)
        out[...] = 0.0
        return out

    @property
    def bound(self) -> float:
        return 0.0

    def to_dict(self) -> dict:
        return {"kind": "none"}


@dataclass(frozen=True)
class GaussianNoise(NoiseModel):
    """Independent zero-mean Gaussian noise with standard deviation ``std`` per entry."""

    std: float

    def __post_init__(self) -> None:
        if not np.isfinite(self.std) or self.std < 0:
            raise ValueError(f"GaussianNoise.std must be a finite number >= 0, got {self.std!r}")

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...],
               out: np.ndarray | None = None) -> np.ndarray:
        if out is None:
            return self.std * rng.standard_normal(shape)
        rng.standard_normal(out=out)  # the same stream, written in place
        out *= self.std
        return out

    @property
    def bound(self) -> float:
        return float("inf") if self.std > 0 else 0.0

    def to_dict(self) -> dict:
        return {"kind": "gaussian", "std": self.std}


@dataclass(frozen=True)
class UniformNoise(NoiseModel):
    """Bounded noise, independent and uniform on ``[-bound, bound]`` per entry."""

    half_width: float

    def __post_init__(self) -> None:
        if not np.isfinite(self.half_width) or self.half_width < 0:
            raise ValueError(
                f"UniformNoise.half_width must be a finite number >= 0, got {self.half_width!r}"
            )

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...],
               out: np.ndarray | None = None) -> np.ndarray:
        draw = rng.uniform(-self.half_width, self.half_width, size=shape)
        if out is None:
            return draw
        out[...] = draw
        return out

    @property
    def bound(self) -> float:
        return float(self.half_width)

    def to_dict(self) -> dict:
        return {"kind": "uniform", "half_width": self.half_width}


def noise_from_dict(spec: dict | None) -> NoiseModel:
    """Build a noise model from ``{"kind": "none" | "gaussian" | "uniform", ...}``.

    Raises
    ------
    ValueError
        If ``kind`` is unknown or a parameter is missing or not allowed.
    """
    if spec is None:
        return NoNoise()
    spec = dict(spec)
    kind = spec.pop("kind", None)
    allowed = {"none": (NoNoise, set()), "gaussian": (GaussianNoise, {"std"}),
               "uniform": (UniformNoise, {"half_width"})}
    if kind not in allowed:
        raise ValueError(f"noise kind must be one of {sorted(allowed)}, got {kind!r}")
    cls, keys = allowed[kind]
    if set(spec) != keys:
        raise ValueError(f"noise kind {kind!r} takes exactly the fields {sorted(keys)}, "
                         f"got {sorted(spec)}")
    return cls(**{k: float(v) for k, v in spec.items()})
