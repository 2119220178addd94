"""Layer 1 — the update rules and the compiled machinery that runs them.

The one implementation of the freshness-index observer's update (eqs. (7)-(14)) and of the
consensus baselines (eq. (6)): compiled row functions (:mod:`.rules`), explicit vector
code for the rows (:mod:`.lanes`), loops over batch members and agents compiled serial
and threaded (:mod:`.drivers`, built by :class:`.jit.Driver`, which also hands numpy's
random streams to compiled code), and the checked array functions every caller uses
(:mod:`.update`). The scripted observers, the environment and the benchmarks all call
this code, so it sits below every other layer.

Safety: the names exported here (and every public function of :mod:`.update`) check
shapes, dtypes and index ranges before any compiled code runs, and raise ``ValueError``
naming the argument (helpers in :mod:`.checks`). :mod:`.rules`, :mod:`.lanes`,
:mod:`.drivers` and :mod:`.jit` are internal: compiled without bounds checks, for callers
that guarantee their arrays (the batched core calls ``update._apply_actions`` and
``update._check_actions``, the unchecked forms of the public functions).

May import: numpy, numba. Nothing else from netsense.
"""

from netsense.kernels import notice as _notice
from netsense.kernels.rules import OMEGA
from netsense.kernels.update import (
    StepBuffers,
    StepOut,
    advance_indices,
    apply_actions,
    average_indices,
    freshness_choice,
    gather_substates,
    innovation_correction,
    propagate,
    slot_messages,
    substate_messages,
    uniform_mix,
    usable_slots,
)

__all__ = [
    "OMEGA", "StepBuffers", "StepOut", "advance_indices", "apply_actions", "average_indices",
    "freshness_choice", "gather_substates", "innovation_correction", "propagate",
    "slot_messages", "substate_messages", "uniform_mix", "usable_slots",
]

_notice.install()  # one line on stderr when numba starts compiling netsense's code
