"""Training pipeline, stage *distribution*: the masked action distribution.

:class:`MaskedMultiCategorical` turns flat logits and the flat action mask of
:class:`netsense.engine.core.BatchedCore` (``core.nvec``: one block of ``nvec[a]`` choices per
action entry, the order of the flat action mask) into independent masked categoricals, one
per action entry; every network and every control mode uses it.

Imports: torch and TorchRL only (no other stage).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch.distributions import Independent

__all__ = ["MaskedMultiCategorical"]

_PAD_CACHE: dict[tuple, torch.Tensor] = {}


def _pad_index(nvec: tuple[int, ...], device: torch.device) -> torch.Tensor:
    """``(A, K_max)`` positions in the flat layout (``sum(nvec)`` = padding)."""
    key = (nvec, str(device))
    if key not in _PAD_CACHE:
        total, kmax = sum(nvec), max(nvec)
        idx = np.full((len(nvec), kmax), total, dtype=np.int64)
        start = 0
        for a, k in enumerate(nvec):
            idx[a, :k] = np.arange(start, start + k)
            start += k
        _PAD_CACHE[key] = torch.as_tensor(idx, device=device)
    return _PAD_CACHE[key]


class MaskedMultiCategorical(Independent):
    """Independent masked categoricals, one per action entry, from flat logits and mask.

    The flat layout is ``core.nvec``'s (the flat action mask's): entry ``a`` owns the
    ``nvec[a]`` positions after those of entries ``< a``. The logits and the mask are
    padded to ``(..., A, max(nvec))`` and handed to TorchRL's
    :class:`~torchrl.modules.MaskedCategorical`; ``log_prob`` and ``entropy`` sum over
    the ``A`` entries (one joint action per agent), ``sample`` returns ``(..., A)``.

    Parameters
    ----------
    logits : (..., sum(nvec)) tensor
    mask : (..., sum(nvec)) bool tensor
        ``True`` where a choice is allowed (every entry needs at least one).
    nvec : sequence of int
    """

    def __init__(self, logits: torch.Tensor, mask: torch.Tensor,
                 nvec: Sequence[int]) -> None:
        from torchrl.modules import MaskedCategorical

        nv = tuple(int(v) for v in nvec)
        if len(set(nv)) == 1:  # equal blocks: a view, no padding
            padded = logits.unflatten(-1, (len(nv), nv[0]))
            m = mask.bool().unflatten(-1, (len(nv), nv[0]))
        else:
            idx = _pad_index(nv, logits.device)
            pad = logits.new_zeros(logits.shape[:-1] + (1,))
            padded = torch.cat([logits, pad], -1)[..., idx]
            m = torch.cat([mask.bool(), mask.new_zeros(mask.shape[:-1] + (1,),
                                                       dtype=torch.bool)], -1)[..., idx]
        self.nvec = nv
        super().__init__(MaskedCategorical(logits=padded, mask=m), 1, validate_args=False)

    @property
    def deterministic_sample(self) -> torch.Tensor:
        """The most likely allowed choice of every entry, ``(..., A)``."""
        return self.base_dist.logits.argmax(-1)

    @property
    def mode(self) -> torch.Tensor:
        return self.deterministic_sample
