"""The package's cache folder and its atomically written ``.npy`` files.

An entry is whole or absent: written beside its path and renamed over it, so jobs
sharing the folder never read one half-written; one damaged another way (a
truncated copy, a full disk) is recomputed with a warning.

``$RHYTHMIC_JAX_CACHE`` (default ``~/.cache/rhythmic_jax``) holds descriptor
files (:func:`rhythmic_jax.frames.features.cached_describe`,
:func:`rhythmic_jax.frames.pipeline.describe_files`) and the compiled networks
(:mod:`rhythmic_jax.frames.compiled`).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.atomic import save_npy
from rhythmic_jax.io.reader import load_npy, npy_header

__all__ = [
    "cache_key_check",
    "cache_unusable",
    "default_cache_dir",
    "load_cached",
    "save_cached",
]

log = logging.getLogger(__name__)
_WARNED: set[str] = set()  # what this process has warned about already


def default_cache_dir() -> Path:
    """``$RHYTHMIC_JAX_CACHE``, else ``~/.cache/rhythmic_jax``."""
    env = os.environ.get("RHYTHMIC_JAX_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "rhythmic_jax"


def cache_key_check(key: str) -> None:
    """Refuse a cache key that is not a plain, non-empty file-name part."""
    if not key or any(c in key for c in "/\\") or key.startswith("."):
        raise InputError(f"cache key {key!r}: use a plain, non-empty file-name part")


def load_cached(path: Path, shape: tuple[int, int | None]) -> np.ndarray | None:
    """The float32 array of ``shape`` in the cache file ``path``, else None
    (missing, unreadable or mis-shaped: the caller recomputes it). A width of
    None takes any 2-d array of those rows: where the file's name already
    digests the descriptor and its settings, which fix the width, so a hit needs
    no network built (nor torch imported) to know it."""
    try:
        if not path.is_file():
            return None
        head = npy_header(path)
        rows, width = shape
        if (
            len(head.shape) == 2 and head.dtype == np.float32 and head.shape[0] == rows
            and (width is None or head.shape[1] == width)
        ):
            return load_npy(path)
    except InputError as err:
        log.warning("recomputing unreadable cache file %s (%s)", path, err)
    return None


def save_cached(path: Path, x: np.ndarray) -> None:
    """Write ``x`` to the cache file ``path`` atomically
    (:func:`rhythmic_jax.io.atomic.save_npy`: a hidden temporary file in the same
    folder, flushed, then ``os.replace``). Jobs sharing the cache may write one
    entry at once: each replace puts a whole file in place, and a reader holds
    the whole file it opened. A writer killed mid-write leaves its hidden
    temporary file, never a partial entry.

    A cache is only a cache: one that cannot be written (a full or read-only
    disk, ``$RHYTHMIC_JAX_CACHE`` naming a file) warns once
    (:func:`cache_unusable`) and the job goes on without it."""
    try:
        save_npy(path, np.asarray(x))
    except OSError as err:
        cache_unusable(path.parent, "writing", err)


def cache_unusable(folder: Path, doing: str, err: OSError) -> None:
    """Warn, once per folder and process, that the cache ``folder`` failed
    (``doing``: "reading", "writing", ...) and the job goes on without it."""
    if str(folder) in _WARNED:
        return
    _WARNED.add(str(folder))
    reason = err.strerror or str(err) or type(err).__name__
    log.warning(
        "cache %s: %s failed (%s); going on without the cache (set "
        "RHYTHMIC_JAX_CACHE to a writable folder to keep results)",
        folder,
        doing,
        reason.lower(),
    )
