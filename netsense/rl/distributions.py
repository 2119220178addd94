"""Training pipeline, stage *distribution*: the masked action distribution.

:class:`MaskedMultiCategorical` turns flat logits and the flat action mask of
:class:`netsense.engine.core.BatchedCore` (``core.nvec``: one block of ``nvec[a]`` choices per
action entry, the order of the flat action mask) into independent masked categoricals, one
per action entry; every network and every control mode uses it.

Imports: torch and TorchRL only (no other stage).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch.distributions import Independent

__all__ = ["MaskedMultiCategorical"]

def _runs(nvec: tuple[int, ...]) -> list[tuple[int, int, int, int]]:
    """Runs of consecutive entries with the same number of choices: ``(first entry, end
    entry, choices, first flat position)`` (full control: ten entries of ``M + 1``
    choices, then the transmit bit)."""
    out, a0, s0 = [], 0, 0
    while a0 < len(nvec):
        a1 = a0
        while a1 < len(nvec) and nvec[a1] == nvec[a0]:
            a1 += 1
        out.append((a0, a1, nvec[a0], s0))
        s0 += (a1 - a0) * nvec[a0]
        a0 = a1
    return out


class MaskedMultiCategorical(Independent):
    """Independent masked categoricals, one per action entry, from flat logits and mask.

    The flat layout is ``core.nvec``'s (the flat action mask's): entry ``a`` owns the
    ``nvec[a]`` positions after those of entries ``< a``. The logits and the mask are
    padded to ``(..., A, max(nvec))`` and handed to TorchRL's
    :class:`~torchrl.modules.MaskedCategorical`; ``log_prob`` and ``entropy`` sum over
    the ``A`` entries (one joint action per agent), ``sample`` returns ``(..., A)``. The
    distribution is computed in float32 (bfloat16 logits are cast up first).

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
        # float32 whatever the network's arithmetic: under bfloat16 mixed precision
        # (PPOConfig.precision) the logits come out of a bfloat16 product, and the
        # log-probabilities, ratios and entropies are computed from them in float32
        logits = logits.float()
        if len(set(nv)) == 1:  # equal blocks: a view, no padding
            padded = logits.unflatten(-1, (len(nv), nv[0]))
            m = mask.bool().unflatten(-1, (len(nv), nv[0]))
        else:  # padded to max(nvec) choices (logit 0, not allowed), one copy per run of
            # entries of one size (an index over the flat layout took twice as long)
            shape = (len(nv), max(nv))
            padded = logits.new_zeros(logits.shape[:-1] + shape)
            m = torch.zeros(mask.shape[:-1] + shape, dtype=torch.bool, device=mask.device)
            for a0, a1, k, s0 in _runs(nv):
                s1 = s0 + (a1 - a0) * k
                padded[..., a0:a1, :k] = logits[..., s0:s1].unflatten(-1, (a1 - a0, k))
                m[..., a0:a1, :k] = mask[..., s0:s1].bool().unflatten(-1, (a1 - a0, k))
        self.nvec = nv
        self._allowed = m
        super().__init__(MaskedCategorical(logits=padded, mask=m), 1, validate_args=False)

    def log_prob(self, value: torch.Tensor) -> torch.Tensor:
        """``log p(value)`` summed over the entries, ``(...)``: the normalised logits
        (``-inf`` where a choice is not allowed) read at the chosen choices.

        TorchRL's ``MaskedCategorical.log_prob`` computes the same by a cross-entropy,
        which normalises the normalised logits again; the distribution already holds
        them (equal to float rounding, and faster)."""
        logp = self.base_dist.logits.gather(-1, value.unsqueeze(-1)).squeeze(-1)
        return logp.sum(-1)

    def entropy(self) -> torch.Tensor:
        """``-sum p log p`` over the allowed choices of every entry, summed over the
        entries, ``(...)``. From the normalised logits once (TorchRL's
        ``MaskedCategorical.entropy`` fills the disallowed choices with the most negative
        float and normalises again, whose ``exp`` is slow on the CPU)."""
        logp = self.base_dist.logits
        p_log_p = logp.exp() * torch.where(self._allowed, logp, 0.0)
        return -p_log_p.sum((-2, -1))

    @property
    def deterministic_sample(self) -> torch.Tensor:
        """The most likely allowed choice of every entry, ``(..., A)``."""
        return self.base_dist.logits.argmax(-1)

    @property
    def mode(self) -> torch.Tensor:
        return self.deterministic_sample
