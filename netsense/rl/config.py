"""Training pipeline, stage *configuration*: the run configuration.

:class:`PPOConfig` is the one description of a batched MAPPO / IPPO run (frozen; checked
when built); :func:`training_seeds` lists the episode seeds a run uses, so the protocol can
keep them apart from its evaluation seeds.

Imports: torch, :mod:`netsense.rl.credit`, :mod:`netsense.rl.envs` (control modes) and
:mod:`netsense.rl.networks` (critic kinds).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import torch

from netsense.rl import credit
from netsense.rl.envs import CONTROLS
from netsense.rl.networks import CRITICS

__all__ = ["ALGOS", "BC_HELDOUT_SEED", "EVAL_SEED", "NETWORKS", "PPOConfig", "device_of",
           "training_seeds"]

ALGOS = ("mappo", "ippo")
NETWORKS = ("mlp", "set")
#: Seeds of the periodic evaluation during training start here (monitoring only; the
#: protocol of :mod:`netsense.benchmark.protocol` evaluates on its own seeds).
EVAL_SEED = 10**9
#: Held-out members of the behaviour-cloning check are seeded from here.
BC_HELDOUT_SEED = 900_000


def training_seeds(config: PPOConfig) -> list[int]:
    """Explicit episode seeds a run uses: member ``b`` of the first batch gets
    ``seed * num_envs + b`` (scripted data for behaviour cloning too); held-out
    cloning data ``BC_HELDOUT_SEED + b``. All below
    :data:`netsense.benchmark.protocol.TRAIN_SEED_LIMIT` (checked by
    :class:`PPOConfig`); later episodes draw seeds from a generator over ``[0, 2^62)``."""
    B = int(config.num_envs)
    out = list(range(config.seed * B, (config.seed + 1) * B))
    if config.bc:
        out += list(range(BC_HELDOUT_SEED, BC_HELDOUT_SEED + B))
    return out


@dataclass(frozen=True)
class PPOConfig:
    """One batched MAPPO / IPPO run.

    Attributes
    ----------
    scenario : str
        Scenario id.
    algo : {"mappo", "ippo"}
        Centralised (``critic`` ``"state"`` or ``"joint"``) or local critic.
    network : {"mlp", "set"}
        Actor network (:mod:`netsense.rl.networks`, :mod:`netsense.rl.set_network`).
    control : {None, "full", "transmit", "substates"}
        Control mode (:func:`netsense.rl.envs.make_core`); ``None`` keeps the
        scenario's.
    reward : str
        Reward option (:data:`netsense.rl.credit.REWARDS`).
    steps : int
        Agent-steps of experience (``N`` per env-step).
    seed : int
    num_envs, rollout : int
        ``B`` environments, ``T`` steps each per iteration.
    epochs, minibatch : int
        PPO epochs per iteration; minibatch size in env-steps (each holds ``N`` agents).
    lr, clip, gamma, lmbda, entropy_coef, critic_coef, max_grad_norm : float
    hidden : tuple of int
        Hidden layers of the MLP actor (the set network uses ``set_hidden``).
    critic_hidden : tuple of int
    set_hidden : int
    critic : str or None
        ``"state"``, ``"joint"`` or ``"local"``; default ``"state"`` for mappo, ``"local"``
        for ippo.
    eval_interval : int
        Evaluate and checkpoint every this many iterations (0: only at the end).
    eval_envs : int
        Evaluation episodes (one batch, deterministic actions, seeds from
        :data:`EVAL_SEED`).
    bc : str or None
        Scripted policy to clone before PPO (:func:`~netsense.rl.scripted.scripted_actions`).
    bc_steps, bc_epochs, bc_minibatch : int
        Env-steps of scripted data (split over ``num_envs`` members; each holds ``N``
        agent-steps), passes over it, env-steps per gradient step. The defaults clone a
        deterministic baseline of ``comm_process_noise-v0`` (``sources:0``, ``event:2``) to
        99.7-99.95 % of its actions (held out) and to its return within 0.2; 8192 steps
        and 5 passes at a minibatch of 2048 reached 81-85 % and lost 4-11 of return
        sampled, 37-73 greedy (64 training-evaluation episodes).
    bc_lr : float
        Adam learning rate of the cloning.
    critic_warmup : int
        First iterations that train only the critic.
    device : str
        ``"auto"`` (CUDA when available), ``"cpu"`` or ``"cuda"``.
    numba_threads : int or None
        Threads of the core's compiled passes during training (``None``: numba's
        default). One by default: the learner's torch threads use the cores between
        collections, and threaded passes stall on busy cores (``docs/rl.md``).
    torch_threads : int or None
        ``torch.set_num_threads`` for the learner (``None``: torch's default). One by
        default, as the SB3 path: on the shared 2-core machine two threads of small
        matrix products waited on each other (a 20480 x 233 x 64 layer: 11.5 ms on one
        thread, 25 ms on two, with the other core busy).
    overrides : dict
        Scenario overrides.
    """

    scenario: str
    algo: str = "mappo"
    network: str = "mlp"
    control: str | None = None
    reward: str = "scenario"
    steps: int = 200_000
    seed: int = 0
    num_envs: int = 64
    rollout: int = 32
    epochs: int = 4
    minibatch: int = 512
    lr: float = 3e-4
    clip: float = 0.2
    gamma: float = 0.95
    lmbda: float = 0.95
    entropy_coef: float = 0.01
    critic_coef: float = 0.5
    max_grad_norm: float = 1.0
    hidden: tuple[int, ...] = (64, 64)
    critic_hidden: tuple[int, ...] = (128, 128)
    set_hidden: int = 32
    critic: str | None = None
    eval_interval: int = 10
    eval_envs: int = 16
    bc: str | None = None
    bc_steps: int = 32768
    bc_epochs: int = 40
    bc_minibatch: int = 512
    bc_lr: float = 3e-3
    critic_warmup: int = 0
    device: str = "auto"
    numba_threads: int | None = 1
    torch_threads: int | None = 1
    overrides: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, options in (("algo", ALGOS), ("network", NETWORKS), ("control", CONTROLS),
                              ("reward", credit.REWARDS)):
            if getattr(self, name) not in options:
                raise ValueError(f"PPOConfig.{name} must be one of {options}, got "
                                 f"{getattr(self, name)!r}")
        if self.critic is not None and self.critic not in CRITICS:
            raise ValueError(f"PPOConfig.critic must be one of {CRITICS}, got {self.critic!r}")
        if self.algo == "ippo" and self.critic not in (None, "local"):
            raise ValueError("ippo uses a local critic (critic='local')")
        for name in ("steps", "num_envs", "rollout", "epochs", "minibatch", "eval_envs",
                     "bc_steps", "bc_epochs", "bc_minibatch"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"PPOConfig.{name} must be >= 1, got {getattr(self, name)}")
        for name in ("lr", "bc_lr"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"PPOConfig.{name} must be a finite number > 0, got {v!r}")
        if isinstance(self.seed, bool) or int(self.seed) != self.seed or self.seed < 0:
            raise ValueError(f"PPOConfig.seed must be an integer >= 0, got {self.seed!r}")
        if (self.seed + 1) * self.num_envs > BC_HELDOUT_SEED:
            raise ValueError(f"PPOConfig.seed: training members are seeded seed * num_envs "
                             f"+ b, which must stay below {BC_HELDOUT_SEED} (evaluation "
                             f"seeds are kept apart); got seed {self.seed} with num_envs "
                             f"{self.num_envs}")
        if self.device not in ("auto", "cpu", "cuda"):
            raise ValueError(f"PPOConfig.device must be auto, cpu or cuda, got {self.device!r}")

    @property
    def critic_kind(self) -> str:
        return self.critic or ("local" if self.algo == "ippo" else "state")

    def conservative(self) -> PPOConfig:
        """Fine-tuning after a warm start: clip 0.1, lr 1e-4, entropy 1e-3, 2 critic-only
        iterations (unless already set lower / longer)."""
        return replace(self, clip=min(self.clip, 0.1), lr=min(self.lr, 1e-4),
                       entropy_coef=min(self.entropy_coef, 1e-3),
                       critic_warmup=max(self.critic_warmup, 2))


def device_of(name: str) -> torch.device:
    """``"auto"`` -> CUDA when available, else the CPU; ``"cpu"``/``"cuda"`` as named."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)
