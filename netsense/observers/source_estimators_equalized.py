"""Equalized-recovery observer as the local estimator of source nodes, with delayed data.

:class:`EqualizedSource` plugs into :class:`netsense.observers.source.SourceEstimator`:
each source agent ``j`` (``n_j > 0``) runs an :class:`EqualizedRecoveryEstimator` for its
own substate, designed for ``(A_jj, C_jj)`` of Lemma 1's coordinates and a
:class:`~netsense.sensing.delays.DelayLanguage`. Its measurement ``y_j[k]`` reaches it
through a :class:`~netsense.sensing.delays.DelayChannel` drawing words of that language
(a measurement flagged as not arrived by the environment is lost for good). The upstream
part ``sum_{q<j} C_jq z^(q)`` of ``y_j`` is removed with the agent's own estimates of the
upstream substates at the measurement's time, and the coupling ``sum_{q<j} A_jq z^(q)`` is
the known input of eq. (4), which the distributed observer's open-loop step already adds.

Guarantee: the bound :attr:`EqualizedSource.bounds` holds for a source without upstream
substates (and for any source if ``eta_w`` covers the upstream estimation errors, with
``W = I``); otherwise it is indicative only.

Use: ``FreshnessObserver(design, source_estimator=EqualizedSource(language, eta_v=0.05))``
or, in an environment model, ``source_estimator=functools.partial(EqualizedSource,
language, eta_v=0.05)`` (picklable).
"""

from __future__ import annotations

import numpy as np

from netsense.estimators.equalized import EqualizedRecoveryEstimator
from netsense.estimators.equalized_design import EqualizedDesign, EqualizedProblem
from netsense.estimators.equalized_design import design as design_equalized
from netsense.observers.source import Rngs, SourceEstimator
from netsense.sensing.delays import DelayChannel, DelayLanguage
from netsense.systems.design import ObserverDesign

__all__ = ["EqualizedSource"]


class EqualizedSource(SourceEstimator):
    """Source-node estimator: eqs. (4)-(5) on each source's own substate.

    Parameters
    ----------
    language : DelayLanguage
        Delay patterns the design must cover and the channel draws from.
    eta_v : float
        Bound on each entry of the measurement noise.
    eta_w : float
        Bound on a disturbance entering every own-substate coordinate (``W = I``); 0 for
        none.
    mu1 : float, optional
        Fixed equalized recovery level (default: searched, see
        :func:`~netsense.estimators.equalized_design.design`).
    channel : DelayChannel, optional
        Run-time delay model; default ``language.channel()`` (uniform words, data after
        its block lost).
    """

    uses_rng = True

    def __init__(self, language: DelayLanguage, eta_v: float, *, eta_w: float = 0.0,
                 mu1: float | None = None, channel: DelayChannel | None = None) -> None:
        if not isinstance(language, DelayLanguage):
            raise ValueError(f"language must be a DelayLanguage, got {type(language).__name__}")
        for name, val in (("eta_v", eta_v), ("eta_w", eta_w)):
            if not np.isfinite(val) or val < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {val!r}")
        if channel is not None and channel.language.T != language.T:
            raise ValueError(f"channel horizon {channel.language.T} differs from the "
                             f"language horizon {language.T}")
        self.language, self.eta_v, self.eta_w, self.mu1 = language, eta_v, eta_w, mu1
        self.channel = channel or language.channel()
        self._designs: dict[int, EqualizedDesign] = {}
        self._design_key: tuple | None = None

    @staticmethod
    def _key(design: ObserverDesign) -> tuple:
        """What the designs depend on: every source block's ``(A_jj, C_jj)``. A content key
        (not ``id(design)``) survives pickling and deep copies, and never mistakes a new
        design object for an old one whose id was reused."""
        d = design.decomposition
        return tuple((j, d.A_jj(j).shape, d.A_jj(j).tobytes(), d.C_jj(j).shape,
                      d.C_jj(j).tobytes()) for j in range(d.num_agents) if d.sizes[j])

    def designs(self, design: ObserverDesign) -> dict[int, EqualizedDesign]:
        """The equalized design of every source agent (computed once per observer design)."""
        key = self._key(design)
        if self._design_key != key:
            d = design.decomposition
            out = {}
            for j in range(d.num_agents):
                nj = d.sizes[j]
                if nj == 0:
                    continue
                P = EqualizedProblem(A=d.A_jj(j), C=d.C_jj(j), language=self.language,
                                     W=np.eye(nj) if self.eta_w else None, eta_w=self.eta_w,
                                     eta_v=self.eta_v)
                out[j] = design_equalized(P, mu1=self.mu1)
            self._designs, self._design_key = out, key
        return self._designs

    def reset(self, design: ObserverDesign, batch_size: int,
              rng: Rngs = None) -> None:
        """Fresh estimators and delay samplers for every member (``rng``: one generator
        shared by the batch, or one per member, see :mod:`netsense.observers.source`)."""
        super().reset(design, batch_size, rng)
        self.dec = design.decomposition
        self.designs(design)
        self.est: list[dict[int, EqualizedRecoveryEstimator]] = [{}] * batch_size
        self.samplers: list[dict] = [{}] * batch_size
        self._buf: list[dict[int, dict[int, np.ndarray]]] = [{}] * batch_size
        self.k = np.zeros(batch_size, dtype=np.int64)
        self.reset_members(np.ones(batch_size, dtype=bool), rng)

    def reset_members(self, members: np.ndarray, rng: Rngs = None) -> None:
        """Restart the selected members at ``k = 0`` (new estimators, samplers, buffers)."""
        members = np.asarray(members, dtype=bool)
        if members.shape != self.k.shape:
            raise ValueError(f"members must have shape {self.k.shape}, got {members.shape}")
        rngs = self.member_rngs(rng, self.batch_size)
        ds = self._designs
        for b in np.flatnonzero(members):
            self.est[b] = {j: EqualizedRecoveryEstimator(d) for j, d in ds.items()}
            self.samplers[b] = {j: self.channel.sampler(rngs[b]) for j in ds}
            self._buf[b] = {j: {} for j in ds}
            self.k[b] = 0

    def take(self, members: np.ndarray, rng: Rngs = None) -> EqualizedSource:
        """Copies of the selected members' estimators, delay samplers and buffers; with
        ``rng`` (one generator per new member) the samplers draw their later words from
        it (the delays already drawn for measurements taken are kept)."""
        import copy

        members = np.asarray(members, dtype=np.int64)
        out = copy.copy(self)
        out.batch_size = len(members)
        parts = [copy.deepcopy((self.est[b], self.samplers[b], self._buf[b]))
                 for b in members]
        out.est = [e for e, _, _ in parts]
        out.samplers = [s for _, s, _ in parts]
        out._buf = [f for _, _, f in parts]
        out.k = self.k[members].copy()
        if rng is not None:
            for gen, samplers in zip(self.member_rngs(rng, len(members)), out.samplers,
                                     strict=True):
                for smp in samplers.values():
                    smp.rng = gen
        return out

    @property
    def bounds(self) -> np.ndarray:
        """``(B, N)`` guaranteed bounds on each source's own-substate error (``nan`` for
        agents without a substate); see the module docstring for when they hold."""
        out = np.full((self.batch_size, self.dec.num_agents), np.nan)
        for b, ests in enumerate(self.est):
            for j, e in ests.items():
                out[b, j] = e.bound
        return out

    def correction(self, k: int | np.ndarray, Z: np.ndarray, y: np.ndarray,
                   arrived: np.ndarray | None) -> np.ndarray:
        kk = self.member_times(k, len(self.est))
        if not np.array_equal(kk, self.k):
            raise ValueError(f"EqualizedSource expected steps k = {self.k.tolist()}, got "
                             f"{kk.tolist()}; reset it together with the observer")
        out = np.zeros_like(Z)
        for b, ests in enumerate(self.est):
            kb = int(kk[b])
            for j, est in ests.items():
                blk = self.dec.block(j)
                Cb = self.dec.C_bar[j]
                x_hat = Z[b, j, blk]
                if kb == 0:
                    est.reset(x_hat)
                est.estimate = x_hat.copy()
                if arrived is None or arrived[b, j]:
                    up = Cb[:, : blk.start] @ Z[b, j, : blk.start]
                    self._buf[b][j][kb] = y[b, j, : Cb.shape[0]] - up
                got = {i: self._buf[b][j].pop(i) for i in self.samplers[b][j].next()
                       if i in self._buf[b][j]}
                out[b, j, blk] = est.step(got) - self.dec.A_jj(j) @ x_hat
        self.k += 1
        return out
