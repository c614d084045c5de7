"""JAX's persistent compilation cache under the package's cache folder.

A fresh process compiles every XLA program it runs, and compiling is a large
part of a first fit's time (measured per job: ``reports/compile.md``).
:func:`enable_compile_cache` turns on JAX's own persistent cache
(``jax_compilation_cache_dir``) in ``<cache folder>/jax`` (``$RHYTHMIC_JAX_CACHE``,
see :func:`rhythmic_jax.frames.cache_files.default_cache_dir`), so the next process
loads each program instead of compiling it.

Thresholds: every program is cached (JAX's minimum compile time and minimum
entry size both set to zero). Measured on a default fit and its predictions, no
program compiled faster than it loaded from the cache, while JAX's default of
caching only programs that compile in a second or more left most of the
compile time uncached, since most programs are small; the entries are small
too (kilobytes, under a megabyte for the fit).

Damaged and foreign entries. JAX writes an entry in place (a killed process
leaves it cut short, a concurrent one may read it half-written), never replaces
one, and trusts any entry that decompresses and deserialises: an entry of
another program under this key was run, and failed, in place of the fit's own
(measured: the fit ended in a ValueError from the wrong program's shapes). So
this module gives JAX its own file cache, :class:`CheckedCache`: each entry is
written through a temporary file and renamed into place, and starts with a
SHA-256 of its key and content; an entry whose digest does not match (cut short,
garbled, renamed, written by JAX's plain cache) is deleted and the program
recompiled and written anew, never run.

The CLI, ``rhythmic-jax demo``, the notebooks and the tests turn the cache on;
importing the library changes no JAX setting. ``RHYTHMIC_JAX_COMPILE_CACHE=0``
(or ``off``, ``false``, ``no``) turns it off everywhere; a folder in that
variable puts the cache there. As JAX warns, the cache is trusted code: keep the
folder private to its user.
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
from pathlib import Path

__all__ = [
    "ENV",
    "MIN_COMPILE_SECONDS",
    "MIN_ENTRY_BYTES",
    "compile_cache_dir",
    "enable_compile_cache",
    "pack_entry",
    "unpack_entry",
]

log = logging.getLogger(__name__)

ENV = "RHYTHMIC_JAX_COMPILE_CACHE"
OFF = ("0", "off", "false", "no")
ON = ("", "1", "on", "true", "yes")
MIN_COMPILE_SECONDS = 0.0
MIN_ENTRY_BYTES = 0
MAGIC = b"rjxc\x00\x01\r\n"  # format of a checked entry, version 1
_DIGEST = 32
_SUFFIX = "-cache"  # the name JAX's file cache gives an entry: <key>-cache


def compile_cache_dir(path: str | os.PathLike | None = None) -> Path | None:
    """The folder of the compile cache: None when ``$RHYTHMIC_JAX_COMPILE_CACHE``
    switches it off; else ``path``, the folder that variable names, or
    ``<cache folder>/jax``."""
    from rhythmic_jax.frames.cache_files import default_cache_dir

    setting = os.environ.get(ENV, "").strip()
    if setting.lower() in OFF:
        return None
    if path is not None:
        return Path(path)
    if setting.lower() not in ON:
        return Path(setting)
    return default_cache_dir() / "jax"


def _digest(key: str, value: bytes) -> bytes:
    h = hashlib.sha256(key.encode())
    h.update(b"\x00")
    h.update(value)
    return h.digest()


def pack_entry(key: str, value: bytes) -> bytes:
    """The file content of JAX's ``value`` under ``key``: magic, SHA-256 of key
    and value, value."""
    return MAGIC + _digest(key, value) + value


def unpack_entry(key: str, data: bytes) -> bytes | None:
    """JAX's value in the file content ``data`` of ``key``; None unless whole
    and written for this key."""
    head = len(MAGIC) + _DIGEST
    if len(data) <= head or not data.startswith(MAGIC):
        return None
    value = data[head:]
    return value if data[len(MAGIC) : head] == _digest(key, value) else None


def _checked_cache_class():
    from jax._src.compilation_cache_interface import CacheInterface

    from rhythmic_jax.errors import InputError
    from rhythmic_jax.io.reader import memory_budget, read_bytes

    class CheckedCache(CacheInterface):
        """JAX's cache interface over a folder of checked, atomically written
        entries (:func:`pack_entry`); a bad entry is deleted and missed."""

        def __init__(self, path: Path):
            self._path = Path(path)
            self.damaged = 0

        def get(self, key: str) -> bytes | None:
            path = self._path / f"{key}{_SUFFIX}"
            try:  # a regular file; a pipe or device there is a miss
                data = read_bytes(path, memory_budget())
            except InputError:
                return None
            value = unpack_entry(key, data)
            if value is None:  # one warning a process, the rest at info
                level = logging.INFO if self.damaged else logging.WARNING
                self.damaged += 1
                log.log(level, "compile cache: recompiling damaged entry %s", path)
                path.unlink(missing_ok=True)
            return value

        def put(self, key: str, value: bytes) -> None:
            path = self._path / f"{key}{_SUFFIX}"
            fd, tmp = tempfile.mkstemp(dir=self._path, prefix=f".{key}.", suffix=".tmp")
            try:
                with os.fdopen(fd, "wb") as f:
                    f.write(pack_entry(key, value))
                os.replace(tmp, path)
            finally:
                Path(tmp).unlink(missing_ok=True)

        def clear(self) -> None:
            for entry in self._path.glob(f"*{_SUFFIX}"):
                entry.unlink(missing_ok=True)

    return CheckedCache


def enable_compile_cache(path: str | os.PathLike | None = None) -> Path | None:
    """Turn on JAX's persistent compilation cache, with checked entries, for
    this process.

    ``path``: the folder (default ``<cache folder>/jax``, see
    :func:`compile_cache_dir`). Takes effect even after programs were compiled.
    Returns the folder, or None (nothing changed) when
    ``$RHYTHMIC_JAX_COMPILE_CACHE`` is ``0``/``off``, or when the folder cannot
    be made or this JAX's cache cannot take checked entries (then it stays off,
    with one warning).

    Example::

        import rhythmic_jax as rj
        rj.enable_compile_cache()  # later processes load the fit's programs
    """
    import jax
    from jax.experimental.compilation_cache import compilation_cache

    folder = compile_cache_dir(path)
    if folder is None:
        return None
    try:  # JAX's own module: where its file cache is made and kept
        from jax._src import compilation_cache as jax_cache

        checked = _checked_cache_class()(folder)
        lock = jax_cache._cache_initialized_mutex
    except (ImportError, AttributeError) as err:
        log.warning("compile cache off: this JAX cannot take checked entries (%s)", err)
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        log.warning("compile cache off: %s", err)
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", MIN_ENTRY_BYTES)
    compilation_cache.reset_cache()  # JAX decides once per process otherwise
    with lock:
        jax_cache._cache = checked
        jax_cache._cache_initialized = True
    return folder
