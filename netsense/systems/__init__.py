"""Layer 3 — the plant and the observer design, from the freshness paper's Section II-III.

Plants ``x[k+1] = A x[k] + W w[k]``, ``y_i[k] = C_i x[k] + v_i[k]`` and the named ones of
the papers (:mod:`.plants`), Lemma 1's multi-sensor observable decomposition
(:mod:`.decomposition`) and the gains of Theorem 1 (rate-ordered) and Corollary 1
(deadbeat) (:mod:`.design`).

May import: :mod:`netsense.kernels`, :mod:`netsense.sensing` (noise models of a plant).
"""

from netsense.systems.decomposition import Decomposition, decompose, is_observable
from netsense.systems.design import ObserverDesign, deadbeat_gain, design_observer, rate_gain
from netsense.systems.plants import Plant, fig1_scalar, oscillator_bank, random_structured

__all__ = [
    "Decomposition", "ObserverDesign", "Plant", "deadbeat_gain", "decompose",
    "design_observer", "fig1_scalar", "is_observable", "oscillator_bank", "random_structured",
    "rate_gain",
]
