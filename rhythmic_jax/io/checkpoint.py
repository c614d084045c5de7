"""Maps on disk: orbax-checkpoint arrays plus a JSON metadata file, saved atomically.

A map folder holds ``arrays/`` (an orbax checkpoint of named arrays) and
``map.json`` (format version, periods, n, d, C, dtype, descriptor and its
settings, package version, candidate errors). Saving writes a hidden temporary
folder beside the target and renames it into place, so a process killed during a
save leaves the previous map loadable (if it dies between the two renames, the
previous map is still found under its hidden backup name and :func:`load_map`
takes it from there; the next successful save removes what a killed one left).

The new map is written beside the previous one, so the disk must hold both for a
moment: :func:`check_space` refuses a save (and the command line a fit, before
its solve) that would not fit, and a write that still runs out of space ends
with one line and the previous map in place.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import shutil
import sys
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from rhythmic_jax.errors import InputError

__all__ = [
    "FORMAT_VERSION",
    "check_space",
    "check_target",
    "load_map",
    "save_map",
    "without_closed_loop",
]

FORMAT_VERSION = 1
_META = "map.json"
_ARRAYS = "arrays"
# what a map folder takes beyond its arrays' bytes: map.json and orbax's metadata,
# about 16 files and folders of at most a 4 KiB block each
OVERHEAD_BYTES = 64 * 1024
_FULL = (errno.ENOSPC, errno.EDQUOT)
log = logging.getLogger(__name__)


def _orbax():
    import orbax.checkpoint as ocp  # deferred: orbax is slow to import

    return ocp


def _checkpointer():
    """orbax's checkpointer for this process alone: in a multi-process fit only
    process 0 saves the map, so no other process may be waited for."""
    import jax

    ocp = _orbax()
    if jax.process_count() == 1:
        return ocp.StandardCheckpointer()
    me = jax.process_index()
    options = ocp.options.MultiprocessingOptions(
        primary_host=me, active_processes={me}, barrier_sync_key_prefix=f"map{me}"
    )
    return ocp.StandardCheckpointer(multiprocessing_options=options)


def save_map(
    path: str | os.PathLike, arrays: dict[str, np.ndarray], meta: dict
) -> Path:
    """Write ``arrays`` and ``meta`` to the folder ``path``, replacing it atomically."""
    target = check_target(path)
    arrays = {k: np.asarray(v) for k, v in arrays.items()}
    for name, value in arrays.items():  # orbax fails on these, some after a mkdir
        if value.dtype.kind not in "biufc" or value.size == 0:
            raise InputError(
                f"arrays[{name!r}]: cannot save a {value.dtype} array of shape "
                f"{value.shape} (need a non-empty numeric array)"
            )
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"{target}: cannot create its folder ({err})") from None
    body = json.dumps({"format_version": FORMAT_VERSION, **meta}, indent=2)
    check_space(target, sum(v.nbytes for v in arrays.values()) + len(body))
    tmp = target.parent / f".{target.name}.tmp-{uuid.uuid4().hex[:8]}"
    old = target.parent / f".{target.name}.old-{uuid.uuid4().hex[:8]}"
    try:
        with _disk_full_is_input_error(target, tmp):
            _write(tmp, arrays, body)
        if target.exists():
            _clean(target, "old")  # a killed clean-up's leftovers: keep one backup
            os.rename(target, old)
        os.rename(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if old.exists() and not target.exists():
            os.rename(old, target)  # put the previous map back
        raise
    _clean(target, "old", "tmp")  # the previous map, and killed saves' leftovers
    return target


def without_closed_loop(hook):
    """``hook`` (a ``sys.unraisablehook``) minus the "Event loop is closed" that
    orbax's I/O threads raise when they answer after a failed read or write has
    closed its loop; the command line keeps it for its whole run, as the threads
    may answer late."""

    if getattr(hook, "without_closed_loop", False):
        return hook  # once is enough

    def unraisable(info):
        if str(info.exc_value) != "Event loop is closed":
            hook(info)

    unraisable.without_closed_loop = True
    return unraisable


@contextlib.contextmanager
def _quiet_orbax_failures():
    """Orbax's echoes of a failed read or write (absl error logs, and its I/O
    threads' "Event loop is closed") stay off stderr: the caller reports the
    failure once."""
    absl, hook = logging.getLogger("absl"), sys.unraisablehook
    level = absl.level
    absl.setLevel(logging.CRITICAL)
    sys.unraisablehook = without_closed_loop(hook)
    try:
        yield
    finally:
        absl.setLevel(level)
        sys.unraisablehook = hook


def _write(tmp: Path, arrays: dict[str, np.ndarray], body: str) -> None:
    """The new map's files in the hidden folder ``tmp``."""
    ckpt = _checkpointer()
    with _quiet_orbax_failures():
        try:
            ckpt.save(tmp / _ARRAYS, arrays)
            ckpt.wait_until_finished()
        finally:
            ckpt.close()
    with open(tmp / _META, "w") as fh:
        fh.write(body)
        fh.flush()
        os.fsync(fh.fileno())


def _free_bytes(folder: Path) -> int:
    """Bytes free to this user on the file system of ``folder`` (or its first
    existing parent)."""
    while not folder.exists():
        folder = folder.parent
    return shutil.disk_usage(folder).free


def check_space(path: str | os.PathLike, nbytes: int) -> None:
    """Refuse (:class:`InputError`) a map of ``nbytes`` array and metadata bytes
    that the disk under ``path`` cannot hold beside the previous map."""
    folder = Path(path).expanduser().absolute().parent
    need, free = int(nbytes) + OVERHEAD_BYTES, _free_bytes(folder)
    if need > free:
        raise InputError(
            f"{folder}: the map needs about {need:,} bytes but only {free:,} are free"
        )


def _is_disk_full(err: BaseException) -> bool:
    if isinstance(err, OSError) and err.errno in _FULL:
        return True  # tensorstore (under orbax) raises ValueError with the reason
    text = str(err)
    return "No space left on device" in text or "Disk quota exceeded" in text


@contextlib.contextmanager
def _disk_full_is_input_error(target: Path, tmp: Path):
    """A full disk while ``tmp`` is written: one line, and ``tmp`` removed."""
    try:
        yield
    except Exception as err:
        if not _is_disk_full(err):
            raise
        shutil.rmtree(tmp, ignore_errors=True)
        kept = "; the previous map is unchanged" if target.exists() else ""
        raise InputError(
            f"{target.parent}: the disk filled up while the map was written "
            f"({_free_bytes(target.parent):,} bytes free){kept}"
        ) from None


def _clean(target: Path, *kinds: str) -> None:
    """Remove the hidden ``.<name>.<kind>-*`` folders beside ``target``."""
    for kind in kinds:
        for stale in target.parent.glob(f".{target.name}.{kind}-*"):
            shutil.rmtree(stale, ignore_errors=True)


def check_target(path: str | os.PathLike) -> Path:
    """The absolute path a map may be saved to, or :class:`InputError` (checked
    before a long fit): an existing path must be a map folder, and no parent of it
    may be a file."""
    target = Path(path).expanduser().absolute()
    if target.exists() and not (target / _META).is_file():
        raise InputError(
            f"{target}: exists and is not a map folder; refusing to replace it"
        )
    for parent in target.parents:
        if parent.exists():
            if not parent.is_dir():
                raise InputError(f"{target}: {parent} is a file, not a folder")
            break
    return target


def _resolve(target: Path) -> Path:
    if target.is_dir():
        return target
    backups = sorted(target.parent.glob(f".{target.name}.old-*"))
    if backups:
        log.warning("%s: missing; loading the copy kept by an interrupted save", target)
        return backups[-1]
    if target.exists():
        raise InputError(f"{target}: not a map folder (it is a file)")
    raise InputError(f"{target}: no such map folder")


def read_metadata(path: str | os.PathLike) -> tuple[Path, dict[str, Any]]:
    """A map folder's checked metadata, without its arrays: (folder, metadata)."""
    folder = _resolve(Path(path).expanduser().absolute())
    meta_file = folder / _META
    try:
        meta = json.loads(meta_file.read_text())
    except FileNotFoundError:
        raise InputError(f"{folder}: not a map folder ({_META} is missing)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise InputError(f"{meta_file}: corrupt metadata ({err})") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("format_version"), int):
        raise InputError(f"{meta_file}: corrupt metadata (no format_version)")
    if meta["format_version"] > FORMAT_VERSION:
        raise InputError(
            f"{folder}: map format {meta['format_version']} is newer than this "
            f"rhythmic_jax reads ({FORMAT_VERSION}); upgrade the package"
        )
    return folder, meta


def arrays_listed(folder: Path) -> set[str]:
    """Names of the arrays a completed save lists (empty when it is incomplete).

    Reads orbax's plain-JSON tree metadata only, so it needs neither orbax nor
    JAX; it does not read or check the arrays' data (:func:`load_map` does).
    """
    arrays = Path(folder) / _ARRAYS
    try:
        tree = json.loads((arrays / "_METADATA").read_text())["tree_metadata"]
        done = (arrays / "commit_success.txt").is_file()
    except (OSError, ValueError, KeyError, TypeError):
        return set()
    if not done or not isinstance(tree, dict):
        return set()
    return {k.strip("(),' ") for k in tree}


def load_map(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read a map folder: (arrays, metadata). Bad folders raise :class:`InputError`."""
    folder, meta = read_metadata(path)
    ckpt = _checkpointer()
    with _quiet_orbax_failures():
        try:
            raw = ckpt.restore(folder / _ARRAYS)
        except Exception as err:  # noqa: BLE001 - orbax raises many kinds
            msg = str(err).splitlines()[0] if str(err) else type(err).__name__
            msg = msg.split(" [tensorstore_spec=")[0]  # drop the driver's JSON spec
            msg = msg.split(": Error reading")[0]  # the file, not the driver's chain
            raise InputError(
                f"{folder}: arrays are missing or corrupt ({msg})"
            ) from None
        finally:
            ckpt.close()  # an unclosed checkpointer leaks its event loop
    return {k: np.asarray(v) for k, v in raw.items()}, meta
