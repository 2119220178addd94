"""Training pipeline, stage *checkpoints*: checkpoints and trained policies.

:func:`save_checkpoint` writes the weights with what is needed to run them elsewhere (the
config, the control section the policy acted in, the layout it was trained on);
:func:`read_policy` reads and checks a file, :func:`policy_config` and
:func:`policy_control` interpret it, :class:`BatchedPolicy` / :func:`load_policy` turn it
into a batched policy (``act(obs, mask)``, the interface of the scripted policies).

Imports: torch and the stages below.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from netsense.rl.config import PPOConfig
from netsense.rl.distributions import MaskedMultiCategorical
from netsense.rl.envs import make_core
from netsense.rl.policy import actor_net

__all__ = ["BatchedPolicy", "load_policy", "policy_config", "policy_control", "read_policy",
           "save_checkpoint"]


def save_checkpoint(path: Path, config: PPOConfig, actor_net, critic, it: int, steps: int,
                core) -> None:
    """Weights with what is needed to run them elsewhere: the config, the control section
    the policy acted in (mode and fusion, resolved from the scenario) and the layout
    sizes it was trained on."""
    ctl = core.model.control
    torch.save({"config": asdict(config), "actor": actor_net.state_dict(),
                "critic": critic.state_dict(), "iteration": it, "agent_steps": steps,
                "control": {"mode": ctl.mode, "fusion": ctl.fusion},
                "trained_on": {"N": core.N, "D": core.D, "M": core.M,
                               "obs_dim": core.layout.size,
                               "nvec": [int(v) for v in core.nvec]}}, path)


def read_policy(path: str | Path) -> dict:
    """The contents of a ``policy.pt`` / checkpoint of :func:`~netsense.rl.ppo.train_ppo`, checked.

    Raises ``ValueError`` naming the file when it is missing, unreadable or not a
    checkpoint of this trainer.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"no policy file at {path} (train one with `netsense train "
                         "--backend torchrl`)")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001 - any failure to load is a bad file
        text = " ".join(str(exc).split())[:200]
        raise ValueError(f"{path}: not a readable policy file (truncated or corrupted?): "
                         f"{type(exc).__name__}: {text}") from None
    if not isinstance(state, dict) or not {"config", "actor"} <= set(state):
        raise ValueError(f"{path}: not a checkpoint of netsense's batched trainer (no "
                         "'config' and 'actor' entries)")
    return state


def policy_config(state: dict) -> PPOConfig:
    """The :class:`PPOConfig` stored in a checkpoint (:func:`read_policy`)."""
    cfg = dict(state["config"])
    for key in ("hidden", "critic_hidden"):
        cfg[key] = tuple(cfg[key])
    return PPOConfig(**cfg)


def policy_control(state: dict) -> dict | str | None:
    """What the policy of a checkpoint (:func:`read_policy`) acted in: the stored
    ``[control]`` keys (mode, fusion), else (files written before they were stored) the
    config's ``control`` (a mode name, or ``None``: the scenario's)."""
    return state.get("control") or policy_config(state).control


class BatchedPolicy:
    """A trained actor as a batched policy: ``act(obs (B, N, obs_dim), mask) -> actions``.

    Parameters
    ----------
    path : path
        ``policy.pt`` or a checkpoint of :func:`~netsense.rl.ppo.train_ppo`.
    core : optional
        The core the policy will act on (default: one of the training scenario). A set
        network runs on any layout of its kind (communication fields or not) and action
        layout; an MLP needs the training layout (checked).
    deterministic : bool
        Most likely allowed action (default) or a sample.
    """

    def __init__(self, path: str | Path, core=None, *, deterministic: bool = True) -> None:
        state = read_policy(path)
        self.config = policy_config(state)
        if core is None:
            core = make_core(self.config.scenario, 1, control=policy_control(state),
                             **self.config.overrides)
        trained = state.get("trained_on")
        if self.config.network == "mlp" and trained is not None:
            now = {"N": core.N, "obs_dim": core.layout.size,
                   "nvec": [int(v) for v in core.nvec]}
            diff = {k: (trained[k], v) for k, v in now.items() if trained[k] != v}
            if diff:
                raise ValueError(f"{path}: an MLP policy runs only on the layout it was "
                                 f"trained on; (trained, here): {diff}. Train the set "
                                 "network (--network set) to change N or D")
        self.net = actor_net(self.config, core, torch.device("cpu"))
        self.net.load_state_dict(state["actor"])
        self.net.eval()
        self.nvec = tuple(int(v) for v in core.nvec)
        self.deterministic = deterministic

    def act(self, obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            d = MaskedMultiCategorical(self.net(torch.as_tensor(obs)),
                                       torch.as_tensor(np.asarray(mask).astype(bool)),
                                       self.nvec)
            a = d.deterministic_sample if self.deterministic else d.sample()
        return a.numpy()


def load_policy(path: str | Path, core=None, *, deterministic: bool = True) -> BatchedPolicy:
    """:class:`BatchedPolicy` from ``policy.pt`` or a checkpoint."""
    return BatchedPolicy(path, core, deterministic=deterministic)
