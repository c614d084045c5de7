"""The one atomic writer: a file appears whole at its path, or not at all.

Everything the package writes to a single file (descriptor files, the descriptor
cache, figures, predictions, reports) goes through :func:`atomic_path`: the
content is written to a hidden temporary file in the target's folder, flushed to
disk, given the permissions a plain ``open`` would give, and renamed over the
target (``os.replace``, atomic on POSIX). Anything raised on the way, Ctrl-C
included, removes the temporary file and leaves the previous content in place;
once the job is cancelled (:func:`rhythmic_jax.io.outputs.cancel`) nothing is
renamed into place.
Map folders use the same rename at folder level (:mod:`rhythmic_jax.io.checkpoint`).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from rhythmic_jax.io.outputs import committing

__all__ = ["atomic_path", "save_npy", "write_file"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on a clean exit it becomes ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes the file owner-only
        with committing():
            os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def save_npy(path: str | os.PathLike, x: np.ndarray) -> None:
    """Write ``x`` to ``path`` as ``.npy`` (no pickles), atomically."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.save(fh, np.asarray(x), allow_pickle=False)


def write_file(path: str | os.PathLike, data: str | bytes) -> None:
    """Write ``data`` (text is UTF-8 encoded) to ``path``, atomically."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(data.encode() if isinstance(data, str) else data)
