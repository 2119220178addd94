"""Layer 8 — the environment users step: PettingZoo, Gymnasium and array interfaces.

The PettingZoo parallel env (:mod:`.pettingzoo_env`), the scenario registry that reads the
TOML files of ``netsense/env/scenarios/`` (:mod:`.registry`: ``make``, ``list_scenarios``),
the scripted policies that act through it (:mod:`.policies`), the vectorised interfaces
over the batched core (:mod:`.vector`: ``BatchedEnv``, Gymnasium ``VectorEnv``, SB3
``VecEnv``) and rendering (:mod:`.render`).

May import every layer below (kernels ... engine); never the tools (rl, benchmark,
studies, speed, commands).
"""

from netsense.env.pettingzoo_env import FlatMaskMultiDiscrete, NetSenseEnv
from netsense.env.registry import list_scenarios, make
from netsense.env.vector import AgentVectorEnv, BatchedEnv, make_sb3_vec_env

__all__ = ["AgentVectorEnv", "BatchedEnv", "FlatMaskMultiDiscrete", "NetSenseEnv", "list_scenarios",
           "make",
           "make_sb3_vec_env"]
