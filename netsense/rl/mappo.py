"""MAPPO and IPPO on the batched core, built from TorchRL components (torch; on demand).

Pipeline (no PPO arithmetic here: loss, advantages and collection are TorchRL's)::

    make_core(scenario, B, control)            BatchedCore (or another control mode)
      -> NetSenseBatchedEnv(core, reward)      TorchRL EnvBase, batch [B], group "agents"
      -> Collector(env, actor, B * T frames)   T steps of B environments per iteration
      -> GAE (torchrl.objectives.value)        per-agent advantages (done expanded to agents)
      -> ClipPPOLoss(actor, critic)            clipped surrogate + value + entropy terms
      -> Adam, minibatches of env-steps, gradient clipping

Actor: :func:`netsense.rl.models.mlp_actor_net` or :class:`netsense.rl.models.SetPolicyNet`
behind TorchRL's ``ProbabilisticActor`` with :class:`netsense.rl.models.MaskedMultiCategorical`
reading ``("agents", "action_mask")``; parameters shared by all agents. Critic: ``mappo``
uses the global ``state`` (:func:`netsense.rl.torchrl_batched.global_state`) with each
agent's observation (``critic="state"``) or TorchRL's ``MultiAgentMLP(centralised=True)``
over all observations (``critic="joint"``); ``ippo`` a local critic ``V_i(o_i)``.

Optional behaviour-cloning warm start (:func:`behaviour_clone`): cross-entropy of the
masked distribution on a scripted policy's actions collected through the batched core,
then PPO fine-tuning; :meth:`PPOConfig.conservative` gives the small clip range and
learning rate and the critic warm-up (actor frozen) used for that.

Outputs per run (:func:`train_ppo`): ``log.csv`` (one row per iteration: agent-steps,
wall time, throughput, training return, error, messages, losses, entropy, evaluation
columns when evaluated: ``eval_*`` with the most likely actions, ``eval_sampled_*`` with
sampled ones), TensorBoard events under ``tb/`` when ``tensorboard`` or
``tensorboardX`` is installed, ``checkpoint_<iter>.pt`` at every evaluation and
``policy.pt`` at the end (:func:`load_policy` reads them), ``config.json``. The learner
runs on CUDA when ``torch.cuda.is_available()`` (``device="auto"``); the core always
runs on the CPU.
"""

from __future__ import annotations

import csv
import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import ProbabilisticActor

from netsense.rl import credit
from netsense.rl.models import (
    CRITICS,
    MaskedMultiCategorical,
    SetPolicyNet,
    critic_net,
    mlp_actor_net,
)
from netsense.rl.torchrl_batched import CONTROLS, NetSenseBatchedEnv, make_core

__all__ = ["ALGOS", "NETWORKS", "BatchedPolicy", "PPOConfig", "behaviour_clone",
           "build_actor", "evaluate", "load_policy", "policy_config", "policy_control",
           "read_policy", "scripted_actions", "train_ppo", "training_seeds"]

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
        Actor network (:mod:`netsense.rl.models`).
    control : {None, "full", "transmit", "substates"}
        Control mode (:func:`netsense.rl.torchrl_batched.make_core`); ``None`` keeps the
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
        Scripted policy to clone before PPO (:func:`scripted_actions`).
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


def _device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


# ------------------------------------------------------------------ networks
def actor_net(config: PPOConfig, core, device=None) -> torch.nn.Module:
    """The actor's logits network for ``core``'s layout and action layout."""
    if config.network == "set":
        return SetPolicyNet(core.layout, core.nvec, hidden=config.set_hidden).to(device)
    return mlp_actor_net(core.layout, core.nvec, core.N, hidden=config.hidden, device=device)


def build_actor(net: torch.nn.Module, nvec) -> ProbabilisticActor:
    """``ProbabilisticActor``: logits from ``net``, masked by ``("agents", "action_mask")``."""
    module = TensorDictModule(net, in_keys=[("agents", "observation")],
                              out_keys=[("agents", "logits")])
    return ProbabilisticActor(
        module, in_keys={"logits": ("agents", "logits"), "mask": ("agents", "action_mask")},
        out_keys=[("agents", "action")], distribution_class=MaskedMultiCategorical,
        distribution_kwargs={"nvec": tuple(int(v) for v in nvec)}, return_log_prob=True,
        log_prob_key=("agents", "action_log_prob"),
        default_interaction_type=ExplorationType.RANDOM)


def _critic(config: PPOConfig, env: NetSenseBatchedEnv, device) -> TensorDictModule:
    net, keys = critic_net(config.critic_kind, env.layout.size, env.state_dim, env.n_agents,
                           hidden=config.critic_hidden, device=device)
    return TensorDictModule(net, in_keys=keys, out_keys=[("agents", "state_value")])


# ------------------------------------------------------------------ scripted data
def scripted_actions(name: str, core, seed: int = 0):
    """``(obs, mask) -> actions`` of a scripted policy in ``core``'s action layout.

    ``name``: a communication baseline of :mod:`netsense.env.comm_policies`
    (``event:2``, ``sources:0``, ...; communication-only modes) or a policy of
    :data:`netsense.env.policies.POLICIES` (in a communication-only mode the fusion
    rule's name means "always transmit", ``open_loop`` "never"). ``seed`` seeds the
    randomised ones.
    """
    from netsense.env.comm_policies import COMM_POLICIES, make_comm_policy
    from netsense.env.policies import make_policy

    if name.partition(":")[0] in COMM_POLICIES:
        return make_comm_policy(name, core, seed=seed).act
    return make_policy(name, core, **({"seed": seed} if name == "random" else {})).act


def _collect_scripted(config: PPOConfig, name: str, steps: int, seed: int):
    """Observations, masks and scripted actions of about ``steps`` env-steps (``num_envs``
    members, ``ceil(steps / num_envs)`` steps each), as tensors ``(rows, N, ...)``."""
    core = make_core(config.scenario, config.num_envs, control=config.control,
                     **config.overrides)
    act = scripted_actions(name, core, seed)
    obs, mask = core.reset(seed)
    rng = np.random.default_rng(seed)
    O, Mk, A = [], [], []
    for _ in range(-(-int(steps) // core.B)):
        a = act(obs, mask)
        O.append(obs.copy())
        Mk.append(mask.astype(bool))
        A.append(np.asarray(a, dtype=np.int64))
        out = core.step(a)
        obs, mask = out.obs, out.action_mask
        done = out.terminated | out.truncated
        if done.any():
            obs, mask = core.reset([int(s) for s in rng.integers(0, 2**62, core.B)],
                                   members=done)
    cat = lambda xs: torch.as_tensor(np.concatenate(xs))  # noqa: E731
    return cat(O), cat(Mk), cat(A)


def behaviour_clone(net: torch.nn.Module, config: PPOConfig, scripted: str, *,
                    steps: int | None = None, epochs: int | None = None,
                    lr: float | None = None,
                    seed: int | None = None, device=None) -> dict:
    """Warm start: minimise the cross-entropy of the masked policy on scripted actions.

    Data: about ``steps`` env-steps (default ``config.bc_steps``) of ``config.num_envs``
    members driven by ``scripted`` (members seeded from ``seed``, default the training
    seeds ``config.seed * num_envs + b``; a quarter as many held-out steps from members
    seeded from :data:`BC_HELDOUT_SEED`).

    Returns
    -------
    dict
        ``ce_before``, ``ce_after`` (held-out cross-entropy per agent-step, nats),
        ``accuracy`` (held-out share of action entries where the most likely allowed
        choice equals the scripted one), ``chance`` (the same for a uniform choice among
        the allowed ones), ``samples``.
    """
    steps = int(steps or config.bc_steps)
    epochs = int(epochs or config.bc_epochs)
    lr = float(lr or config.bc_lr)
    device = device or next(net.parameters()).device
    seed = config.seed * config.num_envs if seed is None else int(seed)
    obs, mask, act = (t.to(device) for t in _collect_scripted(config, scripted, steps, seed))
    h_obs, h_mask, h_act = (t.to(device) for t in _collect_scripted(
        config, scripted, max(steps // 4, 1), BC_HELDOUT_SEED))
    core_nvec = make_core(config.scenario, 1, control=config.control,
                          **config.overrides).nvec

    def dist(o, m):
        return MaskedMultiCategorical(net(o), m, core_nvec)

    def held_out() -> tuple[float, float]:
        with torch.no_grad():
            d = dist(h_obs, h_mask)
            ce = float(-d.log_prob(h_act).mean())
            acc = float((d.deterministic_sample == h_act).float().mean())
        return ce, acc

    ce_before, _ = held_out()
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    gen = torch.Generator().manual_seed(seed)
    rows = obs.shape[0]
    mb = max(1, min(rows, config.bc_minibatch))
    for _ in range(epochs):
        perm = torch.randperm(rows, generator=gen).to(device)
        for s in range(0, rows, mb):
            idx = perm[s:s + mb]
            loss = -dist(obs[idx], mask[idx]).log_prob(act[idx]).mean()
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), config.max_grad_norm)
            opt.step()
    ce_after, acc = held_out()
    allowed = MaskedMultiCategorical(torch.zeros(h_mask.shape, device=device), h_mask,
                                     core_nvec).base_dist.mask.sum(-1).float()
    return {"ce_before": ce_before, "ce_after": ce_after, "accuracy": acc,
            "chance": float((1.0 / allowed).mean()), "samples": rows * act.shape[1]}


# ------------------------------------------------------------------ evaluation
def _first_episode(td) -> dict:
    """Means over each member's first episode of a rollout ``td (B, T)``."""
    done = td["next", "done"][..., 0].float()  # (B, T)
    before = torch.cumsum(done, 1) - done == 0  # steps up to and including the first done
    w = before.float()
    steps = w.sum(1).clamp(min=1)
    r = td["next", "agents", "reward"][..., 0].mean(-1)  # (B, T), mean over agents
    e = td["next", "agents", "error"].mean(-1)
    s = td["next", "agents", "sent"].mean(-1)
    return {"return": float((r * w).sum(1).mean()),
            "error": float(((e * w).sum(1) / steps).mean()),
            "messages": float(((s * w).sum(1) / steps).mean())}


def evaluate(actor, config: PPOConfig, *, episodes: int | None = None,
             deterministic: bool = True) -> dict:
    """Return per agent, mean error and messages per agent-step of ``actor`` on
    ``episodes`` fresh episodes (seeds :data:`EVAL_SEED` + b), one horizon each."""
    B = int(episodes or config.eval_envs)
    core = make_core(config.scenario, B, control=config.control, **config.overrides)
    dev = next(actor.parameters()).device
    env = NetSenseBatchedEnv(core, reward=config.reward, seed=EVAL_SEED, device=dev)
    kind = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    with torch.no_grad(), set_exploration_type(kind):
        td = env.rollout(core.horizon, actor, break_when_any_done=False)
    return _first_episode(td)


def evaluate_scripted(name: str, config: PPOConfig, *, episodes: int | None = None) -> dict:
    """:func:`evaluate` for a scripted policy (same seeds, same reward option)."""
    B = int(episodes or config.eval_envs)
    core = make_core(config.scenario, B, control=config.control, **config.overrides)
    env = NetSenseBatchedEnv(core, reward=config.reward, seed=EVAL_SEED)
    act = scripted_actions(name, core)

    def policy(td):
        obs = td["agents", "observation"].numpy()
        mask = td["agents", "action_mask"].numpy().astype(np.int8)
        td["agents", "action"] = torch.as_tensor(act(obs, mask))
        return td

    td = env.rollout(core.horizon, policy, break_when_any_done=False)
    return _first_episode(td)


def mask_violations(td, nvec) -> int:
    """Agent-steps of ``td`` whose action breaks its mask (must be 0)."""
    offsets = torch.as_tensor(np.concatenate([[0], np.cumsum(nvec)[:-1]]))
    a = td["agents", "action"]
    m = td["agents", "action_mask"]
    ok = m.gather(-1, a + offsets.to(a.device)).all(-1)
    return int((~ok).sum())


# ------------------------------------------------------------------ logging
class _Log:
    """``log.csv`` (rows of varying columns, header = union) + optional TensorBoard."""

    def __init__(self, out: Path) -> None:
        self.path = out / "log.csv"
        self.rows: list[dict] = []
        self.tb = None
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:
            try:
                from tensorboardX import SummaryWriter
            except ImportError:
                SummaryWriter = None  # noqa: N806
        if SummaryWriter is not None:
            self.tb = SummaryWriter(str(out / "tb"))

    def add(self, row: dict) -> None:
        self.rows.append(row)
        if self.tb is not None:
            for k, v in row.items():
                if k != "agent_steps" and isinstance(v, (int, float)) and np.isfinite(v):
                    self.tb.add_scalar(k, v, row["agent_steps"])
        cols: list[str] = []
        for r in self.rows:
            cols += [c for c in r if c not in cols]
        with self.path.open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=cols)
            w.writeheader()
            w.writerows(self.rows)

    def close(self) -> None:
        if self.tb is not None:
            self.tb.close()


# ------------------------------------------------------------------ training
@dataclass
class PPOResult:
    """What :func:`train_ppo` produced (paths and per-iteration rows)."""

    out: Path
    rows: list[dict]
    wall_s: float
    agent_steps: int
    mask_violations: int
    bc: dict | None = None

    @property
    def agent_steps_per_s(self) -> float:
        return self.agent_steps / max(self.wall_s, 1e-9)


def _checkpoint(path: Path, config: PPOConfig, actor_net, critic, it: int, steps: int,
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


def train_ppo(config: PPOConfig, out: str | Path | None = None, *, progress: bool = False,
              evaluate_every: bool = True) -> PPOResult:
    """Train one seed; see the module docstring for what is written into ``out``.

    ``out=None`` writes nothing (benchmarks). ``evaluate_every=False`` skips the periodic
    evaluations and checkpoints (benchmarks). Sets ``torch.set_flush_denormal(True)`` for
    the process (a forward and backward pass of a warm-started actor took 0.031 s instead
    of 0.040 s with it).
    """
    from torchrl.collectors import Collector
    from torchrl.objectives import ClipPPOLoss, ValueEstimators
    from tqdm.auto import tqdm

    device = _device(config.device)
    torch.manual_seed(config.seed)
    # subnormal floats take a slow path on x86 CPUs; flushing them to zero changes
    # nothing above 1e-38
    torch.set_flush_denormal(True)
    if config.torch_threads:
        torch.set_num_threads(int(config.torch_threads))
    if config.numba_threads:
        import numba

        numba.set_num_threads(min(int(config.numba_threads), numba.config.NUMBA_NUM_THREADS))
    out = None if out is None else Path(out)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "config.json").write_text(json.dumps(asdict(config), indent=2, default=list)
                                         + "\n")
    core = make_core(config.scenario, config.num_envs, control=config.control,
                     **config.overrides)
    env = NetSenseBatchedEnv(core, reward=config.reward, seed=config.seed * config.num_envs)
    N, B, T = core.N, core.B, config.rollout
    net = actor_net(config, core, device)
    bc = None
    if config.bc:
        bc = behaviour_clone(net, config, config.bc, device=device)
    actor = build_actor(net, core.nvec).to(device)
    critic = _critic(config, env, device).to(device)
    loss = ClipPPOLoss(actor, critic, clip_epsilon=config.clip,
                       entropy_coeff=config.entropy_coef, critic_coeff=config.critic_coef,
                       normalize_advantage=True, normalize_advantage_exclude_dims=(-2,),
                       loss_critic_type="smooth_l1")
    loss.set_keys(reward=("agents", "reward"), action=("agents", "action"),
                  sample_log_prob=("agents", "action_log_prob"),
                  value=("agents", "state_value"), done=("agents", "done"),
                  terminated=("agents", "terminated"))
    loss.make_value_estimator(ValueEstimators.GAE, gamma=config.gamma, lmbda=config.lmbda)
    opt = torch.optim.Adam(loss.parameters(), lr=config.lr)
    frames = B * T
    iters = max(1, -(-int(config.steps) // (frames * N)))
    collector = Collector(env, actor, frames_per_batch=frames, total_frames=frames * iters,
                          env_device="cpu", policy_device=device, storing_device=device,
                          auto_register_policy_transforms=False)
    log = _Log(out) if out is not None else None
    acc = torch.zeros(B, N, device=device)
    returns: list[float] = []
    violations = 0
    agent_steps = 0
    t0 = time.perf_counter()
    bar = tqdm(total=frames * iters * N, desc=f"{config.algo} seed {config.seed}",
               unit="agent-step", disable=not progress)
    rows: list[dict] = []
    t_learned = t0
    collect_s = learn_s = 0.0
    for it, data in enumerate(collector):
        t_collected = time.perf_counter()
        collect_s += t_collected - t_learned
        violations += mask_violations(data, core.nvec)
        nxt = data["next"]
        for key in ("done", "terminated"):
            nxt.set(("agents", key), nxt[key].unsqueeze(-2).expand(B, T, N, 1))
        r = nxt["agents", "reward"][..., 0]
        done = nxt["done"][..., 0]
        for t in range(T):  # training episode returns (mean over agents)
            acc += r[:, t]
            d = done[:, t]
            if d.any():
                returns += acc[d].mean(-1).tolist()
                acc[d] = 0.0
        with torch.no_grad():
            loss.value_estimator(data, params=loss.critic_network_params,
                                 target_params=loss.target_critic_network_params)
        # only what the loss reads (observations, masks, state, actions, log-probs,
        # advantages, targets): gathering minibatches of the whole rollout costs more
        flat = data.exclude("next", ("agents", "logits")).reshape(-1)
        warm = it < config.critic_warmup
        sums = {"loss_objective": 0.0, "loss_critic": 0.0, "loss_entropy": 0.0, "entropy": 0.0}
        n_mb = 0
        mb = min(config.minibatch, flat.shape[0])
        for _ in range(config.epochs):
            perm = torch.randperm(flat.shape[0], device=device)
            for s in range(0, flat.shape[0] - mb + 1, mb):
                lv = loss(flat[perm[s:s + mb]])
                total = lv["loss_critic"] if warm else (
                    lv["loss_objective"] + lv["loss_critic"] + lv["loss_entropy"])
                opt.zero_grad()
                total.backward()
                torch.nn.utils.clip_grad_norm_(loss.parameters(), config.max_grad_norm)
                opt.step()
                for k in sums:
                    sums[k] += float(lv[k].detach())
                n_mb += 1
        collector.update_policy_weights_()
        t_learned = time.perf_counter()
        learn_s += t_learned - t_collected
        agent_steps += frames * N
        bar.update(frames * N)
        wall = time.perf_counter() - t0
        row = {"iteration": it, "agent_steps": agent_steps, "wall_s": round(wall, 3),
               "agent_steps_per_s": round(agent_steps / wall, 1),
               "collect_s": round(collect_s, 3), "learn_s": round(learn_s, 3),
               "train_return": float(np.mean(returns[-64:])) if returns else float("nan"),
               "train_error": float(nxt["agents", "error"].mean()),
               "train_messages": float(nxt["agents", "sent"].mean()),
               **{k: v / max(n_mb, 1) for k, v in sums.items()}}
        if not all(np.isfinite([row[k] for k in sums])):
            raise FloatingPointError(f"non-finite PPO loss at iteration {it}: {row}")
        last = it == iters - 1
        if out is not None and evaluate_every and (
                last or (config.eval_interval and (it + 1) % config.eval_interval == 0)):
            # greedy and sampled: a learned randomised schedule (transmit with some
            # probability) collapses to all-or-nothing under the greedy action
            ev = evaluate(actor, config)
            row.update({f"eval_{k}": v for k, v in ev.items()})
            ev = evaluate(actor, config, deterministic=False)
            row.update({f"eval_sampled_{k}": v for k, v in ev.items()})
            _checkpoint(out / f"checkpoint_{it + 1:05d}.pt", config, net, critic, it + 1,
                        agent_steps, core)
        rows.append(row)
        if log is not None:
            log.add(row)
        bar.set_postfix(ret=f"{row['train_return']:.3g}")
    wall = time.perf_counter() - t0
    bar.close()
    collector.shutdown()
    if out is not None:
        _checkpoint(out / "policy.pt", config, net, critic, iters, agent_steps, core)
        log.close()
        meta = {"wall_s": round(wall, 2), "agent_steps": agent_steps,
                "agent_steps_per_s": round(agent_steps / wall, 1),
                "mask_violations": violations, "device": str(device), "bc": bc}
        (out / "summary.json").write_text(json.dumps(meta, indent=2) + "\n")
    return PPOResult(out, rows, wall, agent_steps, violations, bc)


# ------------------------------------------------------------------ inference
def read_policy(path: str | Path) -> dict:
    """The contents of a ``policy.pt`` / checkpoint of :func:`train_ppo`, checked.

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
        ``policy.pt`` or a checkpoint of :func:`train_ppo`.
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
