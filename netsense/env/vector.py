"""Vectorised interfaces over :class:`netsense.engine.core.BatchedCore` for RL and Monte Carlo.

Three forms of the same ``B`` environments of one scenario (``N`` agents each):

======================  ======================================================================
class                   what it is
======================  ======================================================================
:class:`BatchedEnv`     plain array API in the style of VMAS: ``reset(seed) -> obs (B, N,
                        obs_dim)``, ``step(actions (B, N, M + 1))``; auto-reset of finished
                        members (optional)
:class:`AgentVectorEnv` a Gymnasium (>= 1.0) ``VectorEnv`` with ``B x N`` agent slots, for
                        parameter-shared training (one policy, every agent a slot)
:func:`make_sb3_vec_env`  a Stable-Baselines3 ``VecEnv`` with the same ``B x N`` slots and an
                        ``action_masks()`` method, so ``sb3_contrib.MaskablePPO`` trains on it
                        directly (SB3 is imported only when this is called)
======================  ======================================================================

Benchmark episodes of many seeds run as one batch in the same way
(:func:`netsense.benchmark.batched.rollout_seeds`; the records equal the benchmark's per seed).

No rule is re-implemented here: every step is one call of :meth:`BatchedCore.step` on the
whole batch, and resets go through :meth:`BatchedCore.reset` with a member mask.

Slots
-----
Agent slot ``s = b * N + i`` is agent ``sensor_i`` of batch member (copy) ``b``; its
observation is ``obs[b, i]`` and its action row ``actions[b, i]`` (``MultiDiscrete([D + 2]
* N + [2])``, see :mod:`netsense.env.pettingzoo_env`). All slots of a member start and end episodes
together.

Seeds
-----
``reset(seed=s)`` starts member ``b`` with seed ``s + b``, so member ``b`` equals
``netsense.make(scenario).reset(seed=s + b)`` step by step. Later episodes (auto-resets)
take seeds drawn, in member order, from ``numpy.random.default_rng(s)``: a rollout is a
function of ``s`` and the actions. ``seed=None`` draws fresh entropy.

Auto-reset (same-step)
----------------------
When member ``b`` terminates or is truncated at a step, that step returns its reward and
``terminated``/``truncated`` flags, and **the observation of the first step of its next
episode** (already reset); the last observation of the finished episode is in
``info["final_obs"][b]`` and its action mask in ``info["final_action_mask"][b]``, with
``info["_final_obs"][b] = True`` (Gymnasium's ``AutoresetMode.SAME_STEP``; SB3 receives
the same data as ``infos[s]["terminal_observation"]``). Rows of ``final_obs`` whose flag
is ``False`` hold the member's current observation and mean nothing. With
``auto_reset=False`` (array API only) finished members keep stepping past the horizon
until :meth:`BatchedEnv.reset_at` restarts them (the core never resets itself).

Action masks
------------
``info["action_mask"]`` (``(B, N, M)`` int8, ``M = N (D + 2) + 2``) always belongs to the
returned observation; :meth:`AgentVectorEnv.action_masks` and the SB3 env's
``action_masks()`` return it per slot as ``(B N, M)`` bool.

Examples
--------
>>> env = BatchedEnv("fig1_scalar-v0", num_envs=4)
>>> obs, info = env.reset(seed=0)
>>> obs.shape, info["action_mask"].shape
((4, 3, 19), (4, 3, 11))
>>> actions = np.zeros((4, 3, 4), dtype=np.int64)  # keep every estimate, stay silent
>>> obs, reward, terminated, truncated, info = env.step(actions)
>>> reward.shape, terminated.shape
((4, 3), (4,))
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from netsense.engine.core import BatchedCore, CoreModel
from netsense.env.pettingzoo_env import FlatMaskMultiDiscrete
from netsense.kernels import checks

__all__ = ["AgentVectorEnv", "BatchedEnv", "load_model", "make_sb3_vec_env"]

_ENV_KW = ("render_mode", "action_mask_in")


def load_model(scenario: str | CoreModel, **overrides) -> tuple[CoreModel, str]:
    """The :class:`CoreModel` of a scenario id (with overrides) or of a model as given.

    Returns
    -------
    (CoreModel, str)
        The model and a name for it (the scenario id or ``"custom"``).
    """
    if isinstance(scenario, CoreModel):
        if overrides:
            raise ValueError("scenario overrides need a scenario id, not a CoreModel "
                             f"(got {sorted(overrides)})")
        return scenario, "custom"
    if not isinstance(scenario, str):
        raise ValueError(f"scenario must be a scenario id or a CoreModel, got "
                         f"{type(scenario).__name__}")
    bad = [k for k in overrides if k in _ENV_KW]
    if bad:
        raise ValueError(f"{bad} are options of the PettingZoo env, not of vector envs")
    from netsense.env.registry import make

    return make(scenario, **overrides).model, scenario


class BatchedEnv:
    """``B`` environments of one scenario behind a plain array API (VMAS style).

    Parameters
    ----------
    scenario : str or CoreModel
        A scenario id (see ``netsense list``) or a model.
    num_envs : int
        ``B``, the number of independent environments (batch members).
    invalid_actions : {"raise", "keep"}
        Behaviour on masked actions (see :mod:`netsense.engine.core`).
    auto_reset : bool
        Restart finished members inside :meth:`step` (see the module docstring).
    nonfinite : {"terminate", "raise"}
        A member whose state or estimates stop being finite terminates (with
        ``info["nonfinite"]``) or the step raises :class:`netsense.NumericalError`.
    **overrides
        Scenario overrides for :func:`netsense.make` (``horizon=10``, ...).

    Attributes
    ----------
    core : BatchedCore
        The batched simulation (state arrays ``x``, ``Z``, ``tau``, ... with axis ``B``).
    num_envs, num_agents : int
        ``B`` and ``N``.
    obs_dim, mask_size : int
        Length of one agent's observation and flat action mask.
    single_observation_space, single_action_space : gymnasium.Space
        One agent's spaces (``Box(obs_dim)`` float32, ``MultiDiscrete([D + 2] * N + [2])``).
    episode_seeds : (B,) int array
        Seed of every member's current episode.
    """

    def __init__(self, scenario: str | CoreModel, num_envs: int, *,
                 invalid_actions: str = "raise", auto_reset: bool = True,
                 nonfinite: str = "terminate", **overrides) -> None:
        num_envs = checks.integer("num_envs", num_envs, 1)
        model, self.scenario_id = load_model(scenario, **overrides)
        self.core = BatchedCore(model, int(num_envs), invalid_actions=invalid_actions,
                                nonfinite=nonfinite)
        c = self.core
        self.model = model
        self.auto_reset = bool(auto_reset)
        self.num_envs, self.num_agents = c.B, c.N
        self.obs_dim, self.mask_size = c.layout.size, c.mask_size
        self.layout = c.layout
        self.single_observation_space = spaces.Box(low=-1e3, high=1e3, shape=(self.obs_dim,),
                                                   dtype=np.float32)
        self.single_action_space = FlatMaskMultiDiscrete(c.nvec)
        self.episode_seeds = np.zeros(c.B, dtype=np.int64)
        self.action_mask: np.ndarray | None = None
        self._seed_rng: np.random.Generator | None = None

    # ------------------------------------------------------------------ reset
    def reset(self, seed: int | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start every member; member ``b`` gets seed ``seed + b``.

        Returns
        -------
        obs : (B, N, obs_dim) float32
        info : dict
            ``action_mask`` (B, N, M) int8.
        """
        if seed is not None:  # member b gets seed + b
            seed = checks.seed_value("seed", seed, self.num_envs)
        self._seed_rng = np.random.default_rng(seed)
        if seed is None:
            seeds = self._draw_seeds(self.num_envs)
        else:
            seeds = int(seed) + np.arange(self.num_envs, dtype=np.int64)
        obs, mask = self.core.reset([int(s) for s in seeds])
        self.episode_seeds = np.asarray(seeds, dtype=np.int64)
        self.action_mask = mask
        return obs, {"action_mask": mask}

    def _draw_seeds(self, count: int) -> np.ndarray:
        assert self._seed_rng is not None
        return self._seed_rng.integers(0, 2**62, size=count, dtype=np.int64)

    def reset_at(self, members, seed: int | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Restart only ``members`` (indices or a ``(B,)`` bool mask).

        ``seed``: member ``b`` gets ``seed + b``; default, seeds drawn from the generator
        of the last :meth:`reset`. Returns the observations and masks of **all** members.
        """
        if self._seed_rng is None:
            raise ValueError("reset() must be called before reset_at()")
        sel = np.zeros(self.num_envs, dtype=bool)
        if seed is not None:
            seed = checks.seed_value("seed", seed, self.num_envs)
        m = np.asarray(members)
        if m.dtype == bool:
            if m.shape != (self.num_envs,):
                raise ValueError(f"a member mask must have shape ({self.num_envs},), "
                                 f"got {m.shape}")
            sel = m.copy()
        else:
            if m.dtype.kind not in "iu":
                raise ValueError(f"members must be member indices or a ({self.num_envs},) "
                                 f"bool mask, got dtype {m.dtype}")
            idx = m.astype(np.int64).reshape(-1)
            if idx.size and (idx.min() < 0 or idx.max() >= self.num_envs):
                raise ValueError(f"member indices must be in 0..{self.num_envs - 1}, got "
                                 f"{idx.tolist()}")
            sel[idx] = True
        return self._restart(sel, seed)

    def _restart(self, sel: np.ndarray, seed: int | None = None
                 ) -> tuple[np.ndarray, dict[str, Any]]:
        seeds = self.episode_seeds.copy()
        if seed is not None:
            seeds[sel] = int(seed) + np.flatnonzero(sel)
        else:
            seeds[sel] = self._draw_seeds(int(sel.sum()))
        obs, mask = self.core.reset([int(s) for s in seeds], members=sel)
        self.episode_seeds = seeds
        self.action_mask = mask
        return obs, {"action_mask": mask}

    # ------------------------------------------------------------------ step
    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                     dict[str, Any]]:
        """Advance every member one step under ``actions (B, N, M + 1)``.

        Returns
        -------
        obs : (B, N, obs_dim) float32
            Next observations (of the new episode for members that just finished, when
            ``auto_reset``).
        reward : (B, N) float64
        terminated, truncated : (B,) bool
        info : dict
            ``action_mask`` (B, N, M) int8 of ``obs``; ``error`` (B, N) normalised errors
            and ``transmitted`` (B, N) bool of this step; with auto-reset and some member
            finished also ``final_obs`` (B, N, obs_dim), ``final_action_mask`` and the
            flags ``_final_obs`` (B,) bool; when a member terminated because its state or
            estimates stopped being finite, ``nonfinite`` (B,) object array with that
            member's ``{"step", "what", "agent"}`` (``None`` for the others).
        """
        if self.action_mask is None:
            raise ValueError("reset() must be called before step()")
        out = self.core.step(actions)
        info: dict[str, Any] = {"action_mask": out.action_mask, "error": self.core.errors,
                                "transmitted": self.core.transmit}
        obs = out.obs
        done = out.terminated | out.truncated
        if out.terminated.any() and any(r is not None for r in self.core.nonfinite):
            flags = np.empty(self.num_envs, dtype=object)
            flags[:] = [r if t else None for r, t in zip(self.core.nonfinite,
                                                         out.terminated, strict=True)]
            info["nonfinite"] = flags
        if self.auto_reset and done.any():
            # the partial reset writes into the core's per-member arrays: keep this step's
            info["error"] = self.core.errors.copy()
            info["transmitted"] = self.core.transmit.copy()
            info["final_obs"] = obs
            info["final_action_mask"] = out.action_mask
            info["_final_obs"] = done
            obs, rinfo = self._restart(done)
            info["action_mask"] = rinfo["action_mask"]
        self.action_mask = info["action_mask"]
        return obs, out.reward, out.terminated, out.truncated, info

    def close(self) -> None:
        """Nothing to release (kept for API symmetry)."""


class AgentVectorEnv(VectorEnv):
    """Gymnasium ``VectorEnv`` whose sub-environments are the ``B x N`` agent slots.

    One parameter-shared policy sees every agent of every member as a separate slot:
    ``num_envs = B N``, observations ``(B N, obs_dim)``, actions ``(B N, M + 1)``. Rewards,
    terminations and truncations are per slot (the flags of a member repeated over its
    agents). Auto-reset: ``AutoresetMode.SAME_STEP`` (declared in ``metadata``), with
    ``infos["final_obs"]`` ``(B N, obs_dim)`` and ``infos["_final_obs"]`` ``(B N,)``.

    Parameters
    ----------
    scenario : str or CoreModel
    batch_size : int
        ``B``, the number of copies of the scenario.
    invalid_actions : {"raise", "keep"}
    **overrides
        Scenario overrides.

    Notes
    -----
    ``reset(seed=s)`` seeds copy ``b`` with ``s + b``; ``options={"reset_mask": m}`` with
    ``m`` of shape ``(B N,)`` (constant over each copy's slots) or ``(B,)`` resets only
    those copies. ``infos["action_mask"]`` ``(B N, M)`` int8 and :meth:`action_masks`
    give the masks of the returned observations.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, scenario: str | CoreModel, batch_size: int, *,
                 invalid_actions: str = "raise", **overrides) -> None:
        self.batched = BatchedEnv(scenario, batch_size, invalid_actions=invalid_actions,
                                  auto_reset=True, **overrides)
        be = self.batched
        self.batch_size, self.num_agents = be.num_envs, be.num_agents
        self.num_envs = be.num_envs * be.num_agents
        self.single_observation_space = be.single_observation_space
        self.single_action_space = be.single_action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.metadata = dict(self.metadata, name=f"netsense/{be.scenario_id}")
        self.render_mode = None

    def _flat(self, a: np.ndarray) -> np.ndarray:
        return a.reshape((self.num_envs,) + a.shape[2:])

    def _per_slot(self, flags: np.ndarray) -> np.ndarray:
        return np.repeat(flags, self.num_agents)

    def reset(self, *, seed: int | None = None, options: dict | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every copy (copy ``b`` gets ``seed + b``) or those in ``reset_mask``."""
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"options must be a dict or None, got {type(options).__name__}")
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if options:
            raise ValueError(f"unknown reset options {sorted(options)}; only 'reset_mask'")
        if mask is None:
            obs, info = self.batched.reset(seed)
        else:
            m = np.asarray(mask)
            if m.dtype != bool:
                raise ValueError(f"reset_mask must be a bool array, got dtype {m.dtype}")
            if m.shape == (self.num_envs,):
                per_copy = m.reshape(self.batch_size, self.num_agents)
                if not (per_copy == per_copy[:, :1]).all():
                    raise ValueError("reset_mask must select all agent slots of a copy or "
                                     "none (copies reset as a whole)")
                m = per_copy[:, 0]
            elif m.shape != (self.batch_size,):
                raise ValueError(f"reset_mask must have shape ({self.num_envs},) or "
                                 f"({self.batch_size},), got {m.shape}")
            if self.batched.action_mask is None:
                raise ValueError("the first reset must reset every copy")
            obs, info = self.batched.reset_at(m, seed)
        return self._flat(obs), {"action_mask": self._flat(info["action_mask"])}

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                     dict[str, Any]]:
        """One step of every slot; ``actions`` ``(B N, M + 1)``."""
        a = np.asarray(actions)
        width = self.batched.core.nvec.size  # M + 1, or the bits of a communication mode
        if a.shape != (self.num_envs, width):
            raise ValueError(f"actions must have shape (num_envs, len(nvec)) = "
                             f"{(self.num_envs, width)}, got {a.shape}")
        obs, rew, term, trunc, info = self.batched.step(
            a.reshape(self.batch_size, self.num_agents, -1))
        infos: dict[str, Any] = {"action_mask": self._flat(info["action_mask"]),
                                 "error": info["error"].reshape(-1),
                                 "transmitted": info["transmitted"].reshape(-1)}
        if "nonfinite" in info:
            infos["nonfinite"] = np.repeat(info["nonfinite"], self.num_agents)
        if "final_obs" in info:
            infos["final_obs"] = self._flat(info["final_obs"])
            infos["final_action_mask"] = self._flat(info["final_action_mask"])
            infos["_final_obs"] = self._per_slot(info["_final_obs"])
        return (self._flat(obs), rew.reshape(-1), self._per_slot(term),
                self._per_slot(trunc), infos)

    def action_masks(self) -> np.ndarray:
        """``(B N, M)`` bool masks of the current observations (MaskablePPO's layout)."""
        if self.batched.action_mask is None:
            raise ValueError("reset() must be called before action_masks()")
        return self._flat(self.batched.action_mask).astype(bool)






# ---------------------------------------------------------------------------- SB3
_SB3_CLASS: type | None = None


def _sb3_class() -> type:
    """Build (once) the SB3 ``VecEnv`` subclass; SB3 is imported only here."""
    global _SB3_CLASS
    if _SB3_CLASS is not None:
        return _SB3_CLASS
    try:
        from stable_baselines3.common.vec_env.base_vec_env import VecEnv
    except ImportError as exc:  # pragma: no cover - depends on the installed extras
        raise ImportError("make_sb3_vec_env needs stable-baselines3: pip install -e "
                          "'.[rl]' (with torch==2.13.0 already installed)") from exc

    class NetSenseSB3VecEnv(VecEnv):
        """SB3 ``VecEnv`` over :class:`AgentVectorEnv`'s ``B x N`` slots (see
        :func:`make_sb3_vec_env`)."""

        def __init__(self, venv: AgentVectorEnv) -> None:
            self.venv = venv
            self.render_mode = None
            self._actions: np.ndarray | None = None
            super().__init__(venv.num_envs, venv.single_observation_space,
                             venv.single_action_space)

        def reset(self):
            seed = self._seeds[0]
            obs, _ = self.venv.reset(seed=None if seed is None else int(seed))
            self._reset_seeds()
            self._reset_options()
            return obs

        def step_async(self, actions: np.ndarray) -> None:
            self._actions = np.asarray(actions)

        def step_wait(self):
            obs, rew, term, trunc, info = self.venv.step(self._actions)
            dones = term | trunc
            infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
            if dones.any():
                fo = info["final_obs"]
                for s in np.flatnonzero(dones):
                    infos[s]["terminal_observation"] = fo[s]
                    if "nonfinite" in info and info["nonfinite"][s] is not None:
                        infos[s]["nonfinite"] = info["nonfinite"][s]
                    infos[s]["TimeLimit.truncated"] = bool(trunc[s] and not term[s])
            return obs, rew.astype(np.float32), dones, infos

        def action_masks(self) -> np.ndarray:
            """``(num_envs, M)`` bool, read by ``sb3_contrib.MaskablePPO``."""
            return self.venv.action_masks()

        def close(self) -> None:
            self.venv.close()

        def _indices(self, indices) -> list[int]:
            if indices is None:
                return list(range(self.num_envs))
            if isinstance(indices, int):
                return [indices]
            return list(indices)

        def get_attr(self, attr_name: str, indices=None) -> list[Any]:
            value = getattr(self, attr_name)
            return [value] * len(self._indices(indices))

        def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
            setattr(self, attr_name, value)

        def env_method(self, method_name: str, *method_args, indices=None,
                       **method_kwargs) -> list[Any]:
            idx = self._indices(indices)
            if method_name == "action_masks":
                return list(self.action_masks()[idx])
            result = getattr(self, method_name)(*method_args, **method_kwargs)
            return [result] * len(idx)

        def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
            return [False] * len(self._indices(indices))

        def get_images(self):
            return []

    _SB3_CLASS = NetSenseSB3VecEnv
    return _SB3_CLASS


def make_sb3_vec_env(scenario: str | CoreModel, batch_size: int, *, seed: int | None = None,
                     invalid_actions: str = "raise", **overrides):
    """A Stable-Baselines3 ``VecEnv`` with ``batch_size x N`` agent slots and masks.

    Every agent of every copy is one slot (``num_envs = B N``), so a single SB3 policy is
    shared by all agents. ``action_masks()`` (also through ``env_method``) serves the
    masks ``sb3_contrib.MaskablePPO`` needs. Finished copies auto-reset; the last
    observation is in ``infos[s]["terminal_observation"]`` and a time-limit end sets
    ``infos[s]["TimeLimit.truncated"]``.

    Parameters
    ----------
    scenario : str or CoreModel
    batch_size : int
        ``B``.
    seed : int, optional
        Seed of the first reset (copy ``b`` gets ``seed + b``).
    invalid_actions : {"raise", "keep"}
    **overrides
        Scenario overrides.

    Examples
    --------
    >>> from sb3_contrib import MaskablePPO                       # doctest: +SKIP
    >>> venv = make_sb3_vec_env("fig1_scalar-v0", 64, seed=0)    # doctest: +SKIP
    >>> MaskablePPO("MlpPolicy", venv).learn(10_000)              # doctest: +SKIP
    """
    if seed is not None:
        seed = checks.seed_value("seed", seed, batch_size if isinstance(batch_size, int)
                                 else 1)
    cls = _sb3_class()
    venv = cls(AgentVectorEnv(scenario, batch_size, invalid_actions=invalid_actions,
                              **overrides))
    if seed is not None:
        venv.seed(int(seed))
    return venv

