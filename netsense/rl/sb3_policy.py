"""MaskablePPO policy files, read as data: ``LearnedPolicy`` and the ``policy.zip`` format.

Stable-Baselines3 stores a model as a zip: ``policy.pth`` (the weights, a ``torch.save``
of tensors) and ``data`` (settings, several of them *cloudpickled*: unpickling them runs
whatever code the file's author put there). netsense never unpickles ``data``. A
``policy.zip`` written by :func:`netsense.rl.sb3.train` carries one more member,
``netsense.json``: what is needed to rebuild the policy network (observation size, action
layout, layer widths, activation) and the ``sha256`` of that metadata and the weights
(:func:`netsense.rl.policy_files.content_checksum`). :class:`LearnedPolicy` reads only
those two members (``policy.pth`` with ``torch.load(weights_only=True)``), verifies the
checksum and the weights, and builds ``sb3_contrib``'s ``MaskableActorCriticPolicy``
itself. The zip stays a valid SB3 file (``MaskablePPO.load`` still reads it, for those
who trust it).

A zip without ``netsense.json`` (a policy of another tool, or one written before netsense
added it) is refused, saying why; :func:`convert_sb3_policy` (``netsense policy convert
PATH --trust``) converts a file the user trusts: it is the one place that unpickles, and
only when asked to.

Imports: numpy, torch (lazily SB3 / sb3-contrib) and :mod:`netsense.rl.policy_files`.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from netsense.rl.atomic import atomic_path
from netsense.rl.policy_files import check_weights, content_checksum, load_tensors, plain
from netsense.rl.run_folder import check_finished

__all__ = ["FORMAT", "FORMAT_VERSION", "META_MEMBER", "LearnedPolicy", "convert_sb3_policy",
           "read_sb3_policy", "sb3_metadata", "write_sb3_metadata"]

#: ``format`` of ``netsense.json`` and the newest version read.
FORMAT = "netsense-sb3-policy"
FORMAT_VERSION = 1
#: The zip member holding netsense's metadata.
META_MEMBER = "netsense.json"
#: Activations a policy may use (the names stored in the metadata).
ACTIVATIONS = ("tanh", "relu")


def _convert_hint(path) -> str:
    return (f"if you trust the file, convert it once with `netsense policy convert {path} "
            "--trust --out NEW.zip` (this unpickles it, once)")


def _activation(name: str):
    from torch import nn

    return {"tanh": nn.Tanh, "relu": nn.ReLU}[name]


def sb3_metadata(model, **extra) -> dict:
    """``netsense.json`` of a live MaskablePPO ``model`` (without the checksum).

    ``extra``: what the training run adds (``scenario``, ``overrides``, ``seed``,
    ``num_vec_envs``). Raises ``ValueError`` for a policy netsense cannot rebuild (another
    policy class, features extractor or activation, or spaces other than a flat ``Box``
    and ``MultiDiscrete``).
    """
    from gymnasium import spaces
    from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
    from stable_baselines3.common.torch_layers import FlattenExtractor
    from torch import nn

    pol = model.policy
    obs, act = model.observation_space, model.action_space
    if type(pol) is not MaskableActorCriticPolicy:
        raise ValueError(f"a {type(pol).__name__} policy; netsense rebuilds "
                         "MaskableActorCriticPolicy ('MlpPolicy') only")
    if not (isinstance(obs, spaces.Box) and len(obs.shape) == 1
            and isinstance(act, spaces.MultiDiscrete) and np.ndim(act.nvec) == 1):
        raise ValueError(f"a policy for {obs} -> {act}, not a netsense policy (flat Box "
                         "observations, MultiDiscrete actions)")
    if pol.features_extractor_class is not FlattenExtractor:
        raise ValueError(f"features extractor {pol.features_extractor_class.__name__}; "
                         "netsense rebuilds FlattenExtractor only")
    names = {nn.Tanh: "tanh", nn.ReLU: "relu"}
    if pol.activation_fn not in names:
        raise ValueError(f"activation {pol.activation_fn.__name__}; netsense rebuilds "
                         f"{', '.join(ACTIVATIONS)}")
    return plain({"format": FORMAT, "format_version": FORMAT_VERSION,
                  "algo": "maskable_ppo", "policy": "MaskableActorCriticPolicy",
                  "observation_dim": int(obs.shape[0]),
                  "nvec": [int(v) for v in act.nvec], "net_arch": pol.net_arch,
                  "activation": names[pol.activation_fn],
                  "share_features_extractor": bool(pol.share_features_extractor),
                  **extra})


def write_sb3_metadata(src: str | Path, meta: dict, dst: str | Path | None = None) -> Path:
    """Copy the SB3 zip ``src`` to ``dst`` (default: over ``src``) with ``meta`` and its
    checksum as :data:`META_MEMBER` (an older one replaced). The weights are read back
    from the zip (``weights_only=True``) for the checksum, so it covers what was saved."""
    src = Path(src)
    dst = src if dst is None else Path(dst)
    with zipfile.ZipFile(src) as zin:
        weights = load_tensors(zin.read("policy.pth"), f"{src} (policy.pth)")
        meta = {k: v for k, v in plain(meta).items() if k != "sha256"}
        meta["sha256"] = content_checksum(meta, {"policy": weights})
        with atomic_path(dst) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zout:
            for info in zin.infolist():
                if info.filename != META_MEMBER:
                    zout.writestr(info, zin.read(info.filename))
            zout.writestr(META_MEMBER, json.dumps(meta, indent=1, sort_keys=True) + "\n")
    return dst


def _check_meta(meta, where: str) -> None:
    """Types and values of ``netsense.json``; errors name the file and the key."""
    if not isinstance(meta, dict):
        raise ValueError(f"{where}: {META_MEMBER} must hold a JSON object")
    if meta.get("format") != FORMAT or meta.get("format_version") not in range(
            1, FORMAT_VERSION + 1):
        raise ValueError(f"{where}: {META_MEMBER} is format {meta.get('format')!r} version "
                         f"{meta.get('format_version')!r}; this netsense reads {FORMAT!r} "
                         f"versions 1..{FORMAT_VERSION}")

    def ints(v, lo):
        return isinstance(v, list) and all(
            isinstance(x, int) and not isinstance(x, bool) and x >= lo for x in v)

    d = meta.get("observation_dim")
    if not (isinstance(d, int) and not isinstance(d, bool) and d >= 1):
        raise ValueError(f"{where}: {META_MEMBER} 'observation_dim' must be an integer >= 1, "
                         f"got {d!r}")
    if not (ints(meta.get("nvec"), 1) and meta["nvec"]):
        raise ValueError(f"{where}: {META_MEMBER} 'nvec' must be a non-empty list of "
                         f"integers >= 1, got {meta.get('nvec')!r}")
    arch = meta.get("net_arch")
    ok = ints(arch, 1) or (isinstance(arch, dict) and set(arch) <= {"pi", "vf"}
                           and all(ints(v, 1) for v in arch.values()))
    if not ok:
        raise ValueError(f"{where}: {META_MEMBER} 'net_arch' must be a list of layer widths "
                         f"or a dict with lists 'pi' and 'vf', got {arch!r}")
    if meta.get("activation") not in ACTIVATIONS:
        raise ValueError(f"{where}: {META_MEMBER} 'activation' must be one of "
                         f"{list(ACTIVATIONS)}, got {meta.get('activation')!r}")
    if not isinstance(meta.get("share_features_extractor"), bool):
        raise ValueError(f"{where}: {META_MEMBER} 'share_features_extractor' must be true "
                         "or false")
    if not isinstance(meta.get("sha256"), str):
        raise ValueError(f"{where}: {META_MEMBER} carries no checksum ('sha256')")


def read_sb3_policy(path: str | Path) -> tuple[dict, dict]:
    """``(metadata, weights)`` of a netsense ``policy.zip``, checked, nothing unpickled.

    Reads :data:`META_MEMBER` (JSON) and ``policy.pth`` (``weights_only=True``) and
    verifies the checksum and that the weights are finite.

    Raises
    ------
    ValueError
        Naming the file and what is wrong: missing, a directory, not a zip, truncated or
        corrupted, without netsense's metadata (a file of another tool: refused, with
        how to convert a trusted one), a checksum that does not match (changed after it
        was written), non-finite weights.
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"no learned policy at {path} (train one with `netsense train`)")
    check_finished(path.parent)  # a killed run's folder holds no final policy
    if not path.is_file():
        raise ValueError(f"{path}: not a policy file (a directory?)")
    bad = f"{path}: not a readable MaskablePPO policy file (truncated or corrupted?)"
    try:
        with zipfile.ZipFile(path) as z:
            names = set(z.namelist())
            if "policy.pth" not in names:
                raise ValueError(f"{bad}: no policy.pth member")
            if META_MEMBER not in names:
                raise ValueError(
                    f"{path}: refused: a Stable-Baselines3 zip without netsense's metadata "
                    f"({META_MEMBER}: written by another tool, or by netsense before it "
                    "stored one). SB3 keeps its settings as cloudpickle, which runs code "
                    f"when loaded, so netsense does not load it; {_convert_hint(path)}")
            raw_meta = z.read(META_MEMBER)
            raw_weights = z.read("policy.pth")
    except ValueError:
        raise
    except Exception as exc:  # noqa: BLE001 - BadZipFile, CRC errors, truncation
        raise ValueError(f"{bad}: {type(exc).__name__}: "
                         f"{' '.join(str(exc).split())[:200]}") from None
    try:
        meta = json.loads(raw_meta)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{bad}: {META_MEMBER} is not valid JSON ({exc})") from None
    _check_meta(meta, str(path))
    weights = load_tensors(raw_weights, f"{path} (policy.pth)")
    if not isinstance(weights, dict) or not all(
            isinstance(k, str) for k in weights):
        raise ValueError(f"{bad}: policy.pth is not a dict of named tensors")
    try:
        digest = content_checksum({k: v for k, v in meta.items() if k != "sha256"},
                                  {"policy": weights})
    except ValueError as exc:
        raise ValueError(f"{bad}: {exc}") from None
    if digest != meta["sha256"]:
        raise ValueError(f"{path}: checksum mismatch: the weights or {META_MEMBER} changed "
                         "after the file was written (corrupted, or edited); stored "
                         f"{meta['sha256'][:16]}..., content {digest[:16]}...")
    check_weights(weights, f"{path} (policy.pth)")
    return meta, weights


def convert_sb3_policy(src: str | Path, dst: str | Path, *, trust: bool = False,
                       **extra) -> Path:
    """Write a copy of the SB3 MaskablePPO zip ``src`` that netsense reads as data.

    **Unpickles ``src``** (``MaskablePPO.load``): whatever code the file holds runs, so
    ``trust=True`` must say that you trust it. Checks that netsense can rebuild the policy
    (:func:`sb3_metadata`) and that the rebuilt network reproduces the loaded one's
    weights, then writes ``dst`` with :data:`META_MEMBER`. ``extra`` (``scenario``,
    ``seed``, ``num_vec_envs``, ``overrides``) defaults to what ``train_config.json``
    beside ``src`` says (read as JSON), when there is one.
    """
    if trust is not True:
        raise ValueError(f"{src}: converting an SB3 zip unpickles it, which runs any code it "
                         "holds; pass trust=True (`--trust`) only for a file you trust")
    from sb3_contrib import MaskablePPO

    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise ValueError(f"no policy file at {src}")
    try:
        model = MaskablePPO.load(src, device="cpu")
    except Exception as exc:  # noqa: BLE001 - any failure to load is a bad file
        raise ValueError(f"{src}: not a readable MaskablePPO policy file: "
                         f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}"
                         ) from None
    cfg = src.parent / "train_config.json"
    if cfg.is_file():
        try:
            known = json.loads(cfg.read_text())
        except (OSError, ValueError):
            known = {}
        for k in ("scenario", "seed", "num_vec_envs", "overrides"):
            if k in known:
                extra.setdefault(k, known[k])
    try:
        meta = sb3_metadata(model, **extra)
    except ValueError as exc:
        raise ValueError(f"{src}: cannot convert: {exc}") from None
    write_sb3_metadata(src, meta, dst)  # whole or not at all
    LearnedPolicy(dst)  # the converted file reads back
    return dst


def _build(meta: dict):
    """``MaskableActorCriticPolicy`` of the metadata, on the CPU, with fresh weights."""
    from gymnasium import spaces
    from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy

    obs = spaces.Box(-np.inf, np.inf, (meta["observation_dim"],), np.float32)
    act = spaces.MultiDiscrete(meta["nvec"])
    return MaskableActorCriticPolicy(obs, act, lambda _: 0.0, net_arch=meta["net_arch"],
                                     activation_fn=_activation(meta["activation"]),
                                     share_features_extractor=meta["share_features_extractor"])


class LearnedPolicy:
    """A saved MaskablePPO policy acting for every agent of a netsense env.

    Parameters
    ----------
    path : path
        ``policy.zip`` written by :func:`netsense.rl.sb3.train` (or converted by
        :func:`convert_sb3_policy`). Read as data: nothing in it is unpickled.
    deterministic : bool
        Take the most likely allowed action (default) or sample.

    Attributes
    ----------
    policy : MaskableActorCriticPolicy
        The rebuilt network; ``model`` is the same object (``predict(obs,
        action_masks=..., deterministic=...)``, ``observation_space``,
        ``action_space``, as a ``MaskablePPO`` model has them).
    meta : dict
        The file's ``netsense.json``.

    Raises
    ------
    ValueError
        If ``path`` does not exist, is not a file, is not a readable netsense policy
        (truncated, corrupted, another kind of file, a checksum that does not match,
        non-finite weights, weights that do not fit the stored layout) or an SB3 zip
        without netsense's metadata (refused; :func:`convert_sb3_policy`); :meth:`act`
        raises it when the policy was trained for other observation or action spaces
        (another scenario).
    """

    def __init__(self, path: str | Path, *, deterministic: bool = True) -> None:
        import torch

        torch.set_num_threads(1)  # inference on small MLPs; leave cores to other workers
        path = Path(path)
        meta, weights = read_sb3_policy(path)
        policy = _build(meta)
        want = policy.state_dict()
        missing = sorted(set(want) - set(weights))
        extra = sorted(set(weights) - set(want))
        shapes = [f"'{k}' {tuple(weights[k].shape)} in the file, {tuple(want[k].shape)} "
                  "needed" for k in want if k in weights
                  and weights[k].shape != want[k].shape]
        if missing or extra or shapes:
            parts = ([f"missing {missing[:4]}"] if missing else []) + (
                [f"unexpected {extra[:4]}"] if extra else []) + shapes[:4]
            raise ValueError(f"{path}: the weights do not fit the policy its metadata "
                             f"describes (observation_dim {meta['observation_dim']}, nvec "
                             f"{meta['nvec']}, net_arch {meta['net_arch']}): "
                             + "; ".join(parts))
        policy.load_state_dict(weights)
        policy.set_training_mode(False)
        self.policy = self.model = policy
        self.meta = meta
        self.path = path
        self.deterministic = deterministic

    def act(self, flat_obs: dict[str, np.ndarray], wrapper) -> dict:
        """Actions for every agent in ``flat_obs`` (observations of ``wrapper``, a
        :class:`netsense.rl.wrappers.MaskedFlatObs`)."""
        self.check_env(wrapper)
        agents = list(flat_obs)
        stacked = np.stack([flat_obs[a] for a in agents])
        _, masks = wrapper.split(stacked)
        acts, _ = self.policy.predict(stacked, action_masks=masks,
                                      deterministic=self.deterministic)
        return {a: np.asarray(acts[i]) for i, a in enumerate(agents)}

    def check_env(self, wrapper) -> None:
        """Raise ``ValueError`` unless the policy's spaces are ``wrapper``'s (the policy was
        trained on this scenario's observation and action layout)."""
        want_obs = self.policy.observation_space.shape
        want_nvec = np.asarray(self.policy.action_space.nvec).tolist()
        got_obs = wrapper.observation_space(wrapper.possible_agents[0]).shape
        got_nvec = np.asarray(wrapper.nvec).tolist()
        if tuple(got_obs) != tuple(want_obs) or got_nvec != want_nvec:
            raise ValueError(f"the policy {self.path} was trained for observations of shape "
                             f"{tuple(want_obs)} and actions MultiDiscrete({want_nvec}); "
                             f"this environment has {tuple(got_obs)} and "
                             f"MultiDiscrete({got_nvec}) (a policy of another scenario or "
                             "overrides?)")
