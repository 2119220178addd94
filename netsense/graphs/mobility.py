"""Switching graphs from agents moving in the plane (random waypoint, random walk).

Agent ``l`` can send to agent ``i`` at step ``k`` when their distance is at most ``l``'s
communication radius, ``||p_i[k] - p_l[k]|| <= r_l`` (a unit-disk graph; with equal radii
it is symmetric, with per-agent radii it is directed, as with heterogeneous transmit
powers). Positions live in the square ``[0, area]^2``.

* :class:`RandomWaypoint` -- each agent picks a uniform target and a uniform speed in
  ``[speed_min, speed_max]``, walks there in a straight line, pauses ``pause`` steps and
  repeats (the classic model of Johnson & Maltz, 1996).
* :class:`RandomWalk` -- Gaussian steps of standard deviation ``step_std`` per
  coordinate, reflected at the borders.

Both are :class:`netsense.graphs.processes.GraphProcess` subclasses: frozen, picklable, and
``process.sequence(K, seed)`` is reproducible from the seed; ``process.trajectory(rng, K,
state)`` also returns the positions. Whether Assumption 1 holds is *not* guaranteed: check
it with :func:`netsense.graphs.processes.check_joint_connectivity` or see when it is lost with
:func:`netsense.graphs.families.window_connectivity`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from netsense.graphs.processes import GraphProcess
from netsense.kernels import checks

__all__ = ["MobilityState", "RandomWalk", "RandomWaypoint", "disk_graph", "mobility_from_dict"]


def disk_graph(pos: np.ndarray, radius: np.ndarray | float) -> np.ndarray:
    """``adj[..., i, l] = ||p_i - p_l|| <= r_l`` (``l -> i``), no self-loops.

    Parameters
    ----------
    pos : (..., N, 2)
        Positions.
    radius : float or (N,)
        Communication radius of every sender.
    """
    d = np.linalg.norm(pos[..., :, None, :] - pos[..., None, :, :], axis=-1)  # [i, l]
    adj = d <= np.asarray(radius, dtype=float)
    N = pos.shape[-2]
    adj[..., np.arange(N), np.arange(N)] = False
    return adj


@dataclass(frozen=True)
class MobilityState:
    """Continuation state of a mobility process (picklable).

    ``pos`` (N, 2) positions; ``target`` (N, 2) waypoints, ``speed`` (N,) and ``pause``
    (N,) remaining pause steps (random waypoint only; unused by the random walk).
    """

    pos: np.ndarray
    target: np.ndarray | None = None
    speed: np.ndarray | None = None
    pause: np.ndarray | None = None


class _Mobility(GraphProcess):
    """Shared part: validation, disk graph, sampling loop."""

    num_nodes: int
    radius: float | tuple[float, ...]
    area: float

    def _check_common(self) -> None:
        checks.integer("num_nodes", self.num_nodes)
        checks.number("area", self.area)
        for name in ("speed_min", "speed_max", "pause", "step_std"):
            if hasattr(self, name):
                checks.number(name, getattr(self, name))
        r = checks.array("radius", self.radius, kind="f")
        if self.num_nodes < 2:
            raise ValueError(f"num_nodes must be >= 2, got {self.num_nodes}")
        r = np.asarray(self.radius, dtype=float)
        if r.ndim == 1:
            if r.shape != (self.num_nodes,):
                raise ValueError(f"radius must be a float or have {self.num_nodes} entries, "
                                 f"got {r.shape[0]}")
            object.__setattr__(self, "radius", tuple(float(v) for v in r))
        elif r.ndim != 0:
            raise ValueError("radius must be a float or a sequence of floats")
        if np.any(r < 0) or not np.all(np.isfinite(r)):
            raise ValueError(f"radius must be finite and >= 0, got {self.radius}")
        if not (np.isfinite(self.area) and self.area > 0):
            raise ValueError(f"area must be > 0, got {self.area}")

    @property
    def radii(self) -> np.ndarray:
        """``(N,)`` communication radius of every agent."""
        return np.broadcast_to(np.asarray(self.radius, dtype=float), (self.num_nodes,))

    def _move(self, rng: np.random.Generator, state: MobilityState) -> MobilityState:
        raise NotImplementedError  # pragma: no cover

    def trajectory(self, rng: np.random.Generator, num_steps: int, state: MobilityState
                   ) -> tuple[np.ndarray, np.ndarray, MobilityState]:
        """Positions ``(K, N, 2)``, graphs ``(K, N, N)`` and the state to continue from.

        ``G[k]`` is the disk graph of the positions at step ``k``; the agents then move.
        """
        pos = np.empty((num_steps, self.num_nodes, 2))
        for k in range(num_steps):
            pos[k] = state.pos
            state = self._move(rng, state)
        return pos, disk_graph(pos, self.radii), state

    def sample(self, rng, num_steps, state):
        _, graphs, state = self.trajectory(rng, num_steps, state)
        return graphs, state

    def sequence_with_positions(self, num_steps: int,
                                rng: np.random.Generator | int | None = None
                                ) -> tuple[np.ndarray, np.ndarray]:
        """``(positions, graphs)`` from a fresh start; same graphs as :meth:`sequence`."""
        rng = np.random.default_rng(rng)
        pos, graphs, _ = self.trajectory(rng, num_steps, self.initial_state(rng))
        return pos, graphs


@dataclass(frozen=True)
class RandomWaypoint(_Mobility):
    """Random-waypoint mobility in ``[0, area]^2`` with disk-graph links.

    Parameters
    ----------
    num_nodes : int
        ``N >= 2`` agents.
    radius : float or tuple of float
        Communication radius (per agent for directed links).
    area : float
        Side of the square.
    speed_min, speed_max : float
        Speed drawn uniformly per leg (distance per step), ``0 < speed_min <= speed_max``.
    pause : int
        Steps spent at each waypoint before the next leg.
    """

    num_nodes: int
    radius: float | tuple[float, ...] = 0.4
    area: float = 1.0
    speed_min: float = 0.01
    speed_max: float = 0.05
    pause: int = 0

    def __post_init__(self) -> None:
        self._check_common()
        if not 0 < self.speed_min <= self.speed_max:
            raise ValueError(f"speeds must satisfy 0 < speed_min <= speed_max, got "
                             f"speed_min={self.speed_min}, speed_max={self.speed_max}")
        if self.pause < 0:
            raise ValueError(f"pause must be >= 0, got {self.pause}")

    def initial_state(self, rng: np.random.Generator) -> MobilityState:
        N = self.num_nodes
        return MobilityState(pos=rng.uniform(0, self.area, (N, 2)),
                             target=rng.uniform(0, self.area, (N, 2)),
                             speed=rng.uniform(self.speed_min, self.speed_max, N),
                             pause=np.zeros(N, dtype=np.int64))

    def _move(self, rng, state):
        N = self.num_nodes
        # draws are made for every agent at every step so the stream is position-independent
        new_target = rng.uniform(0, self.area, (N, 2))
        new_speed = rng.uniform(self.speed_min, self.speed_max, N)
        delta = state.target - state.pos
        dist = np.linalg.norm(delta, axis=-1)
        moving = state.pause <= 0
        arrive = moving & (dist <= state.speed)
        frac = np.where(dist > 0, np.minimum(state.speed / np.maximum(dist, 1e-300), 1.0), 0.0)
        pos = np.where(moving[:, None], state.pos + frac[:, None] * delta, state.pos)
        pause = np.where(moving, np.where(arrive, self.pause, 0), state.pause - 1)
        target = np.where(arrive[:, None], new_target, state.target)
        speed = np.where(arrive, new_speed, state.speed)
        return MobilityState(pos=pos, target=target, speed=speed, pause=pause)

    def to_dict(self) -> dict:
        return {"kind": "random_waypoint", "num_nodes": self.num_nodes,
                "radius": self.radius, "area": self.area, "speed_min": self.speed_min,
                "speed_max": self.speed_max, "pause": self.pause}


@dataclass(frozen=True)
class RandomWalk(_Mobility):
    """Reflected Gaussian random walk in ``[0, area]^2`` with disk-graph links.

    Parameters
    ----------
    num_nodes : int
        ``N >= 2`` agents.
    radius : float or tuple of float
        Communication radius (per agent for directed links).
    area : float
        Side of the square.
    step_std : float
        Standard deviation of each coordinate's step, ``> 0``.
    """

    num_nodes: int
    radius: float | tuple[float, ...] = 0.4
    area: float = 1.0
    step_std: float = 0.03

    def __post_init__(self) -> None:
        self._check_common()
        if not self.step_std > 0:
            raise ValueError(f"step_std must be > 0, got {self.step_std}")

    def initial_state(self, rng: np.random.Generator) -> MobilityState:
        return MobilityState(pos=rng.uniform(0, self.area, (self.num_nodes, 2)))

    def _move(self, rng, state):
        p = state.pos + rng.normal(0.0, self.step_std, state.pos.shape)
        L = self.area
        p = np.abs(p)  # reflect at 0
        p = L - np.abs(L - p)  # reflect at L
        return MobilityState(pos=np.clip(p, 0.0, L))

    def to_dict(self) -> dict:
        return {"kind": "random_walk", "num_nodes": self.num_nodes, "radius": self.radius,
                "area": self.area, "step_std": self.step_std}


def mobility_from_dict(spec: dict[str, Any]) -> RandomWaypoint | RandomWalk:
    """Build a mobility process from its ``to_dict`` form.

    Raises
    ------
    ValueError
        On an unknown ``kind`` or field (named in the message).
    """
    spec = dict(spec)
    kind = spec.pop("kind", None)
    classes = {"random_waypoint": RandomWaypoint, "random_walk": RandomWalk}
    if kind not in classes:
        raise ValueError(f"mobility kind must be one of {sorted(classes)}, got {kind!r}")
    cls = classes[kind]
    allowed = set(cls.__dataclass_fields__)
    extra = set(spec) - allowed
    if extra:
        raise ValueError(f"mobility kind {kind!r}: unknown fields {sorted(extra)}; "
                         f"allowed {sorted(allowed)}")
    if "num_nodes" not in spec:
        raise ValueError(f"mobility kind {kind!r}: missing field 'num_nodes'")
    if isinstance(spec.get("radius"), list):
        spec["radius"] = tuple(spec["radius"])
    return cls(**spec)
