"""Maps on disk: orbax-checkpoint arrays plus a JSON metadata file, saved atomically
under a lock, every stored byte checksummed.

A map folder holds ``arrays/`` (an orbax checkpoint of named arrays) and
``map.json`` (format version, periods, n, d, C, dtype, descriptor and its
settings, package version, candidate errors, and ``digests``: the sha256 of every
file under ``arrays/`` and of every array's values). Saving writes a hidden
temporary folder beside the target and renames it into place, so a process killed
during a save leaves the previous map loadable (if it dies between the two
renames, the previous map is still found under its hidden backup name and
:func:`load_map` takes it from there).

One writer at a time, one whole version for every reader (as git locks a ref): a
save holds an exclusive OS lock (``fcntl.flock``) on the folder that holds the
target from its first write to its last rename, and a read (metadata, digests,
arrays) holds a shared one, so two saves onto one path end with one
complete map (the second waits for the first), and a reader sees the previous or
the new map whole, never half of each. Whoever holds the exclusive lock knows
that every hidden ``.<name>.tmp-*`` or ``.old-*`` folder is a killed writer's
leftover, and removes it; no live writer's temporary folder is ever touched.

Checksums (as SQLite checks every page): :func:`load_map` and
:func:`verify_files` refuse a map whose files changed since it was saved, in one
line naming the file; maps saved before digests existed still load
(:func:`checksums_of` says so).

The new map is written beside the previous one, so the disk must hold both for a
moment: :func:`check_space` refuses a save (and the command line a fit, before
its solve) that would not fit, and a write that still runs out of space ends
with one line and the previous map in place.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import logging
import os
import shutil
import stat
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.outputs import committing
from rhythmic_jax.io.reader import check_budget, file_sha256, inside, read_json

__all__ = [
    "FORMAT_VERSION",
    "check_space",
    "check_target",
    "checksums_of",
    "load_map",
    "locked",
    "orbax_folder",
    "save_map",
    "verify_files",
    "without_closed_loop",
]

FORMAT_VERSION = 1
_META = "map.json"
_ARRAYS = "arrays"
# what a map folder takes beyond its arrays' bytes: map.json and orbax's metadata,
# about 16 files and folders of at most a 4 KiB block each
OVERHEAD_BYTES = 64 * 1024
_FULL = (errno.ENOSPC, errno.EDQUOT)
_DIGESTS = "digests"
# how long a save or a read waits for another process's save (or reads) to end
LOCK_WAIT_S = 120.0
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
    """Write ``arrays`` and ``meta`` to the folder ``path``, replacing it atomically
    under the path's exclusive lock (another save onto it waits its turn)."""
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
    values = {name: array_digest(value) for name, value in arrays.items()}
    body = {"format_version": FORMAT_VERSION, **meta}
    size = len(json.dumps(body, indent=2)) + 100 * (len(values) + 16)
    check_space(target, sum(v.nbytes for v in arrays.values()) + size)
    with locked(target, exclusive=True):
        check_target(target)  # another save may have left something else there
        _recover(target)
        _clean(target, "old", "tmp")  # killed saves' leftovers: their locks are free
        tmp = target.parent / f".{target.name}.tmp-{uuid.uuid4().hex[:8]}"
        old = target.parent / f".{target.name}.old-{uuid.uuid4().hex[:8]}"
        try:
            body[_DIGESTS] = {"sha256": {"arrays": values}}
            with _disk_full_is_input_error(target, tmp):
                _write(tmp, arrays, body)
            with committing():  # a cancelled job puts no map in place
                if target.exists():
                    os.rename(target, old)
                os.rename(tmp, target)
            _fsync_folder(target.parent)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            if old.exists() and not target.exists():
                os.rename(old, target)  # put the previous map back
            raise
        shutil.rmtree(old, ignore_errors=True)
    return target


@contextlib.contextmanager
def locked(path: str | os.PathLike, *, exclusive: bool) -> Iterator[None]:
    """Hold the lock of the map (or embedding) folder ``path``: exclusive for a
    save, shared for a read.

    The lock is ``fcntl.flock`` on the folder that holds ``path`` (its parent
    directory, opened read-only): nothing is created beside the user's files, a
    read-only folder locks as well, and the OS releases the lock when its holder
    dies, so a killed writer never blocks the next. Saves of two maps in one
    folder take turns too (a save lasts a second or so). A path whose parent does
    not exist is read unlocked (there is nothing to read). Waiting longer than
    :data:`LOCK_WAIT_S` ends in :class:`InputError`.
    """
    target = Path(path).expanduser().absolute()
    try:
        fd = os.open(target.parent, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError as err:
        if exclusive:
            raise InputError(
                f"{target.parent}: cannot lock the folder "
                f"({(err.strerror or str(err)).lower()})"
            ) from None
        yield  # no such folder: the read says so
        return
    try:
        _acquire(fd, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH, target)
        yield
    finally:
        os.close(fd)  # releases the lock


def _acquire(fd: int, mode: int, target: Path) -> None:
    """Take the lock, waiting for its holder (logged once) up to LOCK_WAIT_S."""
    deadline = None
    while True:
        try:
            fcntl.flock(fd, mode | fcntl.LOCK_NB)
            return
        except BlockingIOError:
            pass
        if deadline is None:
            deadline = time.monotonic() + LOCK_WAIT_S
            log.info("%s: waiting for another process's save to end", target)
        elif time.monotonic() > deadline:
            raise InputError(
                f"{target}: another process has held it for over {LOCK_WAIT_S:.0f} "
                "s (saving or reading it); try again when it is done"
            )
        time.sleep(0.02)


def _recover(target: Path) -> None:
    """Put back the previous map of a save killed between its two renames."""
    backups = sorted(
        target.parent.glob(f".{target.name}.old-*"), key=lambda p: p.stat().st_mtime
    )
    if not target.exists() and backups and (backups[-1] / _META).is_file():
        os.rename(backups[-1], target)


def _fsync_folder(folder: Path) -> None:
    """Make the renames in ``folder`` durable (where the file system allows)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


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


def orbax_folder(folder: Path) -> tuple[Path, int | None]:
    """``folder`` as orbax's file system layer (tensorstore) can take it, and the
    descriptor to close once orbax is done (None: nothing opened).

    A path whose bytes are not UTF-8 (file names carried as the OS gives them,
    any non-ASCII name in the C locale) cannot be handed to tensorstore; the
    folder (made if missing) is then reached through an open descriptor,
    ``/proc/self/fd/N``, which both Python and tensorstore resolve."""
    try:
        str(folder).encode("utf-8")
        return folder, None
    except UnicodeEncodeError:
        folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        return Path(f"/proc/self/fd/{fd}"), fd


@contextlib.contextmanager
def _orbax_path(folder: Path) -> Iterator[Path]:
    """:func:`orbax_folder` for the time of a save or a restore."""
    place, fd = orbax_folder(folder)
    try:
        yield place
    finally:
        if fd is not None:
            os.close(fd)


def _write_arrays(tmp: Path, arrays: dict[str, np.ndarray]) -> None:
    """The new map's arrays in the hidden folder ``tmp``."""
    ckpt = _checkpointer()
    with _quiet_orbax_failures(), _orbax_path(tmp) as folder:
        try:
            ckpt.save(folder / _ARRAYS, arrays)
            ckpt.wait_until_finished()
        finally:
            ckpt.close()


def _write(tmp: Path, arrays: dict[str, np.ndarray], body: dict) -> None:
    """The new map's files in the hidden folder ``tmp``: the arrays, then
    ``map.json`` holding ``body`` with the sha256 of every file just written."""
    _write_arrays(tmp, arrays)
    body[_DIGESTS]["sha256"]["files"] = _file_digests(tmp / _ARRAYS)
    with open(tmp / _META, "w") as fh:
        fh.write(json.dumps(body, indent=2))
        fh.flush()
        os.fsync(fh.fileno())


# ------------------------------------------------------------------- checksums


def _file_digests(folder: Path) -> dict[str, str]:
    """sha256 of every file under ``folder``, by its path relative to it."""
    return {
        p.relative_to(folder).as_posix(): file_sha256(p)
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def array_digest(x: np.ndarray) -> str:
    """sha256 of an array's values: its dtype's name, its shape and its elements
    in C order, little-endian (the same for a big-endian or Fortran-ordered array
    of the same values, as orbax reads them back native and C-ordered)."""
    x = np.asarray(x)
    x = np.ascontiguousarray(x, dtype=x.dtype.newbyteorder("<"))
    head = f"{x.dtype.name}{list(x.shape)}".encode()
    return hashlib.sha256(head + x.tobytes()).hexdigest()


def _digests(meta: dict[str, Any], folder: Path) -> dict[str, dict[str, str]] | None:
    """The map's recorded digests ({"files": ..., "arrays": ...}), None in a map
    saved before they existed."""
    if _DIGESTS not in meta:
        return None
    try:
        table = meta[_DIGESTS]["sha256"]
        files, values = dict(table["files"]), dict(table["arrays"])
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{folder / _META}: corrupt metadata (digests)") from None
    return {"files": files, "arrays": values}


def checksums_of(meta: dict[str, Any]) -> str:
    """What ``info`` says of a map's checksums."""
    if _DIGESTS in meta:
        return "sha256 of every stored array, checked"
    return "none (saved before maps carried checksums; not checked)"


def verify_files(folder: Path, meta: dict[str, Any], missing: bool = True) -> None:
    """Refuse (:class:`InputError`, naming the file) a map whose array files
    differ from those its save recorded, or (``missing``) are missing; a map
    saved before digests passes unchecked. :func:`load_map` leaves missing files
    to orbax's restore, which names what it lacks."""
    digests = _digests(meta, folder)
    if digests is None:
        return
    root = folder / _ARRAYS
    for name, expected in digests["files"].items():
        path = inside(root, name, "digest path")  # no name leaves the map
        if not missing and not os.path.lexists(path):
            continue
        try:
            actual = file_sha256(path)
        except InputError as err:
            raise InputError(
                f"{folder}: arrays are missing or corrupt ({err})"
            ) from None
        if actual != expected:
            raise InputError(
                f"{folder}: arrays are missing or corrupt ({_ARRAYS}/{name} changed "
                "since the map was saved: its sha256 differs)"
            )


def _verify_arrays(folder: Path, meta: dict, arrays: dict[str, np.ndarray]) -> None:
    digests = _digests(meta, folder)
    if digests is None:
        return
    expected = digests["arrays"]
    if set(expected) != set(arrays):
        missing = sorted(set(expected) ^ set(arrays))
        raise InputError(f"{folder}: arrays are missing or corrupt ({missing})")
    for name, value in arrays.items():
        if array_digest(value) != expected[name]:
            raise InputError(
                f"{folder}: arrays are missing or corrupt (array {name!r} changed "
                "since the map was saved: its sha256 differs)"
            )


def _check_tree(root: Path) -> None:
    """Refuse (:class:`InputError`) a map whose ``arrays/`` holds anything but
    folders and regular files inside it (a link may name a file inside)."""
    for where, folders, files in os.walk(root):
        for name in folders + files:
            rel = (Path(where) / name).relative_to(root).as_posix()
            target = inside(root, rel, "array file")
            try:
                mode = os.stat(target).st_mode
            except OSError as err:
                reason = (err.strerror or str(err)).lower()
                raise InputError(f"{root / rel}: cannot read ({reason})") from None
            if stat.S_ISDIR(mode) and os.path.islink(Path(where) / name):
                raise InputError(f"{root / rel}: a link to a folder; refusing it")
            if not (stat.S_ISDIR(mode) or stat.S_ISREG(mode)):
                raise InputError(
                    f"{root.parent}: arrays are missing or corrupt ({rel} is not "
                    "a regular file)"
                )


def _check_declared(folder: Path, metadata) -> None:
    """Refuse a map whose arrays declare more bytes than the memory budget
    (:func:`rhythmic_jax.io.reader.check_budget`), before orbax allocates them."""
    tree = getattr(metadata, "item_metadata", metadata) or {}
    shapes = [(v.shape, v.dtype) for v in tree.values() if hasattr(v, "shape")]
    nbytes = sum(int(np.prod(s, dtype=object)) * np.dtype(t).itemsize
                 for s, t in shapes)  # fmt: skip
    check_budget(folder, nbytes, f"its {len(shapes)} arrays")


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
    may be a file. A link is followed: the map it names is the one replaced (as a
    write through a link to a file replaces the file), the link itself is kept and
    nothing is left beside it."""
    given = target = Path(path).expanduser().absolute()
    if target.is_symlink():
        target = Path(os.path.realpath(target))
    if target.exists() and not (target / _META).is_file():
        raise InputError(
            f"{given}: exists and is not a map folder; refusing to replace it"
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
    if not os.path.lexists(meta_file):
        raise InputError(f"{folder}: not a map folder ({_META} is missing)")
    inside(folder, _META, "metadata file")  # a link leaving the map is refused
    meta = read_json(meta_file, "metadata")  # regular, bounded, not too deep
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
        listing = inside(arrays, "_METADATA", "array listing")
        tree = read_json(listing, "array listing")["tree_metadata"]
        done = (arrays / "commit_success.txt").is_file()
    except (InputError, KeyError, TypeError):
        return set()
    if not done or not isinstance(tree, dict):
        return set()
    return {k.strip("(),' ") for k in tree}


def load_map(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read a map folder: (arrays, metadata), under the path's shared lock (a save
    waits for the read, the read for a save), every file and array checked
    against its save's digests (which the metadata returned leaves out). Bad
    folders raise :class:`InputError`."""
    with locked(path, exclusive=False):
        folder, meta = read_metadata(path)
        verify_files(folder, meta, missing=False)
        _check_tree(folder / _ARRAYS)  # what orbax reads: files inside, regular
        ckpt = _checkpointer()
        with _quiet_orbax_failures():
            try:
                with _orbax_path(folder) as place:
                    _check_declared(folder, ckpt.metadata(place / _ARRAYS))
                    raw = ckpt.restore(place / _ARRAYS)
            except InputError:
                raise
            except Exception as err:  # noqa: BLE001 - orbax raises many kinds
                msg = str(err).splitlines()[0] if str(err) else type(err).__name__
                msg = msg.split(" [tensorstore_spec=")[0]  # drop the driver's spec
                msg = msg.split(": Error reading")[0]  # the file, not the chain
                raise InputError(
                    f"{folder}: arrays are missing or corrupt ({msg})"
                ) from None
            finally:
                ckpt.close()  # an unclosed checkpointer leaks its event loop
        verify_files(folder, meta)  # files orbax did without are missing still
    arrays = {k: np.asarray(v) for k, v in raw.items()}
    _verify_arrays(folder, meta, arrays)
    meta.pop(_DIGESTS, None)  # the file's business, not the map's
    return arrays, meta
