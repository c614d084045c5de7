"""The one writer of file outputs: a file appears whole at its path, or not at all;
a device or a pipe is written through, never replaced.

Everything the package writes to a single file (descriptor files, the descriptor
cache, figures, predictions, tables, reports) goes through :func:`atomic_path`,
which asks :func:`rhythmic_jax.io.outputs.output_target` what the path names:

- a regular file or a new name (or a link to one: the file it names, the link
  kept): the content is written to a hidden temporary file in the target's
  folder (``.<name>.<pid>-*.tmp``; those of killed writers are removed by the
  next write), flushed to disk, given the permissions a plain ``open`` would
  give, and renamed over the target (``os.replace``, atomic on POSIX);
- a character device or a FIFO (``/dev/null``, ``/dev/full``, a named pipe, or a
  link to one): the content is written to a temporary file elsewhere, then
  copied into the device, opened for writing as it is; a FIFO is opened without
  blocking, so one that no process reads ends in one line, not a hang;
- a stream of this process (``/dev/stdout``, ``/dev/fd/N``, ``/proc/self/fd/N``):
  the same, written to the open descriptor (at its offset, in its mode);
- a folder, a socket or a block device: refused.

A write that fails on a device or a stream (``/dev/full``, a pipe whose reader
left, a closed descriptor) ends in one line (:class:`~rhythmic_jax.io.outputs.
OutputError`). Anything raised on the way, Ctrl-C included, removes the temporary
file and leaves the previous content in place; once the job is cancelled
(:func:`rhythmic_jax.io.outputs.cancel`) nothing is renamed into place or written
through. Map folders use the same rename at folder level
(:mod:`rhythmic_jax.io.checkpoint`).
"""

from __future__ import annotations

import contextlib
import errno
import glob
import os
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from rhythmic_jax.io.outputs import (
    OutputError,
    Target,
    committing,
    output_target,
    process_alive,
)

__all__ = ["atomic_path", "save_npy", "write_file"]

_BLOCK = 1 << 20


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path to write; on a clean exit its content becomes
    ``path`` (replaced atomically, or written through a device or stream)."""
    target = output_target(path)
    if target.kind != "file":
        with _through(target) as tmp:
            yield tmp
        return
    path = target.path
    path.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale(path)
    prefix = f".{path.name}.{os.getpid()}-"
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=prefix, suffix=".tmp")
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes the file owner-only
        with committing():
            os.replace(tmp, path)
    except IsADirectoryError:  # a folder made there since output_target looked
        tmp.unlink(missing_ok=True)
        raise OutputError(target.given, "is a folder; give a file name") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _remove_stale(path: Path) -> None:
    """Remove the temporaries beside ``path`` of writers whose process is gone
    (killed before they could): ``.<name>.<pid>-*.tmp``."""
    start = len(path.name) + 2
    for stale in path.parent.glob(f".{glob.escape(path.name)}.*-*.tmp"):
        pid = stale.name[start:].split("-", 1)[0]
        if pid.isdigit() and not process_alive(int(pid)):
            stale.unlink(missing_ok=True)


@contextmanager
def _through(target: Target) -> Iterator[Path]:
    """Yield a temporary file (in the temporary folder); on a clean exit its
    bytes are written through ``target``'s device or stream, and it is removed."""
    folder = Path(tempfile.gettempdir())
    _remove_stale(folder / "rhythmic-jax-out")
    prefix = f".rhythmic-jax-out.{os.getpid()}-"
    fd, name = tempfile.mkstemp(dir=folder, prefix=prefix, suffix=".tmp")
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        with committing():
            _copy(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


def _open(target: Target) -> int:
    """A new descriptor writing to ``target`` (never created, truncated or
    waited for)."""
    try:
        if target.kind == "stream":
            for stream in (sys.stdout, sys.stderr):  # what was printed goes first
                with contextlib.suppress(Exception):
                    if stream.fileno() == target.fd:
                        stream.flush()
            return os.dup(target.fd)
        flags = os.O_WRONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC
        fd = os.open(target.path, flags)
    except OSError as err:
        raise OutputError(target.given, _failed(err, opening=True)) from None
    os.set_blocking(fd, True)  # O_NONBLOCK was for the open (a FIFO's reader)
    return fd


def _failed(err: OSError, opening: bool = False) -> str:
    if opening and err.errno == errno.ENXIO:
        return "could not write it (no process reads the pipe)"
    if opening and err.errno == errno.EBADF:
        return "could not write it (the descriptor is closed)"
    reason = os.strerror(err.errno) if err.errno else str(err)
    return f"could not write it ({reason})"


def _copy(tmp: Path, target: Target) -> None:
    out = _open(target)
    try:
        with open(tmp, "rb") as src:
            for block in iter(lambda: src.read(_BLOCK), b""):
                view = memoryview(block)
                while view:
                    view = view[os.write(out, view) :]
    except BrokenPipeError:
        if target.kind == "stream":
            raise  # the reader of a standard stream left (| head): as any print
        what = "could not write it (its reader left)"
        raise OutputError(target.given, what) from None
    except OSError as err:  # a full device
        raise OutputError(target.given, _failed(err)) from None
    finally:
        os.close(out)


def save_npy(path: str | os.PathLike, x: np.ndarray) -> None:
    """Write ``x`` to ``path`` as ``.npy`` (no pickles), atomically."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.save(fh, np.asarray(x), allow_pickle=False)


def write_file(path: str | os.PathLike, data: str | bytes) -> None:
    """Write ``data`` to ``path``, atomically; text is UTF-8 encoded, the bytes
    of file names that are not UTF-8 written as the OS gave them."""
    if isinstance(data, str):
        data = data.encode("utf-8", "surrogateescape")
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
