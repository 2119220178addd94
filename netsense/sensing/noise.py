"""Additive noise models for process and measurement noise.

Every model draws from a caller-supplied :class:`numpy.random.Generator`, so that all
randomness in a run flows from one seed. ``sample(rng, shape)`` returns an array of the
requested shape whose last axis is the noise dimension; ``sample_many(rngs, shape, out)``
fills ``out[m]`` with what ``sample(rngs[m], shape)`` would return, for many runs at once
(the batched core's refills).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import prange
from numba.np.random.distributions import random_standard_normal

from netsense.kernels import checks
from netsense.kernels.jit import Driver, bit_generator, bit_streams


class NoiseModel:
    """Base class: zero-mean additive noise with a documented bound or covariance."""

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Draw noise of ``shape``."""
        raise NotImplementedError

    def sample_many(self, rngs: Sequence[np.random.Generator], shape: tuple[int, ...],
                    out: np.ndarray) -> np.ndarray:
        """``out[m] = sample(rngs[m], shape)`` for every run ``m``; returns ``out``
        (float64, C-contiguous, ``(len(rngs), *shape)``). Each generator advances exactly
        as by its own ``sample`` call."""
        _check_many(out, len(rngs), shape)
        for m, rng in enumerate(rngs):
            out[m] = self.sample(rng, shape)
        return out

    @property
    def bound(self) -> float:
        """Infinity-norm bound on one draw (``inf`` for unbounded noise)."""
        raise NotImplementedError

    def to_dict(self) -> dict:
        raise NotImplementedError


@dataclass(frozen=True)
class NoNoise(NoiseModel):
    """No noise: every draw is exactly zero."""

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        return np.zeros(shape)

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
        checks.number("GaussianNoise.std", self.std, 0)

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        return self.std * rng.standard_normal(shape)

    def sample_many(self, rngs: Sequence[np.random.Generator], shape: tuple[int, ...],
                    out: np.ndarray) -> np.ndarray:
        # one compiled pass over the runs: each run's normals come from its own generator
        # through numba's copy of numpy's ziggurat on numpy's own bit-generator functions
        # (the stream of rng.standard_normal, bit for bit), without a Python call per run
        streams = bit_streams(rngs)
        if streams is None:  # mixed bit-generator types or a generator listed twice
            return super().sample_many(rngs, shape, out)
        _check_many(out, len(rngs), shape)
        flat = out.reshape(len(rngs), -1)
        _normals.at(flat.size, runs=flat.shape[0])(streams[0], streams[1], float(self.std), flat)
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
        checks.number("UniformNoise.half_width", self.half_width, 0)

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        return rng.uniform(-self.half_width, self.half_width, size=shape)

    @property
    def bound(self) -> float:
        return float(self.half_width)

    def to_dict(self) -> dict:
        return {"kind": "uniform", "half_width": self.half_width}


def _check_many(out: np.ndarray, runs: int, shape: tuple[int, ...]) -> None:
    want = (runs, *shape)
    if (not isinstance(out, np.ndarray) or out.shape != want or out.dtype != np.float64
            or not out.flags.c_contiguous):
        raise ValueError(f"out must be a C-contiguous float64 array of shape {want}, got "
                         f"{getattr(out, 'dtype', type(out))} {getattr(out, 'shape', '')}")


def _normals(fns, states, std, out):
    """``out[m, t] = std * z`` with ``z`` the next standard normal of run ``m``'s generator
    (``Generator.standard_normal``'s algorithm and stream), for every ``t`` in order."""
    for m in prange(out.shape[0]):
        bg = bit_generator(fns, states[m])
        for t in range(out.shape[1]):
            out[m, t] = random_standard_normal(bg) * std


_normals = Driver(_normals)


def noise_from_dict(spec: dict | None) -> NoiseModel:
    """Build a noise model from ``{"kind": "none" | "gaussian" | "uniform", ...}``.

    Raises
    ------
    ValueError
        If ``kind`` is unknown or a parameter is missing or not allowed.
    """
    if spec is None:
        return NoNoise()
    if not isinstance(spec, dict):
        raise ValueError(f"a noise spec must be a table {{kind = ...}}, got {spec!r:.60}")
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
    return cls(**{k: checks.number(k, v, 0) for k, v in spec.items()})
