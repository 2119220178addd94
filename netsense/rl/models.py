"""Former home of the networks; kept so that old imports keep working.

New code imports :mod:`netsense.rl.distributions`, :mod:`netsense.rl.networks` and
:mod:`netsense.rl.set_network`.

Imports: the stages it re-exports.
"""

from __future__ import annotations

from netsense.rl.distributions import MaskedMultiCategorical
from netsense.rl.networks import CRITICS, critic_net, mlp_actor_net
from netsense.rl.set_network import ACTION_LAYOUTS, SetPolicyNet, action_layout

__all__ = ["ACTION_LAYOUTS", "CRITICS", "MaskedMultiCategorical", "SetPolicyNet",
           "action_layout", "critic_net", "mlp_actor_net"]
