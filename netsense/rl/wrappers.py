"""A PettingZoo wrapper that makes netsense's masked observations flat, for RL libraries.

Most RL libraries want one ``Box`` observation per agent, while a netsense agent's
action mask travels with its observation. :class:`MaskedFlatObs` flattens the
observation and **appends the flat action mask as the last** ``mask_size`` **entries**,
so that the mask survives any vectorisation layer (SuperSuit's concatenated vector
environments, subprocesses, Ray workers) and can be read back by
:meth:`MaskedFlatObs.split` — this is how :mod:`netsense.rl.sb3` hands the masks to
MaskablePPO.

Flat mask layout (what ``MaskablePPO`` expects for ``MultiDiscrete(nvec)``): the
concatenation over action dimensions ``d`` of a boolean vector of length ``nvec[d]``.

Only numpy, gymnasium and pettingzoo are imported here.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from pettingzoo.utils.env import ParallelEnv

_OBS_KEYS = ("observation", "obs")
_MASK_KEY = "action_mask"


def flat_mask(mask: Any, nvec: np.ndarray) -> np.ndarray:
    """Flatten an action mask for ``MultiDiscrete(nvec)`` to ``(sum(nvec),)`` bool.

    Accepts the flat form itself, a sequence with one mask per action dimension, or a
    padded ``(len(nvec), max(nvec))`` array.
    """
    nvec = np.asarray(nvec, dtype=np.int64)
    total = int(nvec.sum())
    if isinstance(mask, (list, tuple)) and len(mask) == len(nvec):
        out = np.concatenate([np.asarray(m, dtype=bool).reshape(-1)[:k]
                              for m, k in zip(mask, nvec, strict=True)])
    else:
        arr = np.asarray(mask)
        if arr.ndim == 1 and arr.shape[0] == total:
            out = arr.astype(bool)
        elif arr.ndim == 2 and arr.shape[0] == len(nvec) and arr.shape[1] >= nvec.max():
            out = np.concatenate([arr[d, :k] for d, k in enumerate(nvec)]).astype(bool)
        else:
            raise ValueError(f"action mask must have {total} entries (sum of nvec {nvec.tolist()})"
                             f" or shape ({len(nvec)}, {int(nvec.max())}), got {arr.shape}")
    if out.shape != (total,):
        raise ValueError(f"action mask must flatten to {total} entries, got {out.shape}")
    return out


def mask_allows(mask: np.ndarray, action: np.ndarray, nvec: np.ndarray) -> bool:
    """Whether every component of ``action`` is allowed by the flat ``mask``."""
    nvec = np.asarray(nvec, dtype=np.int64)
    action = np.asarray(action, dtype=np.int64).reshape(-1)
    offsets = np.concatenate([[0], np.cumsum(nvec)[:-1]])
    if action.shape != nvec.shape or np.any(action < 0) or np.any(action >= nvec):
        return False
    return bool(np.all(np.asarray(mask, dtype=bool)[offsets + action]))


class MaskedFlatObs(ParallelEnv):
    """Flatten each agent's observation and append its flat action mask.

    Parameters
    ----------
    env : pettingzoo.ParallelEnv
        A netsense environment (``netsense.make(...)``) or any parallel env with
        ``MultiDiscrete`` (or ``Discrete``) actions whose mask comes either in a ``Dict``
        observation (keys ``"observation"`` and ``"action_mask"``) or in
        ``infos[agent]["action_mask"]``.
    sanitize : bool
        When True, a masked action component is replaced by the first allowed choice of
        that dimension before it reaches ``env`` (for libraries that cannot mask, e.g. a
        plain RLlib PPO or a random TorchRL rollout). When False (default) actions pass
        through unchanged, and ``env`` decides what a masked action means.

    Attributes
    ----------
    mask_size : int
        Length of the appended mask.
    obs_size : int
        Length of the flattened observation before the mask.
    last_masks : dict
        Flat mask of every live agent after the last ``reset``/``step``.
    """

    def __init__(self, env: ParallelEnv, *, sanitize: bool = False) -> None:
        if not hasattr(env, "possible_agents") or not hasattr(env, "action_space"):
            raise ValueError(f"env must be a PettingZoo ParallelEnv, got {type(env).__name__}")
        self.env = env
        self.sanitize = bool(sanitize)
        self.possible_agents = list(env.possible_agents)
        self.agents = list(getattr(env, "agents", self.possible_agents))
        self.metadata = dict(getattr(env, "metadata", {}))
        self.render_mode = getattr(env, "render_mode", None)
        a0 = self.possible_agents[0]
        space = env.action_space(a0)
        if isinstance(space, gymnasium.spaces.Discrete):
            self.nvec = np.array([space.n], dtype=np.int64)
        elif isinstance(space, gymnasium.spaces.MultiDiscrete):
            self.nvec = np.asarray(space.nvec, dtype=np.int64).reshape(-1)
        else:
            raise ValueError(f"action_space must be Discrete or MultiDiscrete, got {space}")
        self._inner_obs_space = env.observation_space(a0)
        self._obs_part = self._observation_part_space(self._inner_obs_space)
        self.obs_size = int(gymnasium.spaces.flatdim(self._obs_part))
        self.mask_size = int(self.nvec.sum())
        self._flat_space = gymnasium.spaces.Box(-np.inf, np.inf,
                                                (self.obs_size + self.mask_size,), np.float32)
        self.last_masks: dict[str, np.ndarray] = {}

    # ------------------------------------------------------------------ spaces
    @staticmethod
    def _observation_part_space(space: gymnasium.Space) -> gymnasium.Space:
        if isinstance(space, gymnasium.spaces.Dict):
            for key in _OBS_KEYS:
                if key in space.spaces:
                    return space.spaces[key]
            rest = {k: v for k, v in space.spaces.items() if k != _MASK_KEY}
            return gymnasium.spaces.Dict(rest)
        return space

    def observation_space(self, agent: str) -> gymnasium.Space:
        """Flat ``Box`` of ``obs_size + mask_size`` float32 entries."""
        return self._flat_space

    def action_space(self, agent: str) -> gymnasium.Space:
        """The wrapped environment's action space."""
        return self.env.action_space(agent)

    @property
    def unwrapped(self) -> ParallelEnv:
        """The innermost environment."""
        return getattr(self.env, "unwrapped", self.env)

    # ---------------------------------------------------------------- convert
    def _convert(self, obs: dict, infos: dict) -> dict[str, np.ndarray]:
        out = {}
        self.last_masks = {}
        for agent, o in obs.items():
            if isinstance(o, dict):
                part = next((o[k] for k in _OBS_KEYS if k in o), None)
                if part is None:
                    part = {k: v for k, v in o.items() if k != _MASK_KEY}
                raw_mask = o.get(_MASK_KEY)
            else:
                part, raw_mask = o, None
            if raw_mask is None:
                raw_mask = infos.get(agent, {}).get(_MASK_KEY)
            mask = (np.ones(self.mask_size, dtype=bool) if raw_mask is None
                    else flat_mask(raw_mask, self.nvec))
            self.last_masks[agent] = mask
            flat = np.asarray(gymnasium.spaces.flatten(self._obs_part, part), dtype=np.float32)
            out[agent] = np.concatenate([flat, mask.astype(np.float32)])
        return out

    def split(self, flat_obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Split flat observations (``(..., obs_size + mask_size)``) into (obs, bool mask)."""
        flat_obs = np.asarray(flat_obs)
        return flat_obs[..., : self.obs_size], flat_obs[..., self.obs_size:] > 0.5

    def _fix(self, agent: str, action: Any) -> Any:
        mask = self.last_masks.get(agent)
        if mask is None:
            return action
        a = np.asarray(action, dtype=np.int64).reshape(-1).copy()
        offsets = np.concatenate([[0], np.cumsum(self.nvec)[:-1]])
        for d, (off, k) in enumerate(zip(offsets, self.nvec, strict=True)):
            allowed = mask[off: off + k]
            if not (0 <= a[d] < k) or not allowed[a[d]]:
                a[d] = int(np.argmax(allowed))
        return a if np.ndim(action) else int(a[0])

    # ------------------------------------------------------------------- API
    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset the wrapped env; observations flattened with masks appended."""
        obs, infos = self.env.reset(seed=seed, options=options)
        self.agents = list(self.env.agents)
        return self._convert(obs, infos), infos

    def step(self, actions: dict):
        """Step the wrapped env (sanitising masked actions when asked)."""
        if self.sanitize:
            actions = {a: self._fix(a, act) for a, act in actions.items()}
        obs, rew, term, trunc, infos = self.env.step(actions)
        self.agents = list(self.env.agents)
        return self._convert(obs, infos), rew, term, trunc, infos

    def render(self):
        """Render the wrapped env."""
        return self.env.render()

    def close(self) -> None:
        """Close the wrapped env."""
        self.env.close()

    def state(self) -> np.ndarray:
        """The wrapped env's global state."""
        return self.env.state()

    def __getattr__(self, name: str):
        if name.startswith("_") or name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)
