"""Delay languages: finite-length patterns of delayed and missing observations.

A *word* ``tau(0) tau(1) ... tau(T-1)`` says that the measurement of step ``i`` of a
horizon of length ``T`` arrives at step ``i + tau(i)``; ``i + tau(i) >= T`` means it
arrives after the horizon, which the estimator treats as *missing* (section II-A of the
equalized-recovery paper, Hassaan, Shen and Yong). A :class:`DelayLanguage` is a set of
such words. Its image under eq. (2) is the event-based language of Definitions 2-4, whose
repeated event sequences are removed to give the reduced language ``L^E'``
(:class:`EventLanguage`), organised as a tree of prefixes (Definition 6,
:class:`PrefixTree`). :class:`DelayChannel` draws words at run time and reports, step by
step, which past measurements become available.

In strings, ``0``-``9`` are delays and ``x`` marks a measurement that never arrives.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from netsense.kernels import checks

__all__ = ["DelayChannel", "DelayLanguage", "EventLanguage", "PrefixTree", "event_set",
           "event_string"]


def event_string(k: int, j: int) -> str:
    """Event ``e_{k,j} = binary(j, k+1)`` of Definition 2 (digit ``l`` is ``d_l``)."""
    if k < 0 or not 0 <= j < 2 ** (k + 1):
        raise ValueError(f"event index j must be in [0, 2^(k+1) - 1] for k = {k}, got {j}")
    return format(j, f"0{k + 1}b")


def event_set(k: int) -> tuple[str, ...]:
    """Event set ``e_k`` of Definition 3: all ``2^(k+1)`` events of step ``k``."""
    return tuple(event_string(k, j) for j in range(2 ** (k + 1)))


#: Most words a language may hold (its words are enumerated, and the equalized design
#: grows with them).
MAX_WORDS = 100_000


def _check_size(count: int, what: str) -> None:
    if count > MAX_WORDS:
        digits = len(str(count))
        raise ValueError(f"{what} holds {count if digits < 10 else f'~1e{digits - 1}'} words; "
                         f"at most {MAX_WORDS} are supported (smaller m or T)")


def _parse_word(word: str | Sequence[int], T: int | None) -> tuple[int, ...]:
    if isinstance(word, str):
        if T is None:
            T = len(word)
        try:
            return tuple(T if ch in "xX" else int(ch) for ch in word)
        except ValueError:
            raise ValueError(f"word {word!r} may hold only digits 0-9 and 'x' (missing)") from None
    out = []
    for tau in word:
        if isinstance(tau, bool) or not isinstance(tau, (int, np.integer)):
            raise ValueError(f"delays must be integers >= 0, got {tau!r} in word {word!r}")
        out.append(int(tau))
    return tuple(out)


@dataclass(frozen=True)
class DelayLanguage:
    """Fixed-length delay language ``L`` of section II-A.

    Parameters
    ----------
    words : tuple of tuple of int
        The words ``W_alpha = tau(0) ... tau(T-1)``, each of length ``T``, all distinct.
    T : int
        Horizon (recovery time).
    tau_bar : int, optional
        Known delay bound; every ``tau(i)`` must satisfy ``tau(i) <= tau_bar``. Defaults to
        the largest delay in ``words``.
    """

    words: tuple[tuple[int, ...], ...]
    T: int
    tau_bar: int | None = None

    def __post_init__(self) -> None:
        if isinstance(self.T, bool) or not isinstance(self.T, (int, np.integer)) or self.T < 1:
            raise ValueError(f"DelayLanguage.T must be an integer >= 1, got {self.T!r}")
        words = tuple(_parse_word(w, self.T) for w in self.words)
        if not words:
            raise ValueError("DelayLanguage.words must hold at least one word")
        for w in words:
            if len(w) != self.T:
                raise ValueError(f"every word must have length T = {self.T}, got {w} "
                                 f"of length {len(w)}")
            if min(w) < 0:
                raise ValueError(f"delays must be >= 0, got word {w}")
        if len(set(words)) != len(words):
            dup = next(w for w in words if words.count(w) > 1)
            raise ValueError(f"DelayLanguage.words must be distinct; {dup} is repeated")
        top = max(max(w) for w in words)
        tau_bar = top if self.tau_bar is None else int(self.tau_bar)
        if top > tau_bar:
            raise ValueError(f"every delay must satisfy tau(i) <= tau_bar = {tau_bar}; "
                             f"the language holds a delay {top}")
        object.__setattr__(self, "T", int(self.T))
        object.__setattr__(self, "words", words)
        object.__setattr__(self, "tau_bar", tau_bar)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_words(cls, words: Iterable[str | Sequence[int]],
                   tau_bar: int | None = None) -> DelayLanguage:
        """Explicit word list, e.g. ``["21210"]`` or ``["060000", "006000"]``."""
        parsed = [_parse_word(w, None if not isinstance(w, str) else len(w)) for w in words]
        if not parsed:
            raise ValueError("from_words needs at least one word")
        return cls(words=tuple(parsed), T=len(parsed[0]), tau_bar=tau_bar)

    @classmethod
    def each_delayed_at_most(cls, m: int, T: int) -> DelayLanguage:
        """"Each observation is delayed by at most ``m`` steps": all of ``{0..m}^T``."""
        m, T = checks.integer("m", m, 0), checks.integer("T", T, 1)
        _check_size((m + 1) ** T, f"each_delayed_at_most(m={m}, T={T})")
        return cls(words=tuple(itertools.product(range(m + 1), repeat=T)), T=T, tau_bar=m)

    @classmethod
    def at_most_missing(cls, m: int, T: int) -> DelayLanguage:
        """"At most ``m`` of the ``T`` observations are missing" (no other delays).

        A missing observation is written as the delay ``T`` (it never arrives in the horizon).
        """
        T = checks.integer("T", T, 1)
        m = checks.integer("m", m, 0, T)
        _check_size(sum(math.comb(T, i) for i in range(m + 1)), f"at_most_missing(m={m}, "
                    f"T={T})")
        words = [w for w in itertools.product((0, T), repeat=T)
                 if sum(t > 0 for t in w) <= m]
        return cls(words=tuple(words), T=T, tau_bar=T)

    # ------------------------------------------------------------------ events
    def event_matrix(self, word: Sequence[int]) -> np.ndarray:
        """Event matrix ``E_alpha`` of section III-B: ``E[k, i] = 1`` iff ``tau(i) <= k - i``."""
        w = np.asarray(_parse_word(word, self.T))
        if w.shape != (self.T,):
            raise ValueError(f"word must have length T = {self.T}, got {tuple(w)}")
        k = np.arange(self.T)[:, None]
        i = np.arange(self.T)[None, :]
        return ((i <= k) & (w[None, :] <= k - i)).astype(np.int8)

    def event_indices(self, word: Sequence[int]) -> tuple[int, ...]:
        """Subscripts ``j_k = sum_l 2^l 1[tau(k-l) <= l]`` of eq. (2)-(3)."""
        w = _parse_word(word, self.T)
        return tuple(sum(2 ** ell for ell in range(k + 1) if w[k - ell] <= ell)
                     for k in range(self.T))

    def event_language(self) -> EventLanguage:
        """Reduced event-based language ``L^E'`` (unique event sequences, in first-seen order)."""
        seqs: list[tuple[int, ...]] = []
        index: dict[tuple[int, ...], int] = {}
        mapping = []
        for w in self.words:
            e = self.event_indices(w)
            if e not in index:
                index[e] = len(seqs)
                seqs.append(e)
            mapping.append(index[e])
        return EventLanguage(T=self.T, sequences=tuple(seqs), word_to_sequence=tuple(mapping))

    def first_delayed(self) -> DelayLanguage:
        """Sub-language of words whose first observation is late (``tau(0) >= 1``).

        The recovery language of the implementation strategy (section III-B3): it is used
        from the step at which a delayed or missing observation is detected.
        """
        words = tuple(w for w in self.words if w[0] >= 1)
        if not words:
            raise ValueError("the language has no word with tau(0) >= 1")
        return DelayLanguage(words=words, T=self.T, tau_bar=self.tau_bar)

    def channel(self, weights: Sequence[float] | None = None, *,
                truncate: bool = True) -> DelayChannel:
        """A :class:`DelayChannel` drawing words of this language (see there)."""
        return DelayChannel(self, None if weights is None else tuple(weights), truncate)


@dataclass(frozen=True)
class EventLanguage:
    """Reduced event-based language ``L^E'`` (Definitions 2-4 and eq. (2)).

    Parameters
    ----------
    T : int
        Horizon.
    sequences : tuple of tuple of int
        The unique event sequences ``E'_alpha`` as subscripts ``(j_0, ..., j_{T-1})``.
    word_to_sequence : tuple of int
        For each word of the delay language, the index of its event sequence.
    """

    T: int
    sequences: tuple[tuple[int, ...], ...]
    word_to_sequence: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        for s in self.sequences:
            if len(s) != self.T or any(not 0 <= j < 2 ** (k + 1) for k, j in enumerate(s)):
                raise ValueError(f"event sequence {s} is not a sequence of T = {self.T} "
                                 "events with 0 <= j_k < 2^(k+1)")

    def __len__(self) -> int:
        return len(self.sequences)

    def strings(self, alpha: int) -> tuple[str, ...]:
        """Events of ``E'_alpha`` as bit strings ``d_0 ... d_k``."""
        return tuple(event_string(k, j) for k, j in enumerate(self.sequences[alpha]))

    def event_matrix(self, alpha: int) -> np.ndarray:
        """Lower-triangular event matrix ``E_alpha`` (row ``k`` = digits of ``e_{k,j_k}``)."""
        E = np.zeros((self.T, self.T), dtype=np.int8)
        for k, s in enumerate(self.strings(alpha)):
            E[k, : k + 1] = [int(c) for c in s]
        return E

    def prefixes(self, alpha: int) -> tuple[tuple[int, ...], ...]:
        """``Pref(E'_alpha)`` of Definition 6: the non-empty prefixes, shortest first."""
        s = self.sequences[alpha]
        return tuple(s[:i] for i in range(1, self.T + 1))

    def prefix_tree(self) -> PrefixTree:
        """The prefixes of all sequences as a tree (shared prefixes share a node)."""
        return PrefixTree.build(self)


@dataclass(frozen=True)
class PrefixTree:
    """Tree of the prefixes of ``L^E'``: node 0 is the empty prefix, depth ``k`` nodes are
    prefixes ``e_{0,j_0} ... e_{k-1,j_{k-1}}`` and leaves are the full sequences.

    Attributes
    ----------
    prefixes : tuple of tuple of int
        Prefix (event subscripts) of each node.
    parent : tuple of int
        Parent node (``-1`` for the root).
    children : tuple of dict
        ``children[node][j]`` is the node reached by observing event ``e_{depth, j}``.
    sequences : tuple of tuple of int
        Indices ``alpha`` of the sequences passing through each node.
    """

    prefixes: tuple[tuple[int, ...], ...]
    parent: tuple[int, ...]
    children: tuple[dict[int, int], ...]
    sequences: tuple[tuple[int, ...], ...]
    index: dict[tuple[int, ...], int] = field(repr=False, default_factory=dict)

    @classmethod
    def build(cls, language: EventLanguage) -> PrefixTree:
        prefixes: list[tuple[int, ...]] = [()]
        parent, children, members = [-1], [{}], [list(range(len(language)))]
        index = {(): 0}
        for alpha, seq in enumerate(language.sequences):
            node = 0
            for k, j in enumerate(seq):
                pre = seq[: k + 1]
                if pre not in index:
                    index[pre] = len(prefixes)
                    prefixes.append(pre)
                    parent.append(node)
                    children.append({})
                    members.append([])
                    children[node][j] = index[pre]
                node = index[pre]
                members[node].append(alpha)
        return cls(tuple(prefixes), tuple(parent), tuple(children),
                   tuple(tuple(m) for m in members), index)

    def __len__(self) -> int:
        return len(self.prefixes)

    def depth(self, node: int) -> int:
        return len(self.prefixes[node])

    def path(self, alpha_sequence: Sequence[int]) -> list[int]:
        """Nodes from the root to the leaf of a full event sequence."""
        return [self.index[tuple(alpha_sequence[:k])] for k in range(len(alpha_sequence) + 1)]


@dataclass(frozen=True)
class DelayChannel:
    """Run-time delay model: one word drawn per block of ``T`` steps.

    Parameters
    ----------
    language : DelayLanguage
        Words are drawn from ``language.words`` at steps ``0, T, 2T, ...``.
    weights : tuple of float, optional
        Drawing probabilities of the words (uniform by default).
    truncate : bool
        If true (the paper's semantics) a measurement whose arrival falls after its block
        is lost; if false it still arrives later (a stream of delays, as needed when an
        estimator's windows are not aligned with the blocks).
    """

    language: DelayLanguage
    weights: tuple[float, ...] | None = None
    truncate: bool = True

    def __post_init__(self) -> None:
        if self.weights is not None:
            w = np.asarray(self.weights, dtype=float)
            if w.shape != (len(self.language.words),) or np.any(w < 0) or w.sum() <= 0:
                raise ValueError(f"weights must be {len(self.language.words)} non-negative "
                                 f"numbers with a positive sum, got {self.weights!r}")

    def sampler(self, rng: np.random.Generator) -> DelaySampler:
        return DelaySampler(self, rng)


class DelaySampler:
    """Stateful, picklable draw of arrivals: ``next()`` returns the absolute indices of the
    measurements that become available at the current step (then advances one step)."""

    def __init__(self, channel: DelayChannel, rng: np.random.Generator) -> None:
        self.channel = channel
        self.rng = rng
        self.k = 0
        self.words: list[tuple[int, ...]] = []
        self._pending: dict[int, list[int]] = {}
        w = channel.weights
        self._p = None if w is None else np.asarray(w, float) / np.sum(w)

    def next(self) -> tuple[int, ...]:
        lang = self.channel.language
        T = lang.T
        if self.k % T == 0:
            word = lang.words[int(self.rng.choice(len(lang.words), p=self._p))]
            self.words.append(word)
            for t, tau in enumerate(word):
                if t + tau < T or not self.channel.truncate:
                    self._pending.setdefault(self.k + t + tau, []).append(self.k + t)
        out = tuple(sorted(self._pending.pop(self.k, [])))
        self.k += 1
        return out
