"""Policy files are data: the safe reading, checksums and weight checks shared by both kinds
of policy file (the batched trainer's ``.pt``, :mod:`netsense.rl.checkpoint`; the SB3
``policy.zip``, :mod:`netsense.rl.sb3_policy`).

* :func:`load_tensors` reads a ``torch.save`` file with ``torch.load(weights_only=True)``:
  torch's restricted unpickler rebuilds tensors and plain containers only, so a file that
  holds any other object (one whose ``__reduce__`` would run code) is refused, never
  called.
* :func:`content_checksum` is the ``sha256`` of a file's metadata (canonical JSON) and
  tensors (name, dtype, shape and bytes of each, in name order); loading recomputes it.
* :func:`check_weights` refuses non-floating or non-finite weights.

Imports: torch, numpy (no other stage).
"""

from __future__ import annotations

import hashlib
import io
import json
import pickle
import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch

__all__ = ["check_weights", "content_checksum", "load_tensors", "plain"]


def plain(v):
    """Metadata as JSON-able Python values (numpy scalars and arrays converted, tuples
    as lists)."""
    if isinstance(v, dict):
        return {str(k): plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return plain(v.tolist())
    if isinstance(v, np.generic):
        return v.item()
    return v


def content_checksum(meta: dict, tensors: Mapping[str, Mapping]) -> str:
    """``sha256`` (hex) of a policy file's content.

    The canonical JSON of ``meta`` (keys sorted, no spaces, no NaN) followed by, for each
    group of ``tensors`` and each tensor in name order, ``"<group>/<name>:<dtype>:<shape>;"``
    and the tensor's bytes. Raises ``ValueError`` when ``meta`` is not JSON-able or a
    group is not a dict of tensors.
    """
    try:
        text = json.dumps(meta, sort_keys=True, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"metadata is not plain JSON data ({exc})") from None
    h = hashlib.sha256(text.encode())
    for group in sorted(tensors):
        entries = tensors[group]
        if not isinstance(entries, Mapping):
            raise ValueError(f"'{group}' must be a dict of tensors, got "
                             f"{type(entries).__name__}")
        for key in sorted(entries, key=str):
            t = entries[key]
            if not isinstance(key, str) or not isinstance(t, torch.Tensor):
                raise ValueError(f"'{group}' must map names to tensors; entry {key!r} is "
                                 f"{type(t).__name__}")
            h.update(f"{group}/{key}:{t.dtype}:{list(t.shape)};".encode())
            h.update(t.detach().cpu().contiguous().reshape(-1).view(torch.uint8)
                     .numpy().tobytes())
    return h.hexdigest()


def check_weights(tensors: Mapping, where: str) -> None:
    """Every tensor floating point and finite; else ``ValueError`` naming ``where``, the
    tensor and how many of its entries are NaN or infinite."""
    for key, t in tensors.items():
        if not t.is_floating_point():
            raise ValueError(f"{where}: weight '{key}' has dtype {t.dtype}; a policy's "
                             "weights are floating point")
        bad = int((~torch.isfinite(t)).sum())
        if bad:
            raise ValueError(f"{where}: weight '{key}' holds {bad} of {t.numel()} entries "
                             "that are NaN or infinite; a policy with non-finite weights "
                             "is refused (its actions would be meaningless)")


def load_tensors(source: str | Path | bytes, where: str):
    """``torch.load(weights_only=True)`` of a file (or its bytes); errors name ``where``.

    Raises
    ------
    ValueError
        ``refused`` when the file holds objects other than tensors and plain data (the
        global it references is named; nothing of it ran), ``not readable`` for any other
        failure (truncated, corrupted, not a torch file).
    """
    f = io.BytesIO(source) if isinstance(source, bytes) else source
    try:
        return torch.load(f, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        text = str(exc)
        found = re.search(r"Unsupported global: GLOBAL (\S+)", text)
        if found is None and ("WeightsUnpickler error" not in text
                              or "Unsupported operand" in text):  # bytes that are no pickle
            raise ValueError(f"{where}: not a readable policy file (truncated or "
                             f"corrupted?): {_short(exc)}") from None
        hint = f" (it references {found.group(1)})" if found else ""
        raise ValueError(f"{where}: refused: the file holds Python objects other than "
                         f"tensors and plain data{hint}; loading them could run code, so "
                         "netsense reads policy files with torch.load(weights_only=True) "
                         "only and ran none of it. Retrain, or convert a file you trust "
                         "(docs/rl.md, 'Policy files are data')") from None
    except Exception as exc:  # noqa: BLE001 - any other failure to load is a bad file
        raise ValueError(f"{where}: not a readable policy file (truncated or corrupted?): "
                         f"{_short(exc)}") from None


def _short(exc: BaseException) -> str:
    """The gist of a load error (torch's restricted unpickler wraps its reason in advice
    about ``weights_only=False``, which netsense never takes)."""
    text = " ".join(str(exc).split())
    if "WeightsUnpickler error:" in text:
        text = text.split("WeightsUnpickler error:", 1)[1].split(" Check the documentation")[0]
    return f"{type(exc).__name__}: {text.strip()[:200]}"
