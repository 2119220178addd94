"""Local estimators of the source nodes (the output-injection part of eq. (7)).

A distributed observer propagates every agent's estimate with the open-loop part of
eqs. (7), (10), (12) (see :func:`netsense.kernels.update.propagate`) and then adds, for each
source ``j``, a *correction* on its own block. The paper's correction is the fixed gain
``L_j (y_j - C_bar_j z_j)`` (:class:`LuenbergerSource`); other estimators (KFIO, RSEIO,
equalized recovery, ...) plug in here by subclassing :class:`SourceEstimator`.

The contract of ``correction``: given the estimates ``Z`` at time ``k`` (before the
update), the padded measurements and their arrival flags, return the ``(B, N, n)`` array
added to the open-loop propagation. Rows outside agent ``j``'s own block must be zero for
agent ``j`` (``own_block_mask`` helps); the new own-block value of source ``j`` is then
``(A_bar z_j)^{(j)} + correction_j^{(j)}`` — i.e. any estimator in predictor form.

Per-member state. The ``B`` copies are independent runs that need not be in step: the
batched environment core resets single members (auto-reset), so ``k`` is either one int
(every member at the same time, as in the observers) or a ``(B,)`` array of per-member
time indices, and :meth:`SourceEstimator.reset_members` restarts the selected members
only. A stateful estimator keeps its state with a leading batch axis (or per member), so
that member ``b`` of a batch equals a single run with the same inputs. ``rng`` may be one
generator shared by the batch or a sequence of ``B`` per-member generators (the core
passes each member's own ``"source"`` stream).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netsense.kernels.update import gain_rows, innovation_correction
from netsense.systems.design import ObserverDesign

#: One generator for the whole batch, one per member, or None (a fixed default).
Rngs = np.random.Generator | Sequence[np.random.Generator] | None


class SourceEstimator:
    """Base class of source-node estimators (see the module docstring)."""

    #: Whether the estimator draws random numbers (from the ``rng`` of :meth:`reset`).
    uses_rng: bool = False

    def reset(self, design: ObserverDesign, batch_size: int,
              rng: Rngs = None) -> None:
        """Prepare for a run of ``batch_size`` independent copies."""
        self.design = design
        self.batch_size = batch_size

    def reset_members(self, members: np.ndarray, rng: Rngs = None) -> None:
        """Restart only the members selected by the ``(B,)`` bool mask ``members``.

        Their next :meth:`correction` is at their time ``k = 0``; the other members are
        untouched. ``rng`` as in :meth:`reset` (entries of unselected members are unused).
        Stateless estimators need not override this; stateful ones must.
        """
        raise NotImplementedError(f"{type(self).__name__} keeps state per run but does not "
                                  "implement reset_members(members, rng)")

    def take(self, members: np.ndarray, rng: Rngs = None) -> SourceEstimator:
        """A new estimator whose member ``m`` continues member ``members[m]`` of this one.

        For the forks of :mod:`netsense.engine.fork`: the per-member state is copied
        (members may repeat); ``rng`` (one generator per new member) replaces the
        members' random streams when given (a resampled future), else each new member
        continues a copy of its member's stream. This estimator is not changed. Stateful
        estimators must implement it.
        """
        raise NotImplementedError(f"{type(self).__name__} does not implement take(members, "
                                  "rng): its runs cannot be forked")

    def correction(self, k: int | np.ndarray, Z: np.ndarray, y: np.ndarray,
                   arrived: np.ndarray | None) -> np.ndarray:
        """``(B, N, n)`` correction added to the open-loop step (zero off own blocks).

        ``k`` is the time index of every member (int) or of each member (``(B,)``).
        """
        raise NotImplementedError  # pragma: no cover

    @staticmethod
    def member_rngs(rng: Rngs, batch_size: int) -> list[np.random.Generator]:
        """``rng`` as ``batch_size`` generators (one shared generator is repeated)."""
        if rng is None:
            rng = np.random.default_rng(0)
        if isinstance(rng, np.random.Generator):
            return [rng] * batch_size
        rngs = list(rng)
        if len(rngs) != batch_size:
            raise ValueError(f"rng must be a Generator or {batch_size} Generators, "
                             f"got {len(rngs)}")
        return rngs

    @staticmethod
    def member_times(k: int | np.ndarray, batch_size: int) -> np.ndarray:
        """``k`` as a ``(B,)`` int array (an int is every member's time)."""
        out = np.broadcast_to(np.asarray(k, dtype=np.int64), (batch_size,))
        return out

    @staticmethod
    def own_block_mask(design: ObserverDesign) -> np.ndarray:
        """``(N, n)`` mask: coordinate ``c`` belongs to agent ``i``'s own substate."""
        block_of = design.decomposition.block_of
        return block_of[None, :] == np.arange(design.num_agents)[:, None]


class LuenbergerSource(SourceEstimator):
    """The fixed-gain source update of eq. (7): ``L_j (y_j - C_bar_j z_j)``.

    A measurement that did not arrive contributes nothing (open loop for that step). The
    update is stateless and time-invariant, so per-member resets change nothing.
    """

    def reset_members(self, members: np.ndarray, rng: Rngs = None) -> None:
        """Nothing to restart (stateless)."""

    def take(self, members: np.ndarray, rng: Rngs = None) -> LuenbergerSource:
        """Stateless: a copy for ``len(members)`` members."""
        import copy

        out = copy.copy(self)
        out.batch_size = len(members)
        return out

    def reset(self, design: ObserverDesign, batch_size: int,
              rng: Rngs = None) -> None:
        super().reset(design, batch_size, rng)
        d = design.decomposition
        r_max = max([C.shape[0] for C in d.C_bar] + [1])
        self.C_bar_pad = np.zeros((d.num_agents, r_max, d.n))
        for i, Cb in enumerate(d.C_bar):
            self.C_bar_pad[i, : Cb.shape[0]] = Cb
        self.L_pad = design.gain_padded(r_max)
        #: ``(N, 2)`` rows that hold each agent's gain (:func:`netsense.kernels.update.gain_rows`)
        self.gain_rows = gain_rows(self.L_pad)

    def correction(self, k: int | np.ndarray, Z: np.ndarray, y: np.ndarray,
                   arrived: np.ndarray | None) -> np.ndarray:
        return innovation_correction(Z, y, arrived, self.C_bar_pad, self.L_pad,
                                     self.gain_rows)
