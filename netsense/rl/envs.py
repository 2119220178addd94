"""Training pipeline, stage *environment*: a TorchRL ``EnvBase`` over
:class:`netsense.engine.core.BatchedCore`: ``B`` environments, one agent group (imports
torch and TorchRL; import this module on demand).

:class:`NetSenseBatchedEnv` is the environment of the batched training path
(:mod:`netsense.rl.ppo`). Every step is one call of the core's ``step`` on the whole
batch; nothing is re-implemented. Batch size ``[B]``; all ``N`` agents in the group
``"agents"``. Keys (shapes without the leading ``B``):

===============================  ==========================================================
key                              content
===============================  ==========================================================
``("agents", "observation")``    ``(N, obs_dim)`` float32, the core's flat observation
                                 (layout :class:`netsense.engine.model.ObsLayout`)
``("agents", "action_mask")``    ``(N, sum(nvec))`` bool, the core's flat mask (``True`` =
                                 allowed), read by :class:`netsense.rl.distributions.
                                 MaskedMultiCategorical`; the action spec's mask is
                                 updated with it at every step, so ``rand_action`` and
                                 ``check_env_specs`` draw only allowed actions
``("agents", "action")``         ``(N, len(nvec))`` int64, ``MultiCategorical(core.nvec)``
``("agents", "reward")``         ``(N, 1)``, the reward option (:mod:`netsense.rl.credit`)
``("agents", "error")``          ``(N,)`` clipped normalised errors of the last step
``("agents", "sent")``           ``(N,)`` float, transmit flags chosen at the last step
``"state"``                      ``(S,)`` global state for a centralised critic
                                 (:func:`global_state`)
``"done"``, ``"terminated"``,    ``(1,)`` bool per member; all agents of a member end
``"truncated"``                  together (horizon or divergence)
===============================  ==========================================================

The action layout is the core's (``core.nvec``, ``core.mask_size``): full control
``[D + 2] * M + [2]``, ``[2]`` in the communication-only mode ``"transmit"`` and
``[2] * M`` in ``"substates"`` (:mod:`netsense.engine.control`; the observation then
carries the communication fields ``news``, ``silence``, ``channel_load``, ``collided``,
``agent_id``).

Resets: ``reset()`` seeds member ``b`` with ``seed + b`` (``set_seed``); TorchRL's
partial resets (``"_reset"`` of shape ``(B, 1)``, as collectors send for finished members)
restart only those members, with seeds drawn from ``numpy.random.default_rng(seed)``, as
:class:`netsense.env.vector.BatchedEnv` does.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Categorical, Composite, MultiCategorical, Unbounded
from torchrl.envs import EnvBase

from netsense.engine.control import MODES
from netsense.engine.core import BatchedCore, CoreModel
from netsense.env.registry import ENV_OPTIONS, control_overrides
from netsense.env.vector import load_model
from netsense.kernels import checks
from netsense.kernels.update import OMEGA
from netsense.rl import credit

__all__ = ["CONTROLS", "NetSenseBatchedEnv", "global_state", "make_core", "resolve_device",
           "state_edges", "state_size"]

#: Control modes :func:`make_core` accepts (``None``: the scenario's own ``[control]``).
CONTROLS = (None, *MODES)


def make_core(scenario: str | CoreModel, num_envs: int, *, control: str | dict | None = None,
              **overrides) -> BatchedCore:
    """The :class:`BatchedCore` of ``num_envs`` copies of a scenario in a control mode.

    ``control``: ``None`` keeps the scenario's ``[control]``; ``"full"`` (keep / adopt /
    average per substate, transmit), ``"transmit"`` or ``"substates"`` (communication
    only: the scenario's fusion rule adopts, the agents send;
    :mod:`netsense.engine.control`) set its mode; a dict sets any of its keys.
    ``num_envs`` is an integer >= 1 (not a float or a string); a batch whose arrays do not
    fit in memory is a ``ValueError`` naming it.
    """
    B = checks.integer("num_envs", num_envs, 1)
    if control is not None and not isinstance(scenario, str):
        raise ValueError("control needs a scenario id; a CoreModel carries its own mode")
    env_only = sorted(set(overrides) & ENV_OPTIONS)
    if env_only:
        raise ValueError(f"{env_only} are options of the PettingZoo env, not scenario keys; "
                         "a BatchedCore has no such option here")
    if isinstance(scenario, str):
        overrides = control_overrides(scenario, control, overrides)
    model, _ = load_model(scenario, **overrides)
    if B >= _PROBE_FROM:
        _check_memory(model, B)
    try:
        return BatchedCore(model, B)
    except MemoryError:
        raise ValueError(f"num_envs = {B}: the arrays of {B} copies of the scenario do not "
                         "fit in this machine's memory; use fewer environments") from None


#: Batch sizes from which :func:`make_core` measures a member's memory first.
_PROBE_FROM = 4096


def _array_bytes(obj) -> int:
    arrays = [v for v in vars(obj).values() if isinstance(v, np.ndarray)]
    comm = getattr(obj, "comm", None)
    if comm is not None:
        arrays += [v for v in vars(comm).values() if isinstance(v, np.ndarray)]
    return sum(a.nbytes for a in arrays)


def _available_bytes() -> float:
    """Memory this process may still use: ``MemAvailable`` and the address-space limit."""
    import resource

    avail = float("inf")
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
    except OSError:
        pass
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft not in (resource.RLIM_INFINITY, -1):
        avail = min(avail, soft)
    return avail


def _check_memory(model: CoreModel, B: int) -> None:
    """Refuse a batch whose arrays cannot fit: a member's bytes measured on cores of one
    and two members after a reset (a lower bound on what ``B`` members take)."""
    sizes = []
    for b in (1, 2):
        probe = BatchedCore(model, b)
        probe.reset(0)
        sizes.append(_array_bytes(probe))
    per = max(sizes[1] - sizes[0], 1)
    need, avail = per * B, _available_bytes()
    if need > avail:
        raise ValueError(f"num_envs = {B}: the core's arrays alone take about "
                         f"{need / 2**30:.1f} GiB ({per} bytes per member) and "
                         f"{avail / 2**30:.1f} GiB are available; use fewer environments")


def resolve_device(device, name: str = "device") -> torch.device:
    """The torch device ``device`` names, checked against what this torch has.

    ``"auto"``: CUDA when available, else the CPU; ``"cpu"``, ``"cuda"``, ``"cuda:<k>"``
    or a ``torch.device`` of those kinds. ``ValueError`` naming ``name`` for anything
    else, for CUDA when torch sees no CUDA device, and for an index beyond the devices.
    """
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if isinstance(device, torch.device):
        dev = device
    elif isinstance(device, str):
        try:
            dev = torch.device(device)
        except (RuntimeError, ValueError):
            dev = None
    else:
        dev = None
    if dev is None or dev.type not in ("cpu", "cuda"):
        raise ValueError(f"{name} must be 'auto', 'cpu', 'cuda' or 'cuda:<index>', got "
                         f"{device!r}")
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            built = torch.version.cuda
            raise ValueError(f"{name} = {device!r}, but torch sees no CUDA device here "
                             f"(torch {torch.__version__}, "
                             f"{'built with CUDA ' + built if built else 'a CPU-only build'})"
                             "; use 'cpu' or 'auto'")
        count = torch.cuda.device_count()
        if dev.index is not None and dev.index >= count:
            raise ValueError(f"{name} = {device!r}, but torch sees {count} CUDA "
                             f"device{'s' if count != 1 else ''} (indices 0..{count - 1})")
    return dev


def state_size(N: int, M: int, edges: int | None = None) -> int:
    """Length of :func:`global_state`: ``1 + 2 N + E + 2 N M`` with ``E = edges``, the
    adjacency entries the state carries (``N^2`` when ``None``: :func:`state_edges`)."""
    return 1 + 2 * N + (N * N if edges is None else int(edges)) + 2 * N * M


class _SupportSlots:
    """Where each edge of a graph process's support sits: ``base[i, j]`` the ``j``-th
    possible in-neighbour of node ``i`` (ascending; ``-1`` pads), ``valid`` its mask; the
    state's adjacency entries are ``base[valid]``'s, in row-major order."""

    def __init__(self, support: np.ndarray):
        support = np.asarray(support, bool)
        deg = support.sum(-1)
        width = max(int(deg.max(initial=0)), 1)
        self.base = np.full((support.shape[0], width), -1, np.int64)
        self.valid = np.arange(width)[None, :] < deg[:, None]
        self.base[self.valid] = np.nonzero(support)[1]
        self.edges = int(deg.sum())

    def entries(self, nbr: np.ndarray) -> np.ndarray:
        """``(B, E)`` bool: which support edges are up, from the slot table ``nbr``
        ``(B, N, D)`` (``-1`` = empty slot)."""
        up = (nbr[:, :, None, :] == self.base[None, :, :, None]).any(-1)
        return up[:, self.valid]


def _support_slots(core) -> _SupportSlots | None:
    support = getattr(core.model.graphs, "edge_support", None)
    if support is None:
        return None
    cached = getattr(core, "_state_support", None)
    if cached is None:
        cached = _SupportSlots(support)
        core._state_support = cached
    return cached


def state_edges(core) -> int | None:
    """The number of adjacency entries :func:`global_state` carries for ``core``: the
    edges of the graph process's support (:attr:`netsense.graphs.processes.GraphProcess.
    edge_support`, e.g. the base graph of Markov link failures), or ``None`` (all ``N^2``
    pairs) where the process fixes none."""
    slots = _support_slots(core)
    return None if slots is None else slots.edges


def global_state(core) -> np.ndarray:
    """``(B, S)`` float32 global state of every member, each entry bounded.

    ``[k / H, e (N), t (N), G[k] (E), max(tau, 0) / H (N x M), [tau = omega] (N x M)]``:
    time, the agents' clipped normalised errors of the last step, the transmit flags for
    the next step, the adjacency of the current graph and every agent's freshness indices
    (true ones, a liar's claims aside). ``S`` = :func:`state_size`. The adjacency is all
    ``N x N`` entries, row-major, where the graph process fixes no support; where it does
    (:func:`state_edges`: Markov link failures on a base graph), only the ``E`` entries on
    the support, row-major: nothing is lost (every other entry is always ``False``) and the
    state grows like ``N D`` instead of ``N^2``.
    """
    B = core.B
    H = float(core.horizon)
    tau = core.tau
    slots = _support_slots(core)
    adjacency = (core.adjacency.reshape(B, -1) if slots is None
                 else slots.entries(core.nbr))
    parts = [core.k[:, None] / H, core.errors, core.transmit, adjacency,
             (np.maximum(tau, 0) / H).reshape(B, -1), (tau == OMEGA).reshape(B, -1)]
    out = np.empty((B, state_size(core.N, core.M, adjacency.shape[1])), dtype=np.float32)
    o = 0
    for p in parts:
        out[:, o:o + p.shape[1]] = p
        o += p.shape[1]
    return out


class NetSenseBatchedEnv(EnvBase):
    """``B`` netsense environments as one TorchRL environment (see the module docstring).

    Parameters
    ----------
    core : BatchedCore
        What to step (:func:`make_core`), in any control mode; its batch size is the
        env's.
    reward : str
        One of :data:`netsense.rl.credit.REWARDS`.
    seed : int, optional
        Seed of the first reset.
    device : str or torch device
        Where the env's tensors live (the core itself runs on the CPU); checked by
        :func:`resolve_device`.
    """

    batch_locked = True

    def __init__(self, core, *, reward: str = "scenario", seed: int | None = 0,
                 device="cpu") -> None:
        if not isinstance(core, BatchedCore):
            raise ValueError(f"core must be a BatchedCore (make_core), got "
                             f"{type(core).__name__}")
        checks.choice("reward", reward, credit.REWARDS)
        if seed is not None:
            seed = checks.seed_value("seed", seed, int(core.B))
        bound = core.model.reward_bound
        if not bound <= float(np.finfo(np.float32).max):
            raise ValueError(f"reward: rewards up to {bound:.3g} in magnitude do not fit the "
                             "float32 reward spec of the TorchRL env (|r| <= 3.4e38); scale "
                             "the [reward] weights down")
        B, N = int(core.B), int(core.N)
        device = resolve_device(device)
        super().__init__(device=device, batch_size=torch.Size([B]))
        self.core = core
        self.reward_option = reward
        self.nvec = np.asarray(core.nvec, dtype=np.int64)
        self.n_agents = N
        self.layout = core.layout
        K, A = int(self.nvec.sum()), int(self.nvec.size)
        if K != int(core.mask_size):
            raise ValueError(f"core.mask_size ({core.mask_size}) != sum(core.nvec) ({K})")
        self.state_dim = state_size(N, core.M, state_edges(core))
        rc = core.model.reward
        self._w = (float(rc.error_weight), float(rc.team_weight))
        self._alive = np.asarray(core.alive, bool)
        if reward == "counterfactual":
            # the factors of block_errors: T^{-1} and the substate of every coordinate
            credit.check_adoptions(core)  # before any state is set up
            self._T_inv = np.linalg.inv(core.T)
            blocks = np.zeros((core.n, core.M))
            col = np.full(N, -1)
            col[np.asarray(core.sources)] = np.arange(core.M)
            cols = col[core.block_of]
            blocks[np.flatnonzero(cols >= 0), cols[cols >= 0]] = 1.0
            self._blocks = blocks
            self._floor, self._clip = float(rc.error_floor), float(rc.error_clip)
        #: the chains of the ``"lifetime"`` reward (:class:`netsense.rl.credit.LifetimeCredit`;
        #: None for the other options)
        self.lifetime_credit = None
        if reward == "lifetime":
            self.lifetime_credit = credit.LifetimeCredit(core, self._alive)  # checks adoptions
        dev = self.device
        agents = Composite(
            observation=Unbounded((B, N, self.layout.size), dtype=torch.float32, device=dev),
            action_mask=Binary(n=K, shape=(B, N, K), dtype=torch.bool, device=dev),
            error=Unbounded((B, N), dtype=torch.float32, device=dev),
            sent=Unbounded((B, N), dtype=torch.float32, device=dev),
            shape=(B, N), device=dev)
        self.full_observation_spec = Composite(
            agents=agents, state=Unbounded((B, self.state_dim), dtype=torch.float32,
                                           device=dev), shape=(B,), device=dev)
        self.full_action_spec = Composite(agents=Composite(
            action=MultiCategorical(nvec=self.nvec.tolist(), shape=(B, N, A), dtype=torch.int64,
                                    device=dev, remove_singleton=False),
            shape=(B, N), device=dev), shape=(B,), device=dev)
        self.full_reward_spec = Composite(agents=Composite(
            reward=Unbounded((B, N, 1), dtype=torch.float32, device=dev), shape=(B, N),
            device=dev), shape=(B,), device=dev)
        flag = Categorical(2, (B, 1), dtype=torch.bool, device=dev)
        self.full_done_spec = Composite(done=flag.clone(), terminated=flag.clone(),
                                        truncated=flag.clone(), shape=(B,), device=dev)
        self._seed: int | None = None
        self._seed_rng = np.random.default_rng()
        self._started = False
        if seed is not None:
            self.set_seed(int(seed))

    # ------------------------------------------------------------------ helpers
    def _set_seed(self, seed: int | None) -> None:
        self._seed = None if seed is None else int(seed)
        self._seed_rng = np.random.default_rng(seed)
        self._started = False

    def _tensor(self, a: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(a, device=self.device)

    def _obs_td(self, obs: np.ndarray, mask: np.ndarray) -> dict:
        B, N = self.batch_size[0], self.n_agents
        maskb = torch.as_tensor(np.asarray(mask).view(np.bool_), device=self.device)
        self.full_action_spec["agents", "action"].update_mask(maskb)
        return {
            "agents": TensorDict({
                "observation": self._tensor(obs),
                "action_mask": maskb,
                "error": self._tensor(self.core.errors.astype(np.float32)),
                "sent": self._tensor(self.core.transmit.astype(np.float32)),
            }, batch_size=(B, N), device=self.device),
            "state": self._tensor(global_state(self.core)),
        }

    def _flags(self, terminated: np.ndarray, truncated: np.ndarray) -> dict:
        t = self._tensor(terminated.reshape(-1, 1))
        u = self._tensor(truncated.reshape(-1, 1))
        return {"done": t | u, "terminated": t, "truncated": u}

    # ------------------------------------------------------------------ arrays
    def restart(self, members: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Start episodes and return the core's ``(obs, mask)`` (numpy, no TensorDict).

        ``members=None`` (or every member) restarts the whole batch: the first time with the
        seeds ``seed + b``, later with seeds drawn from the env's generator; a bool mask
        ``(B,)`` restarts only those members (fresh seeds from the generator). This is the
        one implementation of the env's resets: :meth:`_reset` and the training loop's
        collection (:mod:`netsense.rl.rollout`) both call it.
        """
        B = self.batch_size[0]
        sel = None if members is None or bool(np.all(members)) else np.asarray(members, bool)
        if self.reward_option == "lifetime":
            self.lifetime_credit.restart(sel)
        if sel is None or not self._started:
            if self._seed is not None and not self._started:
                seeds = [self._seed + b for b in range(B)]
            else:
                seeds = [int(s) for s in self._seed_rng.integers(0, 2**62, size=B)]
            out = self.core.reset(seeds)
            self._started = True
            return out
        seeds = [int(s) for s in self._seed_rng.integers(0, 2**62, size=B)]
        return self.core.reset(seeds, members=sel)

    def advance(self, actions: np.ndarray) -> tuple[np.ndarray, ...]:
        """One step of every member under ``actions (B, N, len(nvec))``.

        Returns ``(obs, mask, reward, terminated, truncated)`` as numpy arrays; ``reward``
        is ``(B, N)`` float32 of the env's reward option (:mod:`netsense.rl.credit`). The
        one implementation of a step: :meth:`_step` and the training loop call it.
        """
        core = self.core
        cr = None
        if self.reward_option == "lifetime":
            self.lifetime_credit.before(core, actions)
        elif self.reward_option == "counterfactual":
            adopted = credit.adopted_slots(core, actions)
            eps = credit.block_errors(core.Z, core.x, self._T_inv, self._blocks,
                                      self._floor, self._clip)
            cr = credit.sender_credit(eps, adopted, core.nbr, self._alive)
        out = core.step(actions)
        if self.reward_option == "lifetime":
            cr = self.lifetime_credit.after(core)
        r = credit.shaped_reward(self.reward_option, out.reward, core.errors, self._alive,
                                 *self._w, credit=cr)
        return out.obs, out.action_mask, r.astype(np.float32), out.terminated, out.truncated

    # ------------------------------------------------------------------ EnvBase
    def _reset_mask(self, tensordict: TensorDictBase | None) -> np.ndarray | None:
        """The ``_reset`` entry as a ``(B,)`` bool array (``None``: absent); a mask of
        another shape or dtype is a ``ValueError`` naming it and the shape expected."""
        if tensordict is None or "_reset" not in tensordict.keys():
            return None
        B = int(self.batch_size[0])
        m = tensordict.get("_reset")
        if not isinstance(m, torch.Tensor) or m.dtype != torch.bool or \
                tuple(m.shape) not in ((B,), (B, 1)):
            what = (f"{m.dtype} of shape {tuple(m.shape)}" if isinstance(m, torch.Tensor)
                    else type(m).__name__)
            raise ValueError(f"reset: '_reset' must be a bool mask of shape ({B},) or "
                             f"({B}, 1), one entry per environment of the batch, got {what}")
        return m.reshape(B).cpu().numpy()

    def reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        """TorchRL's ``reset``, after checking the given tensordict: its batch size must
        be the env's ``(B,)`` and its ``_reset`` mask, if any, a bool tensor of shape
        ``(B,)`` or ``(B, 1)`` (``ValueError`` naming the argument otherwise)."""
        if tensordict is not None:
            if tuple(tensordict.batch_size) != tuple(self.batch_size):
                raise ValueError(f"reset: the tensordict's batch size must be the env's "
                                 f"{tuple(self.batch_size)}, got "
                                 f"{tuple(tensordict.batch_size)}")
            self._reset_mask(tensordict)
        return super().reset(tensordict, **kwargs)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        B = self.batch_size[0]
        sel = self._reset_mask(tensordict)
        obs, mask = self.restart(sel)
        zeros = np.zeros(B, bool)
        return TensorDict({**self._obs_td(obs, mask), **self._flags(zeros, zeros)},
                          batch_size=self.batch_size, device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        actions = tensordict.get(("agents", "action")).cpu().numpy()
        obs, mask, r, terminated, truncated = self.advance(actions)
        td = {**self._obs_td(obs, mask), **self._flags(terminated, truncated)}
        td["agents"].set("reward", self._tensor(r[..., None]))
        return TensorDict(td, batch_size=self.batch_size, device=self.device)
