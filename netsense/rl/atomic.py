"""Files that appear whole or not at all.

Every file a training run or a benchmark writes (policies, checkpoints, CSV and JSON
files, figures) goes through :func:`atomic_path`: the content is written to a temporary
file in the destination's folder, flushed to disk, and renamed over the destination with
``os.replace`` (atomic on POSIX and Windows within one file system). A process killed
mid-write leaves the old file (or none) and at most a stray ``.*.part`` file, never half
a file under the real name.

Imports: the standard library only.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "save_figure", "write_atomic", "write_json"]


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to; renamed over ``path`` when the block
    ends without an error, removed when it raises.

    Parameters
    ----------
    path : path
        The destination. Its folder must exist.

    Yields
    ------
    Path
        The temporary file (``.<name>.<random>.part`` in the same folder), created empty;
        write it by name (``torch.save``, ``savefig``, ``open``).
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:  # on disk before the rename makes it visible
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes it 0600; a plain open would not
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_atomic(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` (text as UTF-8, or bytes) to ``path`` whole or not at all
    (:func:`atomic_path`); returns ``path``."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


def write_json(path: str | Path, obj, **kwargs) -> Path:
    """``obj`` as indented JSON with a final newline, written atomically
    (:func:`write_atomic`); ``kwargs`` go to :func:`json.dumps` (e.g. ``default=list``)."""
    return write_atomic(path, json.dumps(obj, indent=2, **kwargs) + "\n")


def save_figure(fig, path: str | Path, dpi: int = 110) -> Path:
    """Save a matplotlib figure to ``path`` through :func:`atomic_path`, in the format of
    the path's suffix (PNG without one: the temporary name ends in ``.part``, so the format
    is given, not guessed), and return the path. The figure is left open."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=path.suffix[1:] or "png")
    return path
