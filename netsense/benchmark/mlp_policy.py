"""A framework-neutral policy file: an MLP's weights in an ``.npz``, run with numpy.

Any trainer (your own PPO, BenchMARL, JAX, ...) can write one, and the benchmark suite
(:mod:`netsense.benchmark.suite`) scores it; nothing in it is code. The file is a NumPy
``.npz`` archive read with ``numpy.load(allow_pickle=False)``, holding

* ``header``: a 0-d unicode array, the JSON object below;
* one floating-point array per weight and bias the header names;
* optionally ``agent_features``, an ``(N, F)`` float array appended to agent ``i``'s
  observation as its row ``i`` (a fixed per-agent input, such as a one-hot of the
  substate the agent measures).

The header::

    {"format": "netsense-mlp-policy", "format_version": 1,
     "task": "comm_announced-v0",          # the scenario id it acts in
     "control": "transmit",                # communication-only control mode
     "obs_dim": 152, "nvec": [2],          # observation size, choices per action entry
     "inputs": ["observation", "agent_features"],
     "layers": [{"weight": "w0", "bias": "b0", "activation": "relu"},
                {"weight": "w1", "bias": "b1", "activation": "relu"},
                {"weight": "w2", "bias": "b2", "activation": "identity"}],
     "seed": 0,                            # optional: the training seed (a table label)
     "train_seeds": [0, 255]}              # optional: first and last seed trained on

Every agent runs the same network on its own input ``x``: the concatenation of
``inputs`` (``observation``: the agent's flat observation of the task's layout,
:class:`netsense.engine.model.ObsLayout`; ``agent_features``: its row of that array).
Layer ``l`` computes ``x <- act_l(x @ W_l + b_l)`` with ``W_l`` of shape ``(in, out)``
(the transpose of ``torch.nn.Linear.weight``; :func:`write_torch_mlp` transposes) and
``act_l`` one of :data:`ACTIVATIONS`. The last layer's ``sum(nvec)`` outputs are the
logits in the flat action-mask layout of the task (entry ``a`` owns the ``nvec[a]``
positions after those of the entries before it); the action of entry ``a`` is its
allowed choice with the largest logit (the first on a tie). ``train_seeds``, where given,
must not reach the protocol's evaluation seeds (checked).

:func:`write_mlp_policy` writes a file from arrays, :func:`write_torch_mlp` from a
``torch.nn.Sequential`` of ``Linear`` and activation layers, :func:`convert_policy` from a
``policy.pt`` of netsense's trainer; :func:`read_mlp_policy` reads and checks one.

Imports: numpy (torch only inside :func:`write_torch_mlp` and :func:`convert_policy`).
"""

from __future__ import annotations

import json
import os
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["ACTIVATIONS", "FORMAT", "FORMAT_VERSION", "INPUTS", "MlpPolicy",
           "convert_policy", "read_mlp_policy", "write_mlp_policy", "write_torch_mlp"]

FORMAT = "netsense-mlp-policy"
FORMAT_VERSION = 1
#: Hidden- and output-layer activations a file may name.
ACTIVATIONS = {
    "identity": lambda x: x,
    "relu": lambda x: np.maximum(x, 0),
    "tanh": np.tanh,
    "sigmoid": lambda x: 1.0 / (1.0 + np.exp(-x)),
}
#: Input features a file may name (``observation`` first, always).
INPUTS = ("observation", "agent_features")
_HEADER_KEYS = {"format", "format_version", "task", "control", "obs_dim", "nvec", "inputs",
                "layers", "seed", "train_seeds"}
#: Largest file read (a policy's MLP is far smaller; refuses a decompression bomb early).
MAX_BYTES = 1 << 28


@dataclass(frozen=True)
class MlpPolicy:
    """A checked policy file (:func:`read_mlp_policy`).

    Attributes
    ----------
    path : Path
    header : dict
        The parsed header.
    layers : tuple of (W, b, activation)
        ``W`` ``(in, out)``, ``b`` ``(out,)``, float32.
    agent_features : numpy.ndarray or None
        ``(N, F)`` per-agent inputs.
    """

    path: Path
    header: dict
    layers: tuple
    agent_features: np.ndarray | None

    @property
    def task(self) -> str:
        return self.header["task"]

    @property
    def control(self) -> str:
        return self.header["control"]

    @property
    def nvec(self) -> tuple[int, ...]:
        return tuple(self.header["nvec"])

    def logits(self, obs: np.ndarray) -> np.ndarray:
        """``(..., N, obs_dim) -> (..., N, sum(nvec))``."""
        x = np.asarray(obs, dtype=np.float32)
        if x.shape[-1] != self.header["obs_dim"]:
            raise ValueError(f"{self.path}: observations of size {x.shape[-1]}, the file's "
                             f"network reads {self.header['obs_dim']}")
        if self.agent_features is not None:
            if x.shape[-2] != self.agent_features.shape[0]:
                raise ValueError(f"{self.path}: {x.shape[-2]} agents, agent_features has "
                                 f"rows for {self.agent_features.shape[0]}")
            feat = np.broadcast_to(self.agent_features,
                                   x.shape[:-1] + self.agent_features.shape[-1:])
            x = np.concatenate([x, feat.astype(np.float32)], -1)
        for W, b, act in self.layers:
            x = ACTIVATIONS[act](x @ W + b)
        return x

    def act(self, obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """The greedy action ``(..., N, len(nvec))``: per entry, the allowed choice with
        the largest logit."""
        logits = self.logits(obs)
        m = np.asarray(mask).astype(bool)
        if m.shape != logits.shape:
            raise ValueError(f"{self.path}: action mask of shape {m.shape}, the network "
                             f"writes logits of shape {logits.shape}")
        out = np.empty(logits.shape[:-1] + (len(self.nvec),), dtype=np.int64)
        s = 0
        for a, k in enumerate(self.nvec):
            block = np.where(m[..., s:s + k], logits[..., s:s + k], -np.inf)
            out[..., a] = block.argmax(-1)
            s += k
        return out

    def check_core(self, core) -> None:
        """Refuse a core whose observation or action layout differs from the file's."""
        now = {"obs_dim": int(core.layout.size), "nvec": [int(v) for v in core.nvec]}
        diff = {k: (self.header[k], v) for k, v in now.items() if self.header[k] != v}
        if diff:
            raise ValueError(f"{self.path}: the network does not fit {self.task} in control "
                             f"mode {self.control!r}; (file, task): {diff}")
        if self.agent_features is not None and self.agent_features.shape[0] != core.N:
            raise ValueError(f"{self.path}: agent_features has {self.agent_features.shape[0]}"
                             f" rows, the task has {core.N} agents")


def _bad(path, text: str) -> ValueError:
    return ValueError(f"{path}: {text}")


def _header(raw, path) -> dict:
    if not (isinstance(raw, np.ndarray) and raw.shape == () and raw.dtype.kind == "U"):
        raise _bad(path, "'header' must be a 0-d unicode array holding JSON")
    try:
        h = json.loads(str(raw))
    except ValueError as exc:
        raise _bad(path, f"'header' is not JSON ({exc})") from None
    if not isinstance(h, dict):
        raise _bad(path, "'header' must be a JSON object")
    if h.get("format") != FORMAT or h.get("format_version") != FORMAT_VERSION:
        raise _bad(path, f"format {h.get('format')!r} version {h.get('format_version')!r}; "
                         f"this netsense reads {FORMAT!r} version {FORMAT_VERSION}")
    unknown = sorted(set(h) - _HEADER_KEYS)
    if unknown:
        raise _bad(path, f"header keys {unknown} unknown (known: {sorted(_HEADER_KEYS)})")
    for key in ("task", "control"):
        if not isinstance(h.get(key), str):
            raise _bad(path, f"header '{key}' must be a string")

    def is_int(v):
        return isinstance(v, int) and not isinstance(v, bool)

    if not is_int(h.get("obs_dim")) or h["obs_dim"] < 1:
        raise _bad(path, "header 'obs_dim' must be an integer >= 1")
    nvec = h.get("nvec")
    if not isinstance(nvec, list) or not nvec or not all(is_int(v) and v >= 1 for v in nvec):
        raise _bad(path, "header 'nvec' must be a non-empty list of integers >= 1")
    inputs = h.get("inputs", ["observation"])
    if (not isinstance(inputs, list) or not inputs or inputs[0] != "observation"
            or len(set(inputs)) != len(inputs) or not set(inputs) <= set(INPUTS)):
        raise _bad(path, f"header 'inputs' must list 'observation' first, then optionally "
                         f"'agent_features'; got {inputs!r}")
    h["inputs"] = inputs
    layers = h.get("layers")
    if not isinstance(layers, list) or not layers:
        raise _bad(path, "header 'layers' must be a non-empty list")
    for i, layer in enumerate(layers):
        if (not isinstance(layer, dict) or set(layer) != {"weight", "bias", "activation"}
                or not all(isinstance(v, str) for v in layer.values())):
            raise _bad(path, f"layers[{i}] must be an object of the strings 'weight', "
                             f"'bias' and 'activation', got {layer!r}")
        if layer["activation"] not in ACTIVATIONS:
            raise _bad(path, f"layers[{i}].activation {layer['activation']!r} is not one of "
                             f"{tuple(ACTIVATIONS)}")
    if "seed" in h and not is_int(h["seed"]):
        raise _bad(path, "header 'seed' must be an integer")
    ts = h.get("train_seeds")
    if ts is not None and not (isinstance(ts, list) and len(ts) == 2
                               and all(is_int(v) for v in ts) and 0 <= ts[0] <= ts[1]):
        raise _bad(path, "header 'train_seeds' must be [first, last], integers, first <= last")
    return h


def read_mlp_policy(path: str | Path) -> MlpPolicy:
    """Read and check a policy file (module docstring); nothing in it runs.

    Raises
    ------
    ValueError
        Naming the file and what is wrong: not an ``.npz``, arrays holding Python objects
        (refused, never unpickled), a header that is missing, not JSON or not of this
        format, arrays the header does not name or names but the file lacks, shapes that
        do not chain from ``obs_dim`` (plus the agent features) to ``sum(nvec)``,
        non-floating or non-finite weights, training seeds among the evaluation seeds.
    """
    path = Path(path)
    if not path.is_file():
        raise _bad(path, "no such policy file")
    if path.stat().st_size > MAX_BYTES:
        raise _bad(path, f"{path.stat().st_size} bytes; a policy file is at most {MAX_BYTES}")
    if not zipfile.is_zipfile(path):
        raise _bad(path, "not an .npz archive (a NumPy zip of arrays)")
    try:
        with zipfile.ZipFile(path) as z:
            size = sum(i.file_size for i in z.infolist())
        if size > MAX_BYTES:
            raise _bad(path, f"{size} bytes uncompressed; a policy file is at most "
                             f"{MAX_BYTES}")
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise _bad(path, f"refused: {exc} (netsense reads policy files with "
                         "numpy.load(allow_pickle=False): arrays of numbers only; nothing "
                         "in the file ran)") from None
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise _bad(path, f"not a readable .npz ({type(exc).__name__}: {exc})") from None
    if "header" not in arrays:
        raise _bad(path, "no 'header' array (the JSON description of the network)")
    h = _header(arrays.pop("header"), path)
    feats = arrays.pop("agent_features", None)
    if ("agent_features" in h["inputs"]) != (feats is not None):
        raise _bad(path, "'agent_features' must be present exactly when the header's "
                         "inputs name it")
    names = [n for layer in h["layers"] for n in (layer["weight"], layer["bias"])]
    if len(set(names)) != len(names):
        raise _bad(path, "layers name an array twice")
    missing = [n for n in names if n not in arrays]
    extra = sorted(set(arrays) - set(names))
    if missing or extra:
        raise _bad(path, (f"arrays {missing} named by the header are missing" if missing
                          else "") + ("; " if missing and extra else "")
                   + (f"arrays {extra} are not named by the header" if extra else ""))
    for name, a in list(arrays.items()) + ([("agent_features", feats)] if feats is not None
                                           else []):
        if a.dtype.kind != "f":
            raise _bad(path, f"array '{name}' has dtype {a.dtype}; weights are floating point")
        bad = int((~np.isfinite(a)).sum())
        if bad:
            raise _bad(path, f"array '{name}' holds {bad} non-finite entries")
    if feats is not None and feats.ndim != 2:
        raise _bad(path, f"'agent_features' must be (N, F), got shape {feats.shape}")
    width = h["obs_dim"] + (feats.shape[1] if feats is not None else 0)
    layers = []
    for i, layer in enumerate(h["layers"]):
        W, b = arrays[layer["weight"]], arrays[layer["bias"]]
        if W.ndim != 2 or W.shape[0] != width or b.shape != (W.shape[1],):
            raise _bad(path, f"layers[{i}]: weight {W.shape} and bias {b.shape} do not fit "
                             f"an input of width {width} (weight (in, out), bias (out,))")
        width = W.shape[1]
        layers.append((W.astype(np.float32), b.astype(np.float32), layer["activation"]))
    if width != sum(h["nvec"]):
        raise _bad(path, f"the last layer writes {width} logits; nvec {h['nvec']} needs "
                         f"{sum(h['nvec'])}")
    if h.get("train_seeds") is not None:
        from netsense.benchmark.protocol import EVAL_SEED0

        if h["train_seeds"][1] >= EVAL_SEED0:
            raise _bad(path, f"trained on seeds {h['train_seeds']}, which reach the "
                             f"evaluation seeds (from {EVAL_SEED0}); train below them")
    return MlpPolicy(path, h, tuple(layers),
                     None if feats is None else feats.astype(np.float32))


def write_mlp_policy(path: str | Path, layers: Sequence[tuple], *, task: str, control: str,
                     obs_dim: int, nvec: Sequence[int], agent_features=None,
                     seed: int | None = None,
                     train_seeds: tuple[int, int] | None = None) -> Path:
    """Write a policy file from arrays.

    Parameters
    ----------
    path : path
        The ``.npz`` to write (the suffix is added when missing).
    layers : sequence of (W, b, activation)
        ``W`` ``(in, out)``, ``b`` ``(out,)``; ``activation`` one of :data:`ACTIVATIONS`
        (``"identity"`` for the output layer).
    task, control : str
        The scenario id and its communication-only control mode.
    obs_dim : int
        The observation size of the task's layout.
    nvec : sequence of int
        Choices per action entry (the flat action mask's layout).
    agent_features : (N, F) array, optional
        Per-agent inputs appended to the observations.
    seed : int, optional
        The training seed (the suite's tables label runs by it).
    train_seeds : (first, last), optional
        The seeds the policy was trained on.

    Returns
    -------
    Path
        The file written; it is read back and checked (:func:`read_mlp_policy`) before this
        returns, so a file that would be refused is never left behind.
    """
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    header = {"format": FORMAT, "format_version": FORMAT_VERSION, "task": str(task),
              "control": str(control), "obs_dim": int(obs_dim),
              "nvec": [int(v) for v in nvec],
              "inputs": ["observation"] + (["agent_features"] if agent_features is not None
                                           else []), "layers": []}
    if seed is not None:
        header["seed"] = int(seed)
    if train_seeds is not None:
        header["train_seeds"] = [int(train_seeds[0]), int(train_seeds[1])]
    arrays = {}
    for i, layer in enumerate(layers):
        if len(layer) != 3:
            raise ValueError(f"layers[{i}] must be (W, b, activation), got {len(layer)} items")
        W, b, act = layer
        if act not in ACTIVATIONS:
            raise ValueError(f"layers[{i}]: activation {act!r} is not one of "
                             f"{tuple(ACTIVATIONS)}")
        arrays[f"w{i}"] = np.asarray(W, dtype=np.float32)
        arrays[f"b{i}"] = np.asarray(b, dtype=np.float32)
        header["layers"].append({"weight": f"w{i}", "bias": f"b{i}", "activation": act})
    if agent_features is not None:
        arrays["agent_features"] = np.asarray(agent_features, dtype=np.float32)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part.npz")
    np.savez(tmp, header=np.array(json.dumps(header)), **arrays)
    try:
        read_mlp_policy(tmp)
    except ValueError as exc:
        tmp.unlink()
        raise ValueError(str(exc).replace(str(tmp), str(path))) from None
    os.replace(tmp, path)
    return path


#: torch activation layers :func:`write_torch_mlp` understands.
_TORCH_ACTIVATIONS = {"ReLU": "relu", "Tanh": "tanh", "Sigmoid": "sigmoid",
                      "Identity": "identity"}


def write_torch_mlp(path: str | Path, net, *, task: str, control: str | None = None,
                    agent_features=None, seed: int | None = None,
                    train_seeds: tuple[int, int] | None = None) -> Path:
    """Write a policy file from a torch MLP: ``net`` a ``torch.nn.Sequential`` (nested
    ones are flattened) of ``Linear`` layers, each optionally followed by one of ``ReLU``,
    ``Tanh``, ``Sigmoid`` or ``Identity``; ``Dropout`` layers are skipped (acting is
    evaluation). ``task``'s layout gives ``obs_dim`` and ``nvec`` (in ``control``, default
    the mode the suite scores the task in) and is checked against the network.

    Raises
    ------
    ValueError
        A layer of another kind, two activations in a row, or a network whose input or
        output size does not fit the task.
    """
    from torch import nn

    from netsense.benchmark.protocol import frontier_overrides
    from netsense.engine.core import BatchedCore
    from netsense.env.vector import load_model

    over = frontier_overrides(task)
    if control is not None:
        over = {**over, "control": {**over.get("control", {}), "mode": control}}
    model, _ = load_model(task, **over)
    core = BatchedCore(model, 1)
    mode = core.control.mode
    layers: list[list] = []
    for i, m in enumerate(mod for mod in net.modules()
                          if not isinstance(mod, nn.Sequential)):
        kind = type(m).__name__
        if isinstance(m, nn.Linear):
            W = m.weight.detach().cpu().numpy().T
            b = (m.bias.detach().cpu().numpy() if m.bias is not None
                 else np.zeros(W.shape[1], np.float32))
            layers.append([W, b, "identity"])
        elif kind in _TORCH_ACTIVATIONS:
            if not layers or layers[-1][2] != "identity":
                raise ValueError(f"module {i} ({kind}): an activation must follow a Linear "
                                 "layer, one per layer")
            layers[-1][2] = _TORCH_ACTIVATIONS[kind]
        elif isinstance(m, nn.Dropout):
            continue
        else:
            raise ValueError(f"module {i} is a {kind}; write_torch_mlp takes Linear layers "
                             f"and the activations {tuple(_TORCH_ACTIVATIONS)} (write other "
                             "networks with write_mlp_policy from their arrays)")
    if not layers:
        raise ValueError("net holds no Linear layer")
    extra = 0 if agent_features is None else np.asarray(agent_features).shape[-1]
    if layers[0][0].shape[0] != core.layout.size + extra:
        raise ValueError(f"the network reads {layers[0][0].shape[0]} inputs; {task} in mode "
                         f"{mode!r} has observations of {core.layout.size}"
                         + (f" plus {extra} agent features" if extra else ""))
    return write_mlp_policy(path, [tuple(x) for x in layers], task=task, control=mode,
                            obs_dim=core.layout.size, nvec=core.nvec,
                            agent_features=agent_features, seed=seed,
                            train_seeds=train_seeds)


def convert_policy(src: str | Path, out: str | Path) -> Path:
    """A ``policy.pt`` of netsense's trainer (an MLP actor, optionally with the own-substate
    one-hot; no memory, clock, observation normaliser or news gate) as a policy file.

    Raises
    ------
    ValueError
        A file :func:`netsense.rl.checkpoint.read_policy` refuses, or an actor with parts
        the format does not express.
    """
    from netsense.rl.checkpoint import policy_config, policy_control, read_policy
    from netsense.rl.config import training_seeds

    state = read_policy(src)
    cfg = policy_config(state, src)
    unsupported = [k for k, on in (("network != 'mlp'", cfg.network != "mlp"),
                                   ("memory", cfg.memory), ("clock", cfg.clock),
                                   ("obs_norm", cfg.obs_norm),
                                   ("news_gate", getattr(cfg, "news_gate", False))) if on]
    if unsupported:
        raise ValueError(f"{src}: the actor has {unsupported}, which a {FORMAT} file does "
                         "not express")
    actor = {k: v.numpy() for k, v in state["actor"].items()}
    prefix = "body.params." if "onehot" in actor else "params."
    idx = sorted({int(k[len(prefix):].split(".")[0]) for k in actor if k.startswith(prefix)})
    layers = [(actor[f"{prefix}{i}.weight"].T, actor[f"{prefix}{i}.bias"],
               cfg.activation if j < len(idx) - 1 else "identity")
              for j, i in enumerate(idx)]
    trained = state["trained_on"]
    ctl = policy_control(state)
    mode = ctl.get("mode") if isinstance(ctl, dict) else ctl
    seeds = training_seeds(cfg)
    return write_mlp_policy(out, layers, task=cfg.scenario, control=mode,
                            obs_dim=trained["obs_dim"], nvec=trained["nvec"],
                            agent_features=actor.get("onehot"), seed=cfg.seed,
                            train_seeds=(min(seeds), max(seeds)) if seeds else None)
