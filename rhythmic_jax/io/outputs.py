"""Where a job writes: every output's place checked before any work, a failed
write said in one line, and nothing put in place once the job is cancelled.

A job that would fail only at its end (a read-only folder, a full disk, a path
under a file) is refused before it reads a frame: :func:`check_place` writes and
removes a one-byte probe file where the output will go. A write that still fails
(the disk fills up on the way) ends in one line naming the output
(:func:`write_errors`), never a traceback.

Outputs are written to hidden temporaries and renamed into place. Every such
rename runs under :func:`committing`: once :func:`cancel` is called (the command
line does so on Ctrl-C or SIGTERM, :mod:`rhythmic_jax.app.signals`), no output is
put in place any more, and a rename already under way finishes first. A folder
filled over many steps (the shard folders of ``fit --shards``) is staged whole
(:func:`staged_folder`), so a failed or killed run leaves only a hidden folder
that the next run removes, never one that blocks it.

What an output path names decides how it is written (:func:`output_target`): a
regular file or a new name is replaced atomically (a link to a file: the file it
names, the link kept); a character device or a FIFO (``/dev/null``, ``/dev/full``,
a named pipe, or a link to one) is opened and written through, never replaced; a
stream of this process (``/dev/stdout``, ``/dev/fd/N``, ``/proc/self/fd/N``) is
written to its open descriptor; a folder where a file is wanted, a socket or a
block device is refused, before any work (:func:`check_place` with ``file``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import logging
import os
import re
import shutil
import stat
import tempfile
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path

from rhythmic_jax.errors import InputError

__all__ = [
    "Cancelled",
    "OutputError",
    "Target",
    "cancel",
    "cancelled",
    "check_file_place",
    "check_place",
    "committing",
    "output_target",
    "process_alive",
    "staged_folder",
    "write_errors",
]

# errors that say the place cannot take the output (not that the job is wrong)
WRITE_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM)
_WORDS = ("No space left on device", "Disk quota exceeded", "Read-only file system",
          "Permission denied")  # fmt: skip
# numpy's tofile on a full disk: an OSError with no errno
_SHORT = re.compile(r"^\d+ requested and \d+ written$")
_COMMIT = threading.Lock()
# a stream of a process named as a path: /proc/self/fd/1, /proc/<pid>/fd/1, /dev/fd/1
_FD_PATH = re.compile(r"^/(?:proc/(self|\d+)/fd|dev/fd)/(\d+)$")
_MAX_LINKS = 40  # as the kernel's ELOOP limit
_CANCELLED = threading.Event()


class Cancelled(KeyboardInterrupt):
    """An output was about to be put in place after the job was cancelled."""


class OutputError(InputError):
    """An output that cannot be written where it was asked for: ``path`` and
    ``what`` went wrong; :func:`write_errors` names the option in the line."""

    def __init__(self, path: str | os.PathLike, what: str):
        self.path, self.what = str(path), what
        super().__init__(f"{path}: {what}")


@dataclasses.dataclass(frozen=True)
class Target:
    """Where a file output goes.

    Attributes:
      given: the path as asked for, absolute.
      path: where it is written: the file a chain of links ends at (or a new
        name), the device or FIFO to open.
      kind: ``"file"`` (replaced atomically at ``path``), ``"device"`` (a
        character device or FIFO, opened and written through) or ``"stream"``
        (this process's open descriptor ``fd``, written through).
      fd: the descriptor of a ``"stream"``.
    """

    given: Path
    path: Path
    kind: str
    fd: int | None = None


def _what(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "is a folder; give a file name"
    if stat.S_ISSOCK(mode):
        return "is a socket; give a file, a device or a pipe"
    if stat.S_ISBLK(mode):
        return "is a block device; give a file, a character device or a pipe"
    return "is not a file, a device or a pipe"


def output_target(path: str | os.PathLike) -> Target:
    """What the file output ``path`` names, following its links one by one
    (:class:`Target`); a folder, a socket, a block device or a link loop is
    refused (:class:`OutputError`). Nothing is opened or created."""
    given = Path(path).expanduser().absolute()
    here = given
    for _ in range(_MAX_LINKS):
        stream = _FD_PATH.match(str(here))
        if stream and stream.group(1) in (None, "self", str(os.getpid())):
            return Target(given, here, "stream", int(stream.group(2)))
        if stream:  # another process's stream: opened through its path
            return Target(given, here, "device")
        if not here.is_symlink():
            break
        here = here.parent.resolve() / os.readlink(here)
    else:
        raise OutputError(given, "too many levels of links")
    try:
        mode = os.stat(here).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return Target(given, here, "file")  # a new name (check_place looks above)
    except OSError as err:
        what = f"cannot reach it ({os.strerror(err.errno)})"
        raise OutputError(given, what) from None
    if stat.S_ISREG(mode):
        return Target(given, here, "file")
    if stat.S_ISCHR(mode) or stat.S_ISFIFO(mode):
        return Target(given, here, "device")
    raise OutputError(given, _what(mode))


def cancel(timeout: float = 5.0) -> None:
    """Put no output in place from now on; return once a rename under way (if
    any) has finished, or after ``timeout`` seconds."""
    _CANCELLED.set()
    if _COMMIT.acquire(timeout=timeout):
        _COMMIT.release()


def cancelled() -> bool:
    """Whether :func:`cancel` was called in this process."""
    return _CANCELLED.is_set()


@contextlib.contextmanager
def committing() -> Iterator[None]:
    """Hold while an output is renamed into place; raises :class:`Cancelled`
    (before the rename) once the job is cancelled."""
    with _COMMIT:
        if _CANCELLED.is_set():
            raise Cancelled("cancelled before the output was put in place")
        yield


def _reason(err: BaseException) -> str:
    if isinstance(err, OSError) and err.errno is not None:
        return os.strerror(err.errno)
    text = str(err)
    if _SHORT.search(text):
        return f"the disk is full: {text}"
    return next((w for w in _WORDS if w in text), text.splitlines()[0] if text else "")


def _check_through(option: str, path, target: Target) -> None:
    """A device or stream output: it must be open (a stream) or writable (a
    device). A FIFO is not opened here: a reader would see its end at once."""
    if target.kind == "stream":
        try:
            os.fstat(target.fd)
        except OSError:
            raise InputError(
                f"{{opt:{option}}} {path}: descriptor {target.fd} is closed"
            ) from None
    elif not os.access(target.path, os.W_OK):
        raise InputError(
            f"{{opt:{option}}} {path}: cannot write it ({os.strerror(errno.EACCES)})"
        )


def check_file_place(option: str, path: str | os.PathLike | None) -> Path | None:
    """One file's output ``path`` (None: not asked for): its folder must exist
    (one line naming it), then :func:`check_place` with ``file=True``."""
    if not path:
        return None
    if not Path(path).absolute().parent.is_dir():
        where = Path(path).parent
        raise InputError(f"{{opt:{option}}} {path}: folder {where} not found")
    return check_place(option, path, file=True)


def check_place(
    option: str, path: str | os.PathLike, inside: bool = False, file: bool = False
) -> Path:
    """Refuse (:class:`InputError`, one line) an output ``path`` that cannot be
    written; returns it absolute.

    The folder that will hold ``path`` (its nearest existing parent, as missing
    ones are created) must be a folder where a file can be created and written:
    a one-byte probe file is written and removed there, so a read-only, full or
    forbidden place is refused now, not at the job's end. ``inside``: ``path`` is
    a folder written into (a checkpoint, a report's folder): an existing one is
    probed as well, a file there refused.

    Args:
      option: the setting that names the output (``out``, ``plot``, ...).
      path: where the output goes (a file or a folder).
      inside: ``path`` is a folder: probe it too where it exists; a file there
        is refused.
      file: the output is one file (:func:`output_target`): a folder there is
        refused, a device or a pipe checked for writing instead of its folder,
        and the folder probed is that of the file a link names.
    """
    target = Path(path).expanduser().absolute()
    if file:
        try:
            named = output_target(target)
        except OutputError as err:
            raise InputError(f"{{opt:{option}}} {path}: {err.what}") from None
        if named.kind != "file":
            _check_through(option, path, named)
            return target
        target = named.path
    if inside and target.exists() and not target.is_dir():
        raise InputError(f"{{opt:{option}}} {path}: a file, not a folder")
    folder = target.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise InputError(f"{{opt:{option}}} {path}: {folder} is a file, not a folder")
    places = [folder] + ([target] if inside and target.is_dir() else [])
    for place in places:
        try:
            fd, probe = tempfile.mkstemp(dir=place, prefix=".rhythmic-jax-probe-")
            try:
                os.write(fd, b"\0")
            finally:
                os.close(fd)
                os.unlink(probe)
        except OSError as err:
            raise InputError(
                f"{{opt:{option}}} {path}: cannot write in {place} ({_reason(err)})"
            ) from None
    return target


def _concerns(err: BaseException, target: Path) -> bool:
    """Whether ``err`` is a failed write of the output at ``target`` (its file or
    folder, a hidden temporary beside it, or a folder made for it)."""
    if isinstance(err, OSError):
        if err.errno is None and _SHORT.search(str(err)):
            return True
        if err.errno not in WRITE_ERRNOS:
            return False
        if err.filename is None:
            return True  # a write to an open file: ours, as no input is written
        name = Path(os.fsdecode(err.filename)).absolute()
        hidden = f".{target.name}."  # the temporaries written beside it
        return (
            name == target
            or target in name.parents
            or name in target.parents
            or any(p.name.startswith(hidden) for p in (name, *name.parents))
        )
    # orbax and tensorstore raise their own types, with the reason in the text
    return any(w in str(err) for w in _WORDS)


@contextlib.contextmanager
def write_errors(option: str, path: str | os.PathLike) -> Iterator[None]:
    """Within, a failed write of the output at ``path`` (a full, read-only or
    forbidden place) ends in one line (:class:`InputError`); other errors pass.
    Orbax's echoes of a failed write (error logs with tracebacks, from its
    writer threads) stay off stderr: the line says it once."""
    target = Path(path).expanduser().absolute()
    absl = logging.getLogger("absl")
    level = absl.level
    absl.setLevel(logging.CRITICAL)
    try:
        yield
    except OutputError as err:
        if Path(err.path) != target:
            raise
        raise InputError(f"{{opt:{option}}} {path}: {err.what}") from None
    except InputError:
        raise
    except Exception as err:
        if not _concerns(err, target):
            raise
        raise InputError(
            f"{{opt:{option}}} {path}: could not write it ({_reason(err)})"
        ) from None
    finally:
        absl.setLevel(level)


def process_alive(pid: int) -> bool:
    """Whether the process ``pid`` is running (someone else's counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # someone else's process
    return True


def _remove_stale(target: Path) -> None:
    """Remove the staged folders beside ``target`` whose process is gone."""
    for stale in target.parent.glob(f".{target.name}.tmp-*"):
        pid = stale.name.rsplit(".tmp-", 1)[1].split("-")[0]
        if pid.isdigit() and not process_alive(int(pid)):
            shutil.rmtree(stale, ignore_errors=True)


@contextlib.contextmanager
def staged_folder(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a new hidden folder beside ``path`` to fill; on a clean exit it is
    renamed to ``path``, on any error (Ctrl-C included) removed. Folders staged
    by runs whose process is gone are removed first; those of a run still going
    are left alone."""
    target = Path(path).expanduser().absolute()
    target.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale(target)
    tmp = target.parent / f".{target.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    tmp.mkdir()
    try:
        yield tmp
        with committing():
            os.rename(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
