"""Training pipeline, stage *checkpoints*: policy files (data, never code) and trained
policies.

:func:`save_checkpoint` writes the weights with what is needed to run them elsewhere (the
config, the control section the policy acted in, the layout it was trained on);
:func:`read_policy` reads and checks a file, :func:`policy_config` and
:func:`policy_control` interpret it, :class:`BatchedPolicy` / :func:`load_policy` turn it
into a batched policy (``act(obs, mask)``, the interface of the scripted policies).

**A policy file is data.** It is a ``torch.save`` of one dict: tensors (``actor``, and
``critic`` in checkpoints) and JSON-able metadata (``config``, ``control``,
``trained_on``, ``iteration``, ``agent_steps``, ``format``, ``format_version``), plus
``sha256``, the checksum of both (:func:`policy_checksum`). :func:`read_policy` loads it
with ``torch.load(weights_only=True)`` (torch's restricted unpickler: tensors and plain
containers only, so an object that would run code on loading is refused, never
called), verifies the checksum, and refuses non-finite weights and a config this netsense
does not accept; every error names the file and what is wrong. :func:`seal_policy` adds
the checksum to a file written before netsense stored one (``netsense policy convert``).

Imports: torch and the stages below.
"""

from __future__ import annotations

from dataclasses import asdict, fields
from pathlib import Path

import numpy as np
import torch

from netsense.rl.atomic import atomic_path
from netsense.rl.config import PPOConfig
from netsense.rl.distributions import MaskedMultiCategorical
from netsense.rl.envs import make_core
from netsense.rl.memory import is_recurrent
from netsense.rl.policy import actor_net
from netsense.rl.policy_files import check_weights, content_checksum, load_tensors, plain
from netsense.rl.run_folder import check_finished

__all__ = ["FORMAT", "FORMAT_VERSION", "BatchedPolicy", "load_policy",
           "policy_checksum", "policy_config", "policy_control", "policy_state",
           "read_policy", "save_checkpoint", "seal_policy", "strip_critic", "write_policy"]

#: ``format`` entry of a batched-trainer policy file, and the newest version read.
FORMAT = "netsense-batched-policy"
FORMAT_VERSION = 1
#: Entries holding tensors (state dicts); every other entry is JSON-able metadata.
TENSOR_ENTRIES = ("actor", "critic")
#: Config keys a file must hold (the network cannot be rebuilt without them); other
#: missing keys take :class:`PPOConfig`'s defaults (files of an older netsense).
REQUIRED_CONFIG = ("scenario", "network", "hidden", "set_hidden")


def policy_checksum(state: dict) -> str:
    """``sha256`` (hex) of a policy file's content
    (:func:`netsense.rl.policy_files.content_checksum`): its metadata (every entry but
    the tensors and ``sha256``) and the tensors of :data:`TENSOR_ENTRIES`.

    Raises ``ValueError`` when the metadata is not JSON-able or a tensor entry is not a
    dict of tensors.
    """
    meta = {k: v for k, v in state.items() if k not in TENSOR_ENTRIES and k != "sha256"}
    return content_checksum(meta, {k: state[k] for k in TENSOR_ENTRIES if k in state})


def write_policy(path: str | Path, state: dict) -> Path:
    """Write a policy file: ``state``'s metadata made JSON-able, ``format`` and
    ``format_version`` set, the checksum added (:func:`policy_checksum`). The file is
    written next to ``path`` and renamed over it (a reader never sees half a file)."""
    path = Path(path)
    out = {k: (v if k in TENSOR_ENTRIES else plain(v)) for k, v in state.items()
           if k != "sha256"}
    out["format"], out["format_version"] = FORMAT, FORMAT_VERSION
    for entry in TENSOR_ENTRIES:
        if entry in out:
            out[entry] = {k: t.detach().cpu() for k, t in out[entry].items()}
    out["sha256"] = policy_checksum(out)
    with atomic_path(path) as tmp:
        torch.save(out, tmp)
    return path


def strip_critic(path: str | Path) -> Path:
    """Rewrite a policy file without its critic (acting needs the actor only; committed
    results keep their files small); the checksum is recomputed."""
    state = read_policy(path)
    state.pop("critic", None)
    return write_policy(path, state)


def policy_state(config: PPOConfig, actor_net, it: int, steps: int, core) -> dict:
    """The entries of a policy file for the weights of ``actor_net``: the config, the
    control section the policy acted in (mode and fusion, resolved from the scenario),
    the layout sizes it was trained on, the iteration and agent-steps (what
    :func:`write_policy` writes; the evolution strategy writes this, without a critic)."""
    ctl = core.model.control
    return {
        "config": asdict(config), "actor": actor_net.state_dict(),
        "iteration": int(it), "agent_steps": int(steps),
        "control": {"mode": ctl.mode, "fusion": ctl.fusion},
        "trained_on": {"N": int(core.N), "D": int(core.D), "M": int(core.M),
                       "obs_dim": int(core.layout.size),
                       "nvec": [int(v) for v in core.nvec]}}


def save_checkpoint(path: Path, config: PPOConfig, actor_net, critic, it: int, steps: int,
                    core) -> None:
    """Weights with what is needed to run them elsewhere (:func:`policy_state`) and the
    critic (:func:`write_policy`)."""
    write_policy(path, dict(policy_state(config, actor_net, it, steps, core),
                            critic=critic.state_dict()))


def _load(path: Path) -> dict:
    """:func:`netsense.rl.policy_files.load_tensors` of a file that exists."""
    if not path.exists():
        raise ValueError(f"no policy file at {path} (train one with `netsense train "
                         "--backend torchrl`)")
    if not path.is_file():
        raise ValueError(f"{path}: not a policy file (a directory?)")
    return load_tensors(path, str(path))


def _check_structure(state, path: Path) -> None:
    """The entries of a policy file and their types; errors name the file and entry."""
    if not isinstance(state, dict):
        raise ValueError(f"{path}: not a policy file of netsense's batched trainer (a "
                         f"{type(state).__name__}, not a dict of entries)")
    missing = [k for k in ("config", "actor") if k not in state]
    if missing:
        raise ValueError(f"{path}: not a policy file of netsense's batched trainer (no "
                         f"{' and '.join(repr(k) for k in missing)} "
                         f"entr{'ies' if len(missing) > 1 else 'y'})")
    if not isinstance(state["config"], dict):
        raise ValueError(f"{path}: entry 'config' must be a dict, got "
                         f"{type(state['config']).__name__}")
    for entry in TENSOR_ENTRIES:
        if entry in state and not (isinstance(state[entry], dict) and all(
                isinstance(t, torch.Tensor) for t in state[entry].values())):
            raise ValueError(f"{path}: entry '{entry}' must be a dict of tensors")
    ctl = state.get("control")
    if ctl is not None and not (isinstance(ctl, dict) and set(ctl) <= {"mode", "fusion"}):
        raise ValueError(f"{path}: entry 'control' must be a dict of [control] keys (mode, "
                         f"fusion), got {ctl!r}")
    trained = state.get("trained_on")
    if trained is not None:
        ok = isinstance(trained, dict) and all(
            isinstance(trained.get(k), int) for k in ("N", "D", "M", "obs_dim")) and \
            isinstance(trained.get("nvec"), (list, tuple)) and all(
                isinstance(v, int) for v in trained["nvec"])
        if not ok:
            raise ValueError(f"{path}: entry 'trained_on' must hold the integers N, D, M, "
                             f"obs_dim and the list nvec, got {trained!r}")


def read_policy(path: str | Path) -> dict:
    """The contents of a ``policy.pt`` / checkpoint of :func:`~netsense.rl.ppo.train_ppo`, checked.

    Loads with ``torch.load(weights_only=True)`` (no code in the file runs), then checks
    the entries, the checksum (:func:`policy_checksum`), that the weights are finite and
    that the stored config is one this netsense accepts (:func:`policy_config`).

    Raises
    ------
    ValueError
        Naming the file and what is wrong: missing, in the folder of an unfinished
        training run (:func:`netsense.rl.run_folder.check_finished`), unreadable,
        holding objects other than tensors and plain data, not a checkpoint of this
        trainer, without a checksum (written before netsense stored one:
        :func:`seal_policy`), a checksum that does not match (the file changed after
        it was written), non-finite weights, a config this netsense refuses.
    """
    path = Path(path)
    state = _load(path)
    check_finished(path.parent)  # a killed run's folder holds no final policy
    _check_structure(state, path)
    if "sha256" not in state:
        raise ValueError(f"{path}: the file carries no checksum (written by a netsense "
                         "before policy files had one); if you trust it, add one with "
                         f"`netsense policy convert {path} --trust`")
    fmt, version = state.get("format"), state.get("format_version")
    if fmt != FORMAT or not isinstance(version, int) or not 1 <= version <= FORMAT_VERSION:
        raise ValueError(f"{path}: format {fmt!r} version {version!r}; this netsense reads "
                         f"{FORMAT!r} versions 1..{FORMAT_VERSION}")
    try:
        digest = policy_checksum(state)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    if digest != state["sha256"]:
        raise ValueError(f"{path}: checksum mismatch: the tensors or the configuration "
                         "changed after the file was written (corrupted, or edited); "
                         f"stored {str(state['sha256'])[:16]}..., content {digest[:16]}...")
    for entry in TENSOR_ENTRIES:
        if entry in state:
            check_weights(state[entry], f"{path}: {entry}")
    policy_config(state, path)
    return state


def seal_policy(path: str | Path, out: str | Path | None = None) -> Path:
    """Add the checksum (and ``format``) to a policy file written before netsense stored
    one, after the checks of :func:`read_policy` but the checksum (weights finite, config
    accepted). Reads with ``weights_only=True``: sealing runs nothing in the file, but it
    vouches for the weights: seal only files you trust. Writes ``out`` (default: in
    place); returns its path."""
    path = Path(path)
    state = _load(path)
    _check_structure(state, path)
    if "sha256" in state:
        read_policy(path)  # already sealed: it must verify
    for entry in TENSOR_ENTRIES:
        if entry in state:
            check_weights(state[entry], f"{path}: {entry}")
    policy_config(state, path)
    return write_policy(path if out is None else out, state)


def policy_config(state: dict, path: str | Path | None = None) -> PPOConfig:
    """The :class:`PPOConfig` stored in a checkpoint (:func:`read_policy`).

    Keys of :data:`REQUIRED_CONFIG` must be present; other missing keys take the
    defaults (files of an older netsense); unknown keys (a newer netsense) and values
    the config refuses raise ``ValueError`` naming ``path`` and the key.
    """
    where = f"{path}: " if path is not None else ""
    cfg = dict(state["config"])
    missing = [k for k in REQUIRED_CONFIG if k not in cfg]
    if missing:
        raise ValueError(f"{where}the stored config lacks {missing} (needed to rebuild the "
                         "network); not a policy file of this trainer, or damaged")
    known = {f.name for f in fields(PPOConfig)}
    unknown = sorted(set(cfg) - known)
    if unknown:
        raise ValueError(f"{where}the stored config has keys this netsense does not know: "
                         f"{unknown} (written by a newer netsense?)")
    # Files written before the activation was an option used tanh; the default changed
    # since, so a file without the field must not take the new default.
    cfg.setdefault("activation", "tanh")
    for key in ("hidden", "critic_hidden"):
        if isinstance(cfg.get(key), list):
            cfg[key] = tuple(cfg[key])
    try:
        return PPOConfig(**cfg)
    except ValueError as exc:
        raise ValueError(f"{where}the stored config is refused: {exc}") from None


def policy_control(state: dict) -> dict | str | None:
    """What the policy of a checkpoint (:func:`read_policy`) acted in: the stored
    ``[control]`` keys (mode, fusion), else (files written before they were stored) the
    config's ``control`` (a mode name, a dict, or ``None``: the scenario's)."""
    return state.get("control") or policy_config(state).control


def _fit(net: torch.nn.Module, weights: dict, path: Path, what: str) -> None:
    """Load ``weights`` into ``net`` after comparing names and shapes; a mismatch is a
    ``ValueError`` naming the file, the tensors and both shapes."""
    want = net.state_dict()
    missing = sorted(set(want) - set(weights))
    extra = sorted(set(weights) - set(want))
    shapes = [f"'{k}' {tuple(weights[k].shape)} in the file, {tuple(want[k].shape)} "
              "needed" for k in want if k in weights and weights[k].shape != want[k].shape]
    if missing or extra or shapes:
        parts = ([f"missing {missing[:4]}"] if missing else []) + (
            [f"unexpected {extra[:4]}"] if extra else []) + shapes[:4]
        raise ValueError(f"{path}: the actor's weights do not fit {what}: "
                         + "; ".join(parts))
    net.load_state_dict(weights)


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
        path = Path(path)
        state = read_policy(path)
        self.path = path
        self.config = policy_config(state, path)
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
        if self.config.network == "set":
            ctl = policy_control(state)
            mode = ctl.get("mode", "full") if isinstance(ctl, dict) else ctl
            if mode is not None and (mode != "full") != core.control.comm_only:
                need = ("a communication-only mode ('transmit' or 'substates')"
                        if mode != "full" else "control mode 'full'")
                raise ValueError(
                    f"{path}: a set-network policy runs on any layout of its kind; this one "
                    f"was trained in control mode {mode!r}, "
                    f"{'with' if mode != 'full' else 'without'} the communication-only "
                    f"observation fields, and the core here is in mode "
                    f"{core.control.mode!r}, {'with' if core.control.comm_only else 'without'}"
                    f" them: run it in {need}")
        try:
            self.net = actor_net(self.config, core, torch.device("cpu"))
        except ValueError as exc:
            raise ValueError(f"{path}: cannot build its {self.config.network} network for "
                             f"this core: {exc}") from None
        _fit(self.net, state["actor"], path,
             f"the {self.config.network} network built for this core (N = {core.N}, "
             f"obs_dim = {core.layout.size}, nvec = {[int(v) for v in core.nvec]})")
        self.net.eval()
        self.nvec = tuple(int(v) for v in core.nvec)
        self.deterministic = deterministic
        #: a recurrent actor's state ``(B, N, memory)``; zeroed for every agent whose
        #: observation says ``time = 0`` (an episode starts), so partial resets work
        self.hidden: torch.Tensor | None = None
        self._time = core.layout.time

    def act(self, obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            o = torch.as_tensor(obs)
            if is_recurrent(self.net):
                if self.hidden is None or self.hidden.shape[:-1] != o.shape[:-1]:
                    self.hidden = torch.zeros(*o.shape[:-1], self.net.memory)
                start = (o[..., self._time][..., 0] == 0).unsqueeze(-1)
                logits, self.hidden = self.net(o, self.hidden.masked_fill(start, 0.0))
            else:
                logits = self.net(o)
            d = MaskedMultiCategorical(logits, torch.as_tensor(np.asarray(mask).astype(bool)),
                                       self.nvec)
            a = d.deterministic_sample if self.deterministic else d.sample()
        return a.numpy()


def load_policy(path: str | Path, core=None, *, deterministic: bool = True) -> BatchedPolicy:
    """:class:`BatchedPolicy` from ``policy.pt`` or a checkpoint."""
    return BatchedPolicy(path, core, deterministic=deterministic)
