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
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import re
import shutil
import tempfile
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path

from rhythmic_jax.errors import InputError

__all__ = [
    "Cancelled",
    "cancel",
    "cancelled",
    "check_place",
    "committing",
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
_CANCELLED = threading.Event()


class Cancelled(KeyboardInterrupt):
    """An output was about to be put in place after the job was cancelled."""


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


def check_place(option: str, path: str | os.PathLike, inside: bool = False) -> Path:
    """Refuse (:class:`InputError`, one line) an output ``path`` that cannot be
    written; returns it absolute.

    The folder that will hold ``path`` (its nearest existing parent, as missing
    ones are created) must be a folder where a file can be created and written:
    a one-byte probe file is written and removed there, so a read-only, full or
    forbidden place is refused now, not at the job's end. ``inside``: an existing
    folder at ``path`` is written into too (a checkpoint), so it is probed as well.

    Args:
      option: the setting that names the output (``out``, ``plot``, ...).
      path: where the output goes (a file or a folder).
    """
    target = Path(path).expanduser().absolute()
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


def _alive(pid: int) -> bool:
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
        if pid.isdigit() and not _alive(int(pid)):
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
