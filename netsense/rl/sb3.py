"""Stable-Baselines3 adapter: parameter-shared MaskablePPO on a netsense scenario.

Pipeline (one network for all agents, action masks reaching the learner)::

    netsense.make(scenario)                 PettingZoo ParallelEnv, MultiDiscrete actions
      -> MaskedFlatObs                      flat Box obs, flat action mask appended
      -> supersuit.pettingzoo_env_to_vec_env_v1    one vector slot per agent (sharing)
      -> supersuit.concat_vec_envs_v1(..., base_class="stable_baselines3")
      -> VecActionMasks                     ``action_masks()`` read from the last obs
      -> VecMonitor                         episode returns for the training curve
      -> sb3_contrib.MaskablePPO("MlpPolicy")

MaskablePPO asks the vector env for masks through ``env_method("action_masks")``
(:func:`sb3_contrib.common.maskable.utils.get_action_masks`); :class:`VecActionMasks`
answers it. Saved policies are read back as data by
:class:`netsense.rl.sb3_policy.LearnedPolicy` (re-exported here). Requires the ``rl``
extra: ``pip install torch==2.13.0 && pip install -e ".[rl]"``.
"""

from __future__ import annotations

import csv
import io
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from netsense.rl.atomic import save_figure, write_atomic, write_json
from netsense.rl.run_folder import FINISHED, RUNNING, mark
from netsense.rl.sb3_policy import LearnedPolicy, sb3_metadata, write_sb3_metadata
from netsense.rl.wrappers import MaskedFlatObs, mask_allows

try:
    from stable_baselines3.common.vec_env import VecEnvWrapper
except ImportError as exc:  # pragma: no cover - depends on the installed extras
    raise ImportError("netsense.rl.sb3 needs the 'rl' extra: pip install torch==2.13.0 && "
                      "pip install -e '.[rl]'") from exc

__all__ = ["LearnedPolicy", "TrainConfig", "TrainResult", "make_vec_env", "train"]


def _make_env(scenario: str, overrides: dict | None):
    from netsense.env.registry import make

    return make(scenario, **dict(overrides or {}))


def make_vec_env(scenario: str | None = None, *, num_vec_envs: int = 1, seed: int = 0,
                 overrides: dict | None = None,
                 env_fn: Callable[[], Any] | None = None):
    """SB3 vector env of a scenario: one slot per agent and copy, masks exposed.

    Parameters
    ----------
    scenario : str, optional
        Scenario id for ``netsense.make``.
    num_vec_envs : int
        Independent copies of the environment (``num_envs = num_vec_envs * N``).
    seed : int
        Seed of the first reset (copy ``c`` gets ``seed + c``).
    overrides : dict, optional
        Keyword overrides for ``netsense.make``.
    env_fn : callable, optional
        Builds the ParallelEnv instead of ``netsense.make`` (tests, custom scenarios).

    Returns
    -------
    VecEnv
        With ``action_masks()`` and ``num_envs = num_vec_envs * N``.
    """
    import supersuit as ss
    from stable_baselines3.common.vec_env import VecMonitor

    if num_vec_envs < 1:
        raise ValueError(f"num_vec_envs must be >= 1, got {num_vec_envs}")
    if (scenario is None) == (env_fn is None):
        raise ValueError("give exactly one of scenario and env_fn")
    env = env_fn() if env_fn is not None else _make_env(scenario, overrides)
    wrapped = MaskedFlatObs(env)
    vec = ss.pettingzoo_env_to_vec_env_v1(wrapped)
    vec = ss.concat_vec_envs_v1(vec, num_vec_envs, num_cpus=0, base_class="stable_baselines3")
    masked = VecActionMasks(vec, wrapped.mask_size, wrapped.nvec, seed=seed)
    return VecMonitor(masked)


class VecActionMasks(VecEnvWrapper):
    """SB3 ``VecEnvWrapper`` that serves ``action_masks()`` from the observations' tail.

    Parameters
    ----------
    venv : VecEnv
        Vector env whose observations end with a flat mask of ``mask_size`` entries
        (as :class:`netsense.rl.wrappers.MaskedFlatObs` produces).
    mask_size : int
    nvec : array
        Sizes of the ``MultiDiscrete`` action dimensions.
    seed : int, optional
        Seed of the first reset.
    """

    def __init__(self, venv, mask_size: int, nvec: np.ndarray, seed: int | None = None) -> None:
        super().__init__(venv)
        self.mask_size = int(mask_size)
        self.nvec = np.asarray(nvec, dtype=np.int64)
        self._first_seed = seed
        self._last_obs: np.ndarray | None = None
        self.mask_violations = 0
        self.actions_checked = 0

    def seed(self, seed: int | None = None) -> list:
        """Seed the next reset (copy ``c`` gets ``seed + c``); SuperSuit has no ``seed``."""
        self._first_seed = seed
        return [None if seed is None else seed + i for i in range(self.num_envs)]

    def reset(self) -> np.ndarray:
        """Reset (seeded on the first call) and remember the observations."""
        if self._first_seed is not None:
            obs, infos = self.venv.venv.reset(seed=self._first_seed)
            self.venv.reset_infos = infos
            self._first_seed = None
        else:
            obs = self.venv.reset()
        self._last_obs = np.asarray(obs)
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        """Count actions that break the current masks, then forward them."""
        if self._last_obs is not None:
            masks = self.action_masks()
            acts = np.asarray(actions).reshape(len(masks), -1)
            bad = sum(not mask_allows(m, a, self.nvec) for m, a in zip(masks, acts, strict=True))
            self.mask_violations += int(bad)
            self.actions_checked += len(masks)
        self.venv.step_async(actions)

    def step_wait(self):
        """Forward and remember the observations (after SuperSuit's auto-reset)."""
        obs, rew, done, infos = self.venv.step_wait()
        self._last_obs = np.asarray(obs)
        return obs, rew, done, infos

    def action_masks(self) -> np.ndarray:
        """``(num_envs, sum(nvec))`` boolean masks of the current observations."""
        if self._last_obs is None:
            raise RuntimeError("reset the environment before asking for action masks")
        return self._last_obs[:, -self.mask_size:] > 0.5

    # MaskablePPO reaches the masks through these two VecEnv methods.
    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list:
        """``env_method("action_masks")`` returns one mask per slot; others forward."""
        if method_name == "action_masks":
            return list(self.action_masks())
        return self.venv.env_method(method_name, *args, indices=indices, **kwargs)

    def get_attr(self, attr_name: str, indices=None) -> list:
        """``render_mode`` per slot (SuperSuit's concat env has no ``get_attr`` for it)."""
        if attr_name == "render_mode":
            return [getattr(self.venv, "render_mode", None)] * self.venv.num_envs
        return self.venv.get_attr(attr_name, indices)

    def has_attr(self, attr_name: str) -> bool:
        """True for ``action_masks``; otherwise asks the wrapped env."""
        if attr_name == "action_masks":
            return True
        return self.venv.has_attr(attr_name)


# --------------------------------------------------------------------------- training
@dataclass(frozen=True)
class TrainConfig:
    """Hyper-parameters of :func:`train` (MaskablePPO, shared MLP policy).

    Parameters
    ----------
    scenario : str
        Scenario id.
    steps : int
        Total agent-steps (SB3 ``total_timesteps``; each env step counts ``N``).
    seed : int
        Seed of the learner and the environment.
    num_vec_envs : int
        Environment copies stepped together.
    n_steps : int
        Rollout length per vector slot.
    batch_size, n_epochs : int
        PPO minibatch size and epochs per update.
    learning_rate, gamma, gae_lambda, ent_coef : float
        PPO coefficients.
    net_arch : tuple of int
        Hidden layers of the policy and value networks.
    normalize_reward : bool
        Scale rewards by a running estimate of the return's standard deviation
        (SB3 ``VecNormalize(norm_obs=False)``); inference is unaffected.
    torch_threads : int or None
        ``torch.set_num_threads`` while training (default 1: SB3's minibatches of a few
        hundred rows run slower on two threads, docs/performance.md); ``None`` leaves
        torch's setting (one thread per core unless ``OMP_NUM_THREADS`` says otherwise).
    overrides : dict
        Keyword overrides for ``netsense.make``.
    """

    scenario: str
    steps: int = 50_000
    seed: int = 0
    num_vec_envs: int = 4
    n_steps: int = 128
    batch_size: int = 256
    n_epochs: int = 5
    learning_rate: float = 3e-4
    gamma: float = 0.95
    gae_lambda: float = 0.95
    ent_coef: float = 0.01
    net_arch: tuple[int, ...] = (64, 64)
    normalize_reward: bool = False
    torch_threads: int | None = 1
    overrides: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        from netsense.kernels import checks

        if not isinstance(self.scenario, str):
            raise ValueError(f"TrainConfig.scenario must be a scenario id (str), got "
                             f"{self.scenario!r}")
        for name in ("steps", "num_vec_envs", "n_steps", "batch_size", "n_epochs"):
            checks.integer(f"TrainConfig.{name}", getattr(self, name), 1)
        checks.seed_value("TrainConfig.seed", self.seed)
        checks.number("TrainConfig.learning_rate", self.learning_rate, 0, lo_open=True)
        for name in ("gamma", "gae_lambda"):
            checks.number(f"TrainConfig.{name}", getattr(self, name), 0, 1)
        checks.number("TrainConfig.ent_coef", self.ent_coef)
        if self.torch_threads is not None:
            checks.integer("TrainConfig.torch_threads", self.torch_threads, 1, 4096)
        if not isinstance(self.overrides, dict):
            raise ValueError(f"TrainConfig.overrides must be a dict, got "
                             f"{type(self.overrides).__name__}")


@dataclass
class TrainResult:
    """What :func:`train` produced.

    Attributes
    ----------
    policy_path, curve_csv, curve_png : Path
        Saved policy (``policy.zip``) and training curve.
    curve : list of dict
        Rows ``timesteps, episodes, mean_episode_reward, wall_s``.
    wall_s : float
        Training wall time in seconds.
    mask_violations, actions_checked : int
        Actions taken during training that broke their mask (must be 0), out of all.
    agent_steps : int
        Agent-steps actually trained: ``config.steps`` rounded up to whole rollouts of
        ``n_steps`` x vector slots (SB3 never stops inside a rollout).
    """

    policy_path: Path
    curve_csv: Path
    curve_png: Path
    curve: list[dict]
    wall_s: float
    mask_violations: int
    actions_checked: int
    agent_steps: int = 0


def _callback(total: int, progress: bool):
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm.auto import tqdm

    class CurveCallback(BaseCallback):
        """Records the mean episode return after each rollout; drives a tqdm bar."""

        def __init__(self) -> None:
            super().__init__()
            self.rows: list[dict] = []
            self.t0 = time.perf_counter()
            self.bar = None

        def _on_training_start(self) -> None:
            self.bar = tqdm(total=total, desc="train", unit="step", disable=not progress)

        def _on_step(self) -> bool:
            self.bar.update(self.training_env.num_envs)
            return True

        def _on_rollout_end(self) -> None:
            buf = list(self.model.ep_info_buffer)
            if buf:
                self.rows.append({
                    "timesteps": int(self.num_timesteps),
                    "episodes": len(buf),
                    "mean_episode_reward": float(np.mean([e["r"] for e in buf])),
                    "wall_s": round(time.perf_counter() - self.t0, 3),
                })
                self.bar.set_postfix(reward=f"{self.rows[-1]['mean_episode_reward']:.3g}")

        def _on_training_end(self) -> None:
            self.bar.close()

    return CurveCallback()




def train(config: TrainConfig, out: str | Path, *, progress: bool = True,
          env_fn: Callable[[], Any] | None = None, verbose: int = 0,
          baselines: dict[str, float] | None = None) -> TrainResult:
    """Train a parameter-shared MaskablePPO policy and save it with its training curve.

    Writes ``policy.zip`` (an SB3 zip with netsense's metadata and checksum, read as data
    by :class:`netsense.rl.sb3_policy.LearnedPolicy`), ``training_curve.csv``,
    ``training_curve.png`` and ``train_config.json`` into ``out``.

    Parameters
    ----------
    config : TrainConfig
    out : path
        Output directory (created).
    progress : bool
        Show a tqdm bar.
    env_fn : callable, optional
        Builds the ParallelEnv instead of ``netsense.make(config.scenario)``.
    verbose : int
        SB3 verbosity.
    baselines : dict of str to float, optional
        Mean episode returns of scripted policies, drawn on the curve and stored in
        ``train_config.json`` (:func:`netsense.benchmark.baselines.baseline_returns`
        computes them for ``config``).
    """
    import torch
    from sb3_contrib import MaskablePPO

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    mark(out, RUNNING, backend="sb3")  # a killed run leaves its folder marked unfinished
    if config.torch_threads is not None:
        torch.set_num_threads(int(config.torch_threads))
    env = make_vec_env(None if env_fn else config.scenario, num_vec_envs=config.num_vec_envs,
                       seed=config.seed, overrides=config.overrides, env_fn=env_fn)
    monitor = env
    if config.normalize_reward:
        from stable_baselines3.common.vec_env import VecNormalize

        env = VecNormalize(env, norm_obs=False, norm_reward=True, gamma=config.gamma)
    batch = min(config.batch_size, config.n_steps * env.num_envs)
    model = MaskablePPO("MlpPolicy", env, n_steps=config.n_steps, batch_size=batch,
                        n_epochs=config.n_epochs, learning_rate=config.learning_rate,
                        gamma=config.gamma, gae_lambda=config.gae_lambda,
                        ent_coef=config.ent_coef, seed=config.seed, device="cpu",
                        policy_kwargs={"net_arch": list(config.net_arch)}, verbose=verbose)
    rollout = config.n_steps * env.num_envs  # SB3 trains whole rollouts: the real total
    cb = _callback(-(-config.steps // rollout) * rollout, progress)
    t0 = time.perf_counter()
    model.learn(total_timesteps=config.steps, callback=cb)
    wall = time.perf_counter() - t0
    masks = monitor.venv  # VecMonitor -> VecActionMasks
    policy_path = out / "policy.zip"
    buf = io.BytesIO()
    model.save(buf)
    raw = write_atomic(out / ".policy.unsealed.zip", buf.getvalue())
    # netsense's metadata and checksum: LearnedPolicy reads the file without unpickling
    # (written beside policy.zip and renamed over it)
    write_sb3_metadata(raw, sb3_metadata(
        model, scenario=config.scenario, overrides=config.overrides, seed=config.seed,
        num_vec_envs=config.num_vec_envs), policy_path)
    raw.unlink()
    env.close()
    curve_csv = out / "training_curve.csv"
    text = io.StringIO()
    w = csv.DictWriter(text, fieldnames=["timesteps", "episodes", "mean_episode_reward",
                                         "wall_s"])
    w.writeheader()
    w.writerows(cb.rows)
    write_atomic(curve_csv, text.getvalue())
    refs = dict(baselines or {})
    curve_png = _plot_curve(cb.rows, out / "training_curve.png", config.scenario, refs)
    meta = {**asdict(config), "algo": "maskable_ppo", "wall_s": round(wall, 2),
            "agent_steps": int(model.num_timesteps),
            "mask_violations": masks.mask_violations, "actions_checked": masks.actions_checked,
            "baseline_returns": refs}
    write_json(out / "train_config.json", meta, default=list)
    mark(out, FINISHED, backend="sb3")  # last: the folder holds a finished run
    return TrainResult(policy_path, curve_csv, curve_png, cb.rows, wall,
                       masks.mask_violations, masks.actions_checked, int(model.num_timesteps))


def _plot_curve(rows: list[dict], path: Path, title: str,
                refs: dict[str, float] | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.6, 3.6))
    if rows:
        ax.plot([r["timesteps"] for r in rows], [r["mean_episode_reward"] for r in rows],
                label="MaskablePPO (training, sampled actions)")
    for i, (name, value) in enumerate((refs or {}).items()):
        ax.axhline(value, ls="--", color=f"C{i + 1}", label=f"{name} (scripted)")
    if rows or refs:
        ax.legend(fontsize=8)
    ax.set_xlabel("agent-steps")
    ax.set_ylabel("mean episode return per agent")
    ax.set_title(f"MaskablePPO on {title}")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path
