"""Random measurement (or message) drops: Bernoulli and Gilbert-Elliott arrival models.

Both models implement :class:`netsense.sensing.arrivals.ArrivalModel`; ``True`` in a drawn
array means "arrived" (the indicator ``gamma_t = 1`` of eq. (1) of the robust-estimation
paper), ``False`` means "dropped".

* :class:`BernoulliArrivals` -- independent arrivals with probability ``p`` at every step
  and every entry (the i.i.d. case of Lemma 4 / Theorem 5 of the robust-estimation paper;
  Sinopoli et al. 2004).
* :class:`GilbertElliottArrivals` -- bursty losses from a two-state Markov channel
  (Good/Bad) with a loss probability per state (the Markov-chain case of Lemma 4 / Theorem 5
  when ``loss_good = 0`` and ``loss_bad = 1``).

Each entry of ``shape`` is an independent channel; a sampler draws one step at a time and
keeps its own channel state, so it is cheap to pickle and to reuse inside environments.
With ``scope = "sender"`` (message arrivals, ``shape = (receivers, senders)``) there is one
channel per *sender*, shared by all its out-links: entry ``[i, l]`` is the draw of sender
``l`` (a sender's radio in a fade loses every message it sends, and its delivery history
tells it so).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from netsense.sensing.arrivals import AlwaysArrive, ArrivalModel, ArrivalSampler

__all__ = [
    "BernoulliArrivals",
    "GilbertElliottArrivals",
    "arrival_from_dict",
]


def _probability(owner: str, name: str, value: Any) -> float:
    """Return ``value`` as a float in [0, 1] or raise a ValueError naming the field."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{owner}.{name} must be a number in [0, 1], got {value!r}")
    value = float(value)
    if not (np.isfinite(value) and 0.0 <= value <= 1.0):
        raise ValueError(f"{owner}.{name} must be a number in [0, 1], got {value!r}")
    return value


SCOPES = ("link", "sender")


def _scope(owner: str, value: Any) -> str:
    if value not in SCOPES:
        raise ValueError(f"{owner}.scope must be one of {SCOPES}, got {value!r}")
    return value


class _PerSender(ArrivalSampler):
    """One channel per sender (last axis), broadcast over the receivers."""

    def __init__(self, inner: ArrivalSampler, shape: tuple[int, ...]) -> None:
        self.inner = inner
        self.shape = shape

    def next(self) -> np.ndarray:
        return np.broadcast_to(self.inner.next(), self.shape).copy()

    def redraw(self, rng: np.random.Generator) -> _PerSender:
        """The senders' channels redrawn as one sampler's (:meth:`ArrivalSampler.redraw`)."""
        return _PerSender(self.inner.redraw(rng), self.shape)


def _scoped(make, rng: np.random.Generator, shape: tuple[int, ...], scope: str
            ) -> ArrivalSampler:
    if scope == "link" or len(shape) < 2:
        return make(rng, shape)
    return _PerSender(make(rng, shape[-1:]), shape)


def _shape(shape: Any) -> tuple[int, ...]:
    if isinstance(shape, (int, np.integer)):
        shape = (int(shape),)
    shape = tuple(int(s) for s in shape)
    if any(s < 0 for s in shape):
        raise ValueError(f"shape must hold non-negative sizes, got {shape}")
    return shape


# --------------------------------------------------------------------------- Bernoulli
class BernoulliSampler(ArrivalSampler):
    """Draws i.i.d. arrival indicators with ``P(arrival) = p``."""

    def __init__(self, p: float, rng: np.random.Generator, shape: tuple[int, ...]) -> None:
        self.p = p
        self.rng = rng
        self.shape = shape

    def next(self) -> np.ndarray:
        return self.rng.random(self.shape) < self.p

    def redraw(self, rng: np.random.Generator) -> BernoulliSampler:
        """Independent steps: the same law with ``rng``."""
        return BernoulliSampler(self.p, rng, self.shape)


@dataclass(frozen=True)
class BernoulliArrivals(ArrivalModel):
    """Independent arrivals: ``gamma_t ~ Bernoulli(p)`` for every entry and step.

    Parameters
    ----------
    p : float
        Arrival probability in [0, 1] (the paper's ``E{gamma_t}``; 0.8 in section IV).
        The loss rate is ``1 - p``; the mean burst length of consecutive drops is
        ``1 / p`` (geometric).
    scope : {"link", "sender"}, default "link"
        One channel per entry, or (messages) one per sender (module docstring).
    """

    p: float
    scope: str = "link"

    def __post_init__(self) -> None:
        object.__setattr__(self, "p", _probability("BernoulliArrivals", "p", self.p))
        _scope("BernoulliArrivals", self.scope)

    @property
    def loss_rate(self) -> float:
        """Stationary fraction of dropped entries, ``1 - p``."""
        return 1.0 - self.p

    @property
    def mean_burst_length(self) -> float:
        """Mean length of a run of consecutive drops, ``1 / p`` (``inf`` if ``p = 0``)."""
        return float("inf") if self.p == 0 else 1.0 / self.p

    def sampler(self, rng: np.random.Generator, shape: tuple[int, ...]) -> ArrivalSampler:
        return _scoped(lambda g, sh: BernoulliSampler(self.p, g, sh), rng, _shape(shape),
                       self.scope)

    def to_dict(self) -> dict:
        out = {"kind": "bernoulli", "p": self.p}
        if self.scope != "link":
            out["scope"] = self.scope
        return out


# ------------------------------------------------------------------- Gilbert-Elliott
class GilbertElliottSampler(ArrivalSampler):
    """Two-state Markov channel; ``bad`` holds each entry's current channel state.

    At each ``next()`` the arrival of every entry is drawn from the loss probability of its
    current state, then the state moves on (Good -> Bad with ``p_good_to_bad``, Bad -> Good
    with ``p_bad_to_good``).
    """

    def __init__(self, model: GilbertElliottArrivals, rng: np.random.Generator,
                 shape: tuple[int, ...]) -> None:
        self.model = model
        self.rng = rng
        self.shape = shape
        if model.start == "stationary":
            self.bad = rng.random(shape) < model.stationary_bad
        else:
            self.bad = np.full(shape, model.start == "bad")

    def next(self) -> np.ndarray:
        m = self.model
        loss = np.where(self.bad, m.loss_bad, m.loss_good)
        arrived = self.rng.random(self.shape) >= loss
        u = self.rng.random(self.shape)
        self._before = self.bad  # the state of the step just drawn (for redraw)
        self.bad = self._move(self.bad, u)
        return arrived

    def _move(self, bad: np.ndarray, u: np.ndarray) -> np.ndarray:
        m = self.model
        return np.where(bad, u >= m.p_bad_to_good, u < m.p_good_to_bad)

    def redraw(self, rng: np.random.Generator) -> GilbertElliottSampler:
        """The channel states of the last step drawn, moved on with ``rng``."""
        if not hasattr(self, "_before"):
            raise ValueError("redraw needs a sampler that has drawn a step")
        out = object.__new__(GilbertElliottSampler)
        out.model, out.rng, out.shape = self.model, rng, self.shape
        out._before = self._before
        out.bad = self._move(self._before, rng.random(self.shape))
        return out


@dataclass(frozen=True)
class GilbertElliottArrivals(ArrivalModel):
    """Bursty losses from a Gilbert-Elliott two-state Markov channel.

    Parameters
    ----------
    p_good_to_bad : float
        Probability of moving from the Good to the Bad state at one step.
    p_bad_to_good : float
        Probability of moving from the Bad to the Good state at one step.
    loss_good : float, default 0.0
        Drop probability while Good.
    loss_bad : float, default 1.0
        Drop probability while Bad. With the defaults this is the Gilbert channel, i.e. the
        Markov arrival process of Lemma 4 / Theorem 5 with ``P(drop | arrived) =
        p_good_to_bad`` and ``P(arrive | dropped) = p_bad_to_good``.
    start : {"stationary", "good", "bad"}, default "stationary"
        Initial channel state of every entry; "stationary" draws it from the stationary law
        so the arrival process is stationary from the first step.
    scope : {"link", "sender"}, default "link"
        One channel per entry, or (messages) one per sender, shared by its out-links
        (module docstring).

    Notes
    -----
    With ``pi_B = p_gb / (p_gb + p_bg)`` the stationary loss rate is
    ``(1 - pi_B) loss_good + pi_B loss_bad``. For the Gilbert channel (``loss_good = 0``,
    ``loss_bad = 1``) the drop bursts are geometric with mean ``1 / p_bad_to_good``.
    """

    p_good_to_bad: float
    p_bad_to_good: float
    loss_good: float = 0.0
    loss_bad: float = 1.0
    start: str = "stationary"
    scope: str = "link"

    def __post_init__(self) -> None:
        for name in ("p_good_to_bad", "p_bad_to_good", "loss_good", "loss_bad"):
            value = _probability("GilbertElliottArrivals", name, getattr(self, name))
            object.__setattr__(self, name, value)
        if self.p_good_to_bad + self.p_bad_to_good == 0:
            raise ValueError("GilbertElliottArrivals.p_good_to_bad and p_bad_to_good must not "
                             "both be 0 (the chain would have no stationary law)")
        if self.start not in ("stationary", "good", "bad"):
            raise ValueError("GilbertElliottArrivals.start must be 'stationary', 'good' or "
                             f"'bad', got {self.start!r}")
        _scope("GilbertElliottArrivals", self.scope)

    @property
    def stationary_bad(self) -> float:
        """Stationary probability of the Bad state, ``p_gb / (p_gb + p_bg)``."""
        return self.p_good_to_bad / (self.p_good_to_bad + self.p_bad_to_good)

    @property
    def loss_rate(self) -> float:
        """Stationary drop probability."""
        pb = self.stationary_bad
        return (1.0 - pb) * self.loss_good + pb * self.loss_bad

    @property
    def mean_burst_length(self) -> float:
        """Mean run of consecutive drops, ``1 / p_bad_to_good``.

        Exact only for the Gilbert channel (``loss_good = 0``, ``loss_bad = 1``); raises
        ValueError otherwise, where drop runs are not geometric.
        """
        if self.loss_good != 0.0 or self.loss_bad != 1.0:
            raise ValueError("mean_burst_length has a closed form only for loss_good = 0 and "
                             "loss_bad = 1 (the Gilbert channel)")
        return float("inf") if self.p_bad_to_good == 0 else 1.0 / self.p_bad_to_good

    def sampler(self, rng: np.random.Generator, shape: tuple[int, ...]) -> ArrivalSampler:
        return _scoped(lambda g, sh: GilbertElliottSampler(self, g, sh), rng, _shape(shape),
                       self.scope)

    def to_dict(self) -> dict:
        out = {
            "kind": "gilbert_elliott",
            "p_good_to_bad": self.p_good_to_bad,
            "p_bad_to_good": self.p_bad_to_good,
            "loss_good": self.loss_good,
            "loss_bad": self.loss_bad,
            "start": self.start,
        }
        if self.scope != "link":
            out["scope"] = self.scope
        return out


# --------------------------------------------------------------------------- factory
_FIELDS = {
    "always": ((), ()),
    "bernoulli": (("p",), ("scope",)),
    "gilbert_elliott": (("p_good_to_bad", "p_bad_to_good"),
                        ("loss_good", "loss_bad", "start", "scope")),
}


def arrival_from_dict(spec: dict) -> ArrivalModel:
    """Build an arrival model from its ``to_dict()`` form.

    Parameters
    ----------
    spec : dict
        ``{"kind": "bernoulli", "p": 0.8}``, ``{"kind": "gilbert_elliott",
        "p_good_to_bad": ..., "p_bad_to_good": ..., ["loss_good", "loss_bad", "start"]}`` or
        ``{"kind": "always"}``; Bernoulli and Gilbert-Elliott take ``"scope": "sender"``
        (one channel per sender); ``{"kind": "multirate", ...}`` is dispatched (lazily) to
        :func:`netsense.sensing.multirate.multirate_from_dict`.

    Raises
    ------
    ValueError
        If ``spec`` is not a dict, ``kind`` is unknown, a required field is missing, an
        unknown field is present, or a value is out of range; the message names the field.
    """
    if not isinstance(spec, dict):
        raise ValueError(f"arrival spec must be a dict, got {type(spec).__name__}")
    kind = spec.get("kind")
    if kind == "multirate":
        from netsense.sensing.multirate import multirate_from_dict

        return multirate_from_dict(spec)
    if kind not in _FIELDS:
        raise ValueError(f"arrival spec field 'kind' must be one of "
                         f"{sorted([*_FIELDS, 'multirate'])}, got {kind!r}")
    required, optional = _FIELDS[kind]
    for name in required:
        if name not in spec:
            raise ValueError(f"arrival spec of kind {kind!r} is missing field {name!r}")
    unknown = set(spec) - {"kind", *required, *optional}
    if unknown:
        raise ValueError(f"arrival spec of kind {kind!r} has unknown field(s) "
                         f"{sorted(unknown)}; allowed: {sorted((*required, *optional))}")
    kwargs = {k: v for k, v in spec.items() if k != "kind"}
    if kind == "always":
        return AlwaysArrive()
    if kind == "bernoulli":
        return BernoulliArrivals(**kwargs)
    return GilbertElliottArrivals(**kwargs)
