"""Former name of :mod:`netsense.rl.envs`; kept so that old imports keep working.

Imports: :mod:`netsense.rl.envs`.
"""

from __future__ import annotations

from netsense.rl.envs import CONTROLS, NetSenseBatchedEnv, global_state, make_core, state_size

__all__ = ["CONTROLS", "NetSenseBatchedEnv", "global_state", "make_core", "state_size"]
