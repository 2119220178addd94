"""Local estimators of the source nodes (the output-injection part of eq. (7)).

A distributed observer propagates every agent's estimate with the open-loop part of
eqs. (7), (10), (12) (see :func:`netsense.kernels.propagate`) and then adds, for each
source ``j``, a *correction* on its own block. The paper's correction is the fixed gain
``L_j (y_j - C_bar_j z_j)`` (:class:`LuenbergerSource`); other estimators (KFIO, RSEIO,
equalized recovery, ...) plug in here by subclassing :class:`SourceEstimator`.

The contract of ``correction``: given the estimates ``Z`` at time ``k`` (before the
update), the padded measurements and their arrival flags, return the ``(B, N, n)`` array
added to the open-loop propagation. Rows outside agent ``j``'s own block must be zero for
agent ``j`` (``own_block_mask`` helps); the new own-block value of source ``j`` is then
``(A_bar z_j)^{(j)} + correction_j^{(j)}`` — i.e. any estimator in predictor form.
"""

from __future__ import annotations

import numpy as np

from netsense.design import ObserverDesign
from netsense.kernels import innovation_correction


class SourceEstimator:
    """Base class of source-node estimators (see the module docstring)."""

    def reset(self, design: ObserverDesign, batch_size: int,
              rng: np.random.Generator | None = None) -> None:
        """Prepare for a run of ``batch_size`` independent copies."""
        self.design = design
        self.batch_size = batch_size

    def correction(self, k: int, Z: np.ndarray, y: np.ndarray,
                   arrived: np.ndarray | None) -> np.ndarray:
        """``(B, N, n)`` correction added to the open-loop step (zero off own blocks)."""
        raise NotImplementedError  # pragma: no cover

    @staticmethod
    def own_block_mask(design: ObserverDesign) -> np.ndarray:
        """``(N, n)`` mask: coordinate ``c`` belongs to agent ``i``'s own substate."""
        block_of = design.decomposition.block_of
        return block_of[None, :] == np.arange(design.num_agents)[:, None]


class LuenbergerSource(SourceEstimator):
    """The fixed-gain source update of eq. (7): ``L_j (y_j - C_bar_j z_j)``.

    A measurement that did not arrive contributes nothing (open loop for that step).
    """

    def reset(self, design: ObserverDesign, batch_size: int,
              rng: np.random.Generator | None = None) -> None:
        super().reset(design, batch_size, rng)
        d = design.decomposition
        r_max = max([C.shape[0] for C in d.C_bar] + [1])
        self.C_bar_pad = np.zeros((d.num_agents, r_max, d.n))
        for i, Cb in enumerate(d.C_bar):
            self.C_bar_pad[i, : Cb.shape[0]] = Cb
        self.L_pad = design.gain_padded(r_max)

    def correction(self, k: int, Z: np.ndarray, y: np.ndarray,
                   arrived: np.ndarray | None) -> np.ndarray:
        return innovation_correction(Z, y, arrived, self.C_bar_pad, self.L_pad)
