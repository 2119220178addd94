"""Training pipeline, stage *configuration*: the run configuration.

:class:`PPOConfig` is the one description of a batched MAPPO / IPPO run (frozen; checked
when built); :func:`training_seeds` lists the episode seeds a run uses, so the protocol can
keep them apart from its evaluation seeds.

Imports: torch, :mod:`netsense.rl.credit`, :mod:`netsense.rl.envs` (control modes) and
:mod:`netsense.rl.networks` (critic kinds).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import torch

from netsense.engine.control import MODES
from netsense.kernels import checks
from netsense.rl import credit
from netsense.rl.envs import resolve_device
from netsense.rl.networks import ACTIVATIONS, CRITICS

__all__ = ["ALGOS", "BC_HELDOUT_SEED", "CONFIG_CHECKS", "EVAL_SEED", "MAX_WIDTH", "NETWORKS",
           "PPOConfig", "PRECISIONS", "check_config_fields", "check_field", "device_of",
           "learner_precision", "loss_arithmetic", "training_seeds"]

ALGOS = ("mappo", "ippo")
NETWORKS = ("mlp", "set")
#: Choices of :attr:`PPOConfig.precision`.
PRECISIONS = ("auto", "fp32", "bf16")
#: Seeds of the periodic evaluation during training start here (monitoring only; the
#: protocol of :mod:`netsense.benchmark.protocol` evaluates on its own seeds).
EVAL_SEED = 10**9
#: Held-out members of the behaviour-cloning check are seeded from here.
BC_HELDOUT_SEED = 900_000
#: Widest layer a config accepts (a million-wide layer is a typo, not a network).
MAX_WIDTH = 65536


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
    control : {None, "full", "transmit", "substates"} or dict
        Control mode (:func:`netsense.rl.envs.make_core`); ``None`` keeps the
        scenario's; a dict sets ``[control]`` keys (``mode``, ``fusion``). A ``control``
        entry of ``overrides`` is folded in here (a mode given here wins over its
        ``mode``).
    reward : str
        Reward option (:data:`netsense.rl.credit.REWARDS`).
    steps : int
        Agent-steps of experience (``N`` per env-step).
    seed : int
    num_envs, rollout : int
        ``B`` environments, ``T`` steps each per iteration.
    epochs, minibatch : int
        PPO epochs per iteration; minibatch size in env-steps (each holds ``N`` agents).
        Larger batches train more agent-steps per second but take fewer gradient steps
        per agent-step, and cost returns at a fixed budget (docs/rl.md, "Larger batches
        learn less per sample").
    lr, clip, gamma, lmbda, entropy_coef, critic_coef, max_grad_norm : float
    hidden : tuple of int
        Hidden layers of the MLP actor (the set network uses ``set_hidden``).
    critic_hidden : tuple of int
    set_hidden : int
    set_slots : bool
        The set network pools its (message slot, substate) pair tokens (default); ``False``:
        substate and agent tokens only, in the communication-only control modes, where the
        pair grid's cost is not needed (:class:`netsense.rl.set_network.SetPolicyNet`, ``slots``).
    activation : {"tanh", "relu"}
        Hidden-layer activation of the MLP actor and the critics. ReLU by default: the
        ablation finds the same returns as tanh, and training runs 1.2x faster with it on
        the 2-core development machine (``experiments/bench/train_throughput.py``).
    memory : int
        Size of the actor's GRU state over the agent's own observation history
        (:mod:`netsense.rl.memory`); 0: a feed-forward actor. Works with both networks and
        both algorithms (the critics stay feed-forward: the state critic sees the global
        state, the local one the observation).
    stagger : bool
        Spread the training members' episode phases before the first rollout
        (:class:`netsense.rl.rollout.Collector`): otherwise every rollout window covers the
        same phase of the episode in all members.
    agent_features : bool
        The MLP actors also read a one-hot of the substate the agent owns
        (:class:`netsense.rl.policy.OwnSubstateActor`).
    clock : tuple of int
        Periods ``p`` (steps) of a clock the MLP actors also read: ``sin`` and ``cos`` of
        ``2 pi k / p`` for each, ``k`` the step index recovered from the observation's
        time entry ``k / H`` (:class:`netsense.rl.policy.ClockActor`). The same information
        as that entry, in a form a small network can use for periodic rules: a
        time-division slot ``k mod 5`` is 40 periods of ``k / H`` over a 200-step episode.
        Empty (default): no clock. Not with ``obs_norm`` or the set network.
    clock_shift : bool
        Each agent reads ``clock`` in its own frame, the phases of ``k - i`` for agent
        ``i``, so that one rule shared by the agents is a staggered schedule (default
        ``False``: the common clock; needs ``clock``).
    ages : tuple of int
        Scales ``tau`` (steps) at which the MLP actors also read the observation's ages:
        ``exp(-a / tau)`` for each scale and each entry ``a`` (in steps) of ``news`` and
        ``silence`` (:class:`netsense.rl.policy.AgeActor`), the communication-only fields
        the scripted rules read. Those entries are given in units of the horizon (one step
        is ``1 / H = 0.005`` on the 200-step tasks), beside entries of order 1; on the
        scale of a few steps the decays separate them. Empty (default): none. Not with
        ``obs_norm``, the set network or full control.
    clock_only : bool
        The MLP actor reads the clock, the time entry and (with ``agent_features``) its
        own-substate one-hot only, every other observation entry held at 0
        (:class:`netsense.rl.policy.ClockActor`): the policy is then a learned schedule,
        a function of the step and the agent, blind to the estimates, news and the
        channel's feedback. A restriction of the policy class, not of the task (the
        environment and its observation are unchanged); default ``False``; needs
        ``clock``.
    comm_fields_only : bool
        The MLP actor reads only what the communication-only modes add to the agent's
        observation (``news``, ``silence``, ``channel_load``, ``collided``, ``agent_id``,
        ``next_out``, ``acks``, where the scenario has them) and the time entry, every other
        entry (the measurements and the estimator's slots) held at 0
        (:class:`netsense.rl.policy.CommFieldsActor`); the own-substate one-hot, the clock
        and the ages are read as configured. A restriction of the policy class, not of
        the task; default ``False``. Not with the set network or full control.
    news_gate : bool
        Send only what is news (:class:`netsense.rl.policy.NewsGateActor`): in the
        communication-only control modes, the choice to send a substate (``"substates"``)
        or to transmit (``"transmit"``) is closed where the agent's observation holds no
        news for it; a restriction of the policy class, with either network. Default
        ``False``.
    value_norm : bool
        Critic trained on standardised value targets (TorchRL's ``RunningValueNorm``;
        :mod:`netsense.rl.advantage`).
    reward_scale : bool
        Rewards divided by the running standard deviation of the discounted return
        (:class:`netsense.rl.ppo.ReturnScaler`).
    obs_norm : bool
        Observations standardised by running statistics before the MLP actor (ignored by
        the set network, whose tokens are bounded by construction).
    lr_decay : bool
        Learning rate decays linearly to 0 over the run.
    entropy_final : float or None
        Entropy coefficient at the end of the run (linear schedule from ``entropy_coef``);
        ``None``: constant.
    critic : str or None
        ``"team"``, ``"state"``, ``"joint"`` or ``"local"``
        (:func:`netsense.rl.networks.critic_net`); default: :attr:`critic_kind`.
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
    precision : {"auto", "fp32", "bf16"}
        Arithmetic of the PPO loss's forward pass (and so of its backward pass): ``"fp32"``
        throughout, or ``"bf16"``: torch's automatic mixed precision (``torch.autocast``)
        with bfloat16 matrix products, parameters, optimiser and the rest of the loss in
        float32; collection, advantages and evaluation always run in float32.
        ``"auto"`` (default): ``"bf16"`` when the learner runs on a CPU that computes
        bfloat16 products natively (AVX512-BF16 or AMX), ``"fp32"`` otherwise
        (:func:`learner_precision`). What it gains is the ratio of the ``torchrl-fp32``
        paths of ``experiments/bench/train_throughput.py`` (docs/performance.md); five
        seeds from scratch reach the same returns as in float32 (docs/rl.md, "Threads and
        devices").
    numba_threads : int or None
        Threads of the core's compiled passes during training (``None``: numba's
        default). One by default: at the default batch the passes are too small to pay
        for a second thread, and threaded passes stall on busy cores (``docs/rl.md``).
    torch_threads : int or None
        ``torch.set_num_threads`` for the learner. ``None`` (default) leaves torch's
        setting: one thread per core unless ``OMP_NUM_THREADS`` (or an earlier
        ``torch.set_num_threads``) says otherwise, so the learner takes the cores of the
        machine, and a worker of :func:`netsense.rl.launch.launch` the one its
        environment gives it. On the idle 2-core machine both cores train faster than
        one, at the default batch and in full control (the ``torchrl-onethread`` paths
        of ``experiments/bench/train_throughput.py``, docs/performance.md); on a core
        that another job keeps busy, every product waits for that job: give 1 there.
    overlap : bool
        Collect the next rollout in a second Python thread while the learner trains on
        the current one (the default). The collector then acts with a copy of the actor
        whose parameters are one update behind the learner's (the rollout of iteration
        ``k + 1`` comes from the parameters before update ``k``), and the loss is the
        decoupled clipped objective for such data (TorchRL's ``delay_actor``: clipping
        around the parameters at the start of the update, the surrogate weighted by
        their probability of the action over the collector's; :mod:`netsense.rl.ppo`).
        ``False``: collection and learning one after the other, plain PPO.
    overrides : dict
        Scenario overrides (checked against the scenario file when the config is built).

    Every field is checked when the config is built (:data:`CONFIG_CHECKS`): types are
    not converted and ranges are checked before anything runs; the device's
    availability is checked when training starts (:func:`device_of`).
    """

    scenario: str
    algo: str = "mappo"
    network: str = "mlp"
    control: str | None = None
    reward: str = "team"
    steps: int = 2_000_000
    seed: int = 0
    num_envs: int = 256
    rollout: int = 32
    epochs: int = 4
    minibatch: int = 2048
    lr: float = 1e-3
    clip: float = 0.2
    gamma: float = 0.99
    lmbda: float = 0.95
    entropy_coef: float = 0.01
    critic_coef: float = 0.5
    max_grad_norm: float = 1.0
    hidden: tuple[int, ...] = (64, 64)
    critic_hidden: tuple[int, ...] = (128, 128)
    set_hidden: int = 32
    set_slots: bool = True
    memory: int = 0
    activation: str = "relu"
    stagger: bool = True
    agent_features: bool = True
    clock: tuple[int, ...] = ()
    clock_shift: bool = False
    clock_only: bool = False
    comm_fields_only: bool = False
    ages: tuple[int, ...] = ()
    news_gate: bool = False
    value_norm: bool = True
    reward_scale: bool = False
    obs_norm: bool = False
    lr_decay: bool = False
    entropy_final: float | None = 0.0
    critic: str | None = None
    eval_interval: int = 10
    eval_envs: int = 32
    bc: str | None = None
    bc_steps: int = 32768
    bc_epochs: int = 40
    bc_minibatch: int = 512
    bc_lr: float = 3e-3
    critic_warmup: int = 0
    device: str = "auto"
    precision: str = "auto"
    numba_threads: int | None = 1
    torch_threads: int | None = None
    overlap: bool = True
    overrides: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_config_fields(self, CONFIG_CHECKS)
        if self.algo == "ippo" and self.critic not in (None, "local"):
            raise ValueError(f"PPOConfig.critic: ippo uses a local critic (critic='local' or "
                             f"None), got {self.critic!r}")
        if (self.seed + 1) * self.num_envs > BC_HELDOUT_SEED:
            raise ValueError(f"PPOConfig.seed: training members are seeded seed * num_envs "
                             f"+ b, which must stay below {BC_HELDOUT_SEED} (evaluation "
                             f"seeds are kept apart); got seed {self.seed} with num_envs "
                             f"{self.num_envs}")
        if self.device != "auto":
            try:
                kind = torch.device(self.device).type
            except (RuntimeError, ValueError):
                kind = None
            if kind not in ("cpu", "cuda"):
                raise ValueError(f"PPOConfig.device must be 'auto', 'cpu', 'cuda' or "
                                 f"'cuda:<index>', got {self.device!r}")
        if self.clock and (self.obs_norm or self.network == "set"):
            raise ValueError(f"PPOConfig.clock: the clock reads the raw time entry of the MLP "
                             f"actor's observation; it is not available with obs_norm=True "
                             f"or network='set' (got obs_norm={self.obs_norm}, network="
                             f"{self.network!r})")
        if self.ages and (self.obs_norm or self.network == "set"):
            raise ValueError(f"PPOConfig.ages: the age features read the raw news and silence "
                             f"entries of the MLP actor's observation; they are not available "
                             f"with obs_norm=True or network='set' (got obs_norm="
                             f"{self.obs_norm}, network={self.network!r})")
        if self.clock_shift and not self.clock:
            raise ValueError("PPOConfig.clock_shift shifts the clock's phases by the agent's "
                             "index; give the periods in PPOConfig.clock")
        if self.clock_only and not self.clock:
            raise ValueError("PPOConfig.clock_only: a clock-only actor reads only the clock "
                             "and its own substate; give the periods in PPOConfig.clock")
        explicit_mode = (self.control.get("mode") if isinstance(self.control, dict)
                         else self.control)
        if not self.set_slots and (self.network != "set" or explicit_mode == "full"):
            raise ValueError(f"PPOConfig.set_slots=False leaves the message slots out of the "
                             f"set network in a communication-only mode; got network="
                             f"{self.network!r}, control={self.control!r}")
        if self.comm_fields_only and (self.network == "set" or explicit_mode == "full"):
            raise ValueError("PPOConfig.comm_fields_only keeps the communication-only fields "
                             "of the MLP actor's observation; not with network='set' or "
                             "control mode 'full'")
        if self.ages and explicit_mode == "full":
            raise ValueError("PPOConfig.ages reads the news and silence fields of the "
                             "communication-only control modes; got control 'full'")
        if self.news_gate and explicit_mode == "full":
            raise ValueError("PPOConfig.news_gate gates the send choices of the "
                             "communication-only control modes ('transmit', 'substates'); "
                             "got control 'full'")
        if self.bc and self.memory:
            raise ValueError("PPOConfig.bc: behaviour cloning trains a feed-forward actor "
                             "step by step; it is not available with memory > 0")
        if self.critic == "team" and self.reward != "team":
            raise ValueError("PPOConfig.critic 'team' (one value per member) needs "
                             f"reward='team' (every agent's return the same), got reward "
                             f"{self.reward!r}")
        _check_bc(self.bc)
        _check_scenario(self)

    @property
    def critic_kind(self) -> str:
        """The critic used: ``critic``, else ``local`` for ippo, ``team`` for mappo with the
        team reward (every agent's return is the same) and ``state`` otherwise."""
        if self.critic:
            return self.critic
        if self.algo == "ippo":
            return "local"
        return "team" if self.reward == "team" else "state"

    def conservative(self) -> PPOConfig:
        """Fine-tuning after a warm start: clip 0.1, lr 1e-4, entropy 1e-3, 2 critic-only
        iterations (unless already set lower / longer)."""
        return replace(self, clip=min(self.clip, 0.1), lr=min(self.lr, 1e-4),
                       entropy_coef=min(self.entropy_coef, 1e-3),
                       critic_warmup=max(self.critic_warmup, 2))


def device_of(name: str) -> torch.device:
    """``"auto"`` -> CUDA when available, else the CPU; ``"cpu"``, ``"cuda"`` or
    ``"cuda:<k>"`` as named, checked against what this torch has (``ValueError`` naming
    ``PPOConfig.device`` when it has no such device; :func:`netsense.rl.envs.resolve_device`).
    A config is checked for the device's *name* only, so a policy trained on a GPU still
    loads on a machine without one; training calls this before anything else."""
    return resolve_device(name, "PPOConfig.device")


def learner_precision(precision: str, device: torch.device) -> str:
    """``PPOConfig.precision`` resolved for a learner on ``device``: ``"fp32"`` or
    ``"bf16"``.

    ``"auto"`` is ``"bf16"`` on a CPU whose instruction set has bfloat16 dot products
    (AVX512-BF16, which every CPU with AMX also has; there oneDNN runs bfloat16 products
    at twice the float32 rate) and ``"fp32"`` elsewhere: on CPUs without them bfloat16
    is emulated and slower than float32, and on a GPU the small networks here were not
    measured in bfloat16. ``"bf16"`` asked for on a GPU without bfloat16 support raises
    ``ValueError`` naming ``PPOConfig.precision``.
    """
    if precision == "auto":
        if device.type != "cpu":
            return "fp32"
        native = getattr(torch.cpu, "_is_avx512_bf16_supported", None)
        return "bf16" if native is not None and native() else "fp32"
    if precision == "bf16" and device.type == "cuda" and not torch.cuda.is_bf16_supported():
        raise ValueError(f"PPOConfig.precision 'bf16': the learner's device {device} has no "
                         f"bfloat16 support; use 'fp32' or 'auto'")
    return precision


def loss_arithmetic(device: torch.device, precision: str):
    """The context the PPO loss's forward passes run in for a resolved ``precision``
    (:func:`learner_precision`) on ``device``: ``torch.autocast`` with bfloat16 for
    ``"bf16"`` (the layers' matrix products in bfloat16), off for ``"fp32"``. One rule for
    every pass that must match the loss's arithmetic (the update's minibatches, the
    proximal pass of :func:`netsense.rl.advantage.decouple`)."""
    return torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16")


# ------------------------------------------------------------------ field checks
#: How each field of :class:`PPOConfig` is checked (:func:`check_config_fields`): ``(kind,
#: low, high)``. Kinds: ``"int"`` (an ``int``, not a bool, float or string, in ``[low,
#: high]``), ``"int?"`` (the same or ``None``), ``"float"`` (a finite real number, not a
#: bool or string; ``low`` / ``high`` as ``(value, open)`` pairs, ``None`` for no bound),
#: ``"widths"`` (a non-empty tuple or list of ``int`` layer widths in ``[low, high]``),
#: ``"ints"`` (a tuple or list, possibly empty, of distinct ``int`` in ``[low, high]``),
#: ``"choice"`` / ``"choice?"`` (one of ``low``, compared by type and value; ``?``: or
#: ``None``), ``"str"``, ``"dict"``. A new field adds its row here.
CONFIG_CHECKS: dict[str, tuple] = {
    "scenario": ("str", None, None),
    "algo": ("choice", ALGOS, None),
    "network": ("choice", NETWORKS, None),
    "reward": ("choice", credit.REWARDS, None),
    "critic": ("choice?", CRITICS, None),
    "steps": ("int", 1, checks.MAX_STEPS),
    "seed": ("int", 0, BC_HELDOUT_SEED - 1),
    "num_envs": ("int", 1, BC_HELDOUT_SEED),
    "rollout": ("int", 1, checks.MAX_STEPS),
    "epochs": ("int", 1, 10**6),
    "minibatch": ("int", 1, checks.MAX_STEPS),
    "lr": ("float", (0.0, True), None),
    "clip": ("float", (0.0, True), (1.0, False)),
    "gamma": ("float", (0.0, False), (1.0, False)),
    "lmbda": ("float", (0.0, False), (1.0, False)),
    "entropy_coef": ("float", (0.0, False), None),
    "critic_coef": ("float", (0.0, True), None),
    "max_grad_norm": ("float", (0.0, True), None),
    "hidden": ("widths", 1, MAX_WIDTH),
    "critic_hidden": ("widths", 1, MAX_WIDTH),
    "set_hidden": ("int", 1, MAX_WIDTH),
    "set_slots": ("choice", (True, False), None),
    "memory": ("int", 0, MAX_WIDTH),
    "activation": ("choice", tuple(ACTIVATIONS), None),
    "stagger": ("choice", (True, False), None),
    "agent_features": ("choice", (True, False), None),
    "clock": ("ints", 2, checks.MAX_STEPS),
    "clock_shift": ("choice", (True, False), None),
    "clock_only": ("choice", (True, False), None),
    "comm_fields_only": ("choice", (True, False), None),
    "ages": ("ints", 1, checks.MAX_STEPS),
    "news_gate": ("choice", (True, False), None),
    "value_norm": ("choice", (True, False), None),
    "reward_scale": ("choice", (True, False), None),
    "obs_norm": ("choice", (True, False), None),
    "lr_decay": ("choice", (True, False), None),
    "entropy_final": ("float?", (0.0, False), None),
    "eval_interval": ("int", 0, checks.MAX_STEPS),
    "eval_envs": ("int", 1, BC_HELDOUT_SEED),
    "bc_steps": ("int", 1, checks.MAX_STEPS),
    "bc_epochs": ("int", 1, 10**6),
    "bc_minibatch": ("int", 1, checks.MAX_STEPS),
    "bc_lr": ("float", (0.0, True), None),
    "critic_warmup": ("int", 0, checks.MAX_STEPS),
    "device": ("str", None, None),
    "precision": ("choice", PRECISIONS, None),
    "numba_threads": ("int?", 1, 4096),
    "torch_threads": ("int?", 1, 4096),
    "overlap": ("choice", (True, False), None),
    "overrides": ("dict", None, None),
}


def check_field(owner: str, name: str, value, kind: str, low=None, high=None):
    """Check one field (a row of :data:`CONFIG_CHECKS`); return the value to store (only a
    list of widths changes: to a tuple). ``ValueError`` naming ``owner.name``, what it
    must be and what it got; types are never converted (``"100"``, ``1.5``, ``True`` are
    not integers, ``True`` is not a number)."""
    where = f"{owner}.{name}"
    if kind.endswith("?"):
        if value is None:
            return None
        kind = kind[:-1]
    if kind == "int":
        return checks.integer(where, value, low, high)
    if kind == "float":
        lo, lo_open = low if low is not None else (None, False)
        hi, hi_open = high if high is not None else (None, False)
        return checks.number(where, value, lo, hi, lo_open=lo_open, hi_open=hi_open)
    if kind == "choice":
        return checks.choice(where, value, low)
    if kind == "widths":
        if not isinstance(value, (tuple, list)) or not value:
            raise ValueError(f"{where} must be a non-empty tuple of layer widths, got "
                             f"{value!r}")
        return tuple(checks.integer(f"{where}[{i}]", w, low, high)
                     for i, w in enumerate(value))
    if kind == "ints":
        if not isinstance(value, (tuple, list)):
            raise ValueError(f"{where} must be a tuple of integers, got {value!r}")
        out = tuple(checks.integer(f"{where}[{i}]", v, low, high)
                    for i, v in enumerate(value))
        if len(set(out)) != len(out):
            raise ValueError(f"{where} must not repeat a value, got {value!r}")
        return out
    if kind == "str":
        if not isinstance(value, str):
            raise ValueError(f"{where} must be a string, got {value!r} "
                             f"({type(value).__name__})")
        return value
    if kind == "dict":
        if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
            raise ValueError(f"{where} must be a dict with string keys, got {value!r}")
        return value
    raise ValueError(f"unknown check kind {kind!r} for {where}")


def check_config_fields(config, table: dict[str, tuple]) -> None:
    """Check every field of a frozen dataclass ``config`` named in ``table``, in order
    (:func:`check_field`); normalised values (widths as tuples) are stored back."""
    owner = type(config).__name__
    for name, (kind, low, high) in table.items():
        value = getattr(config, name)
        out = check_field(owner, name, value, kind, low, high)
        if out is not value and isinstance(out, tuple):
            object.__setattr__(config, name, out)


def _check_bc(bc) -> None:
    """``bc``: ``None`` or the name of a scripted policy that
    :func:`~netsense.rl.scripted.scripted_actions` knows."""
    if bc is None:
        return
    from netsense.env.comm_policies import COMM_POLICIES, parse_spec
    from netsense.env.policies import POLICIES

    if not isinstance(bc, str):
        raise ValueError(f"PPOConfig.bc must be None or a scripted policy name, got {bc!r}")
    # a baseline's name ends at its knob or at the base rule of a gate: acked(sources:0)
    if bc.partition(":")[0].partition("(")[0] in COMM_POLICIES:
        try:
            parse_spec(bc)
        except ValueError as exc:
            raise ValueError(f"PPOConfig.bc: {exc}") from None
    elif bc not in POLICIES:
        raise ValueError(f"PPOConfig.bc must be a scripted policy: one of {list(POLICIES)} "
                         f"or a communication baseline ({', '.join(COMM_POLICIES)}, with "
                         f"an optional :knob, a gate with its base rule in parentheses), "
                         f"got {bc!r}")


def _check_scenario(config) -> None:
    """The scenario is registered; ``control`` is a mode, ``None`` or a dict of
    ``[control]`` keys; the overrides are valid for the scenario (the scenario file's
    checks, nothing built). A ``control`` override is folded into ``control`` (so that
    ``make_core(..., control=config.control, **config.overrides)`` gets it once)."""
    from netsense.env.registry import load, unknown_scenario, with_overrides

    try:
        base = load(config.scenario)
    except ValueError as exc:
        if "unknown scenario" in str(exc):
            raise ValueError(f"PPOConfig.scenario: {unknown_scenario(config.scenario)}"
                             ) from None
        raise
    over = dict(config.overrides)
    control = config.control
    if "control" in over:
        section = over.pop("control")
        if not isinstance(section, dict):
            raise ValueError(f"PPOConfig.overrides['control'] must be a table of [control] "
                             f"keys (mode, fusion), got {section!r}")
        control = {**section, **({"mode": control} if isinstance(control, str) else
                                 control if isinstance(control, dict) else {})}
    if control is not None and not isinstance(control, dict):
        checks.choice("PPOConfig.control", control, MODES)
    try:
        sc = with_overrides(base, **over, **({} if control is None else {
            "control": control if isinstance(control, dict) else {"mode": control}}))
    except ValueError as exc:
        raise ValueError(f"PPOConfig.overrides: {exc}") from None
    if isinstance(control, dict):
        control = {k: sc.control[k] for k in control}  # checked by the scenario
    if control is not config.control:
        object.__setattr__(config, "control", control)
    if over != config.overrides:
        object.__setattr__(config, "overrides", over)
