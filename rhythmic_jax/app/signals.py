"""The process the command runs in: Ctrl-C and SIGTERM end it at once (one line,
exit status 128 + signal, 130 for Ctrl-C, and no output put in place); closed
standard streams, stdio that cannot encode a path, and a memory limit end in a
result or one line (:func:`standard_streams`, :func:`memory_limit`).

Raising ``KeyboardInterrupt`` wherever the main thread happens to be does not end
a job cleanly: it lands inside JAX's garbage-collection callback (reported as
"Exception ignored", and the job goes on to write its map), inside an import,
or between a native library's calls into Python, which then crash or hang. So
:func:`install` gives SIGINT and SIGTERM a handler that raises nothing, and
hands them to a watcher thread instead: Python's C-level handler writes the
signal's number to a pipe (``signal.set_wakeup_fd``) the moment it arrives,
whatever the main thread is running (describing images, compiling, solving,
saving). The watcher cancels every output not yet in place
(:func:`rhythmic_jax.io.outputs.cancel`: atomic writers check it before their
final rename, and a rename under way finishes first), writes the line and ends
the process with ``os._exit``: no interpreter shutdown, so no destructor or
thread of XLA, orbax or torch runs again. What a job had half-written stays in
hidden temporaries that the next run removes or ignores; a checkpoint already
written stays, so the same command resumes from it.

A worker started by ``fit --processes``
(:func:`rhythmic_jax.solvers.distributed.launch_local` names its launcher in
:data:`LAUNCHER_ENV`) keeps the default actions of SIGINT and SIGTERM, which end
it even while a collective holds the interpreter, and dies with its launcher,
however the launcher ended: Linux kills it (``prctl(PR_SET_PDEATHSIG)``), and a
watcher thread also polls its parent.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
import threading
import time

from rhythmic_jax.io.outputs import cancel

__all__ = [
    "LAUNCHER_ENV",
    "MIN_ADDRESS_SPACE",
    "finish",
    "install",
    "library_folders",
    "memory_limit",
    "out_of_memory",
    "readable",
    "set_note",
    "standard_streams",
]

# the launcher's process id, set in a worker's environment by launch_local
LAUNCHER_ENV = "RHYTHMIC_JAX_LAUNCHER"
SIGNALS = (signal.SIGINT, signal.SIGTERM)
POLL_SECONDS = 0.5  # how often a worker looks for its launcher
_PR_SET_PDEATHSIG = 1
_state: dict[str, object] = {"note": None, "pipe": None}


def set_note(note: str | None) -> None:
    """A note the interrupted line ends with (where a checkpoint is kept)."""
    _state["note"] = note


def _line(prefix: str, signum: int) -> str:
    what = "interrupted" if signum == signal.SIGINT else "terminated"
    note = _state["note"]
    return f"{prefix}: {what}" + (f"; {note}" if note else "")


def _end(signum: int, prefix: str) -> None:
    """Cancel the outputs, say so in one line, exit now."""
    cancel()
    with contextlib.suppress(Exception):
        sys.stderr.flush()  # a progress bar's last output before the line
    with contextlib.suppress(OSError):
        os.write(2, (_line(prefix, signum) + "\n").encode())
    os._exit(128 + signum)


def _watch(read_fd: int, prefix: str) -> None:
    while True:
        got = [s for s in os.read(read_fd, 64) if s in SIGNALS]
        if got:
            _end(got[0], prefix)


def _watch_launcher(launcher: int) -> None:
    while os.getppid() == launcher:
        time.sleep(POLL_SECONDS)
    os._exit(128 + signal.SIGKILL)


def _relay(signum: int, frame) -> None:
    """The Python-level handler: raises nothing; pokes the watcher again in
    case a library took the wakeup pipe over."""
    with contextlib.suppress(OSError, TypeError):
        os.write(_state["pipe"], bytes([signum]))


def _die_with(launcher: int) -> None:
    """End this worker when its launcher ends (at once if it has already)."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    if os.getppid() != launcher:  # it ended before prctl took effect
        os._exit(128 + signal.SIGKILL)
    threading.Thread(
        target=_watch_launcher, args=(launcher,), name="launcher", daemon=True
    ).start()


def install(command: str | None = None) -> bool:
    """Take SIGINT and SIGTERM over for the rest of the process (the command
    line calls this first); returns False, doing nothing, outside the main
    thread. A worker of ``fit --processes`` only arranges to die with its
    launcher.

    Args:
      command: the command running, named in the line (``rhythmic-jax fit:
        interrupted``).
    """
    if threading.current_thread() is not threading.main_thread():
        return False
    launcher = os.environ.pop(LAUNCHER_ENV, None)
    if launcher is not None and launcher.isdigit():
        _die_with(int(launcher))  # a worker: its launcher speaks for it
        return True
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    _state["pipe"] = write_fd
    signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    for signum in SIGNALS:
        signal.signal(signum, _relay)
    prefix = "rhythmic-jax" + (f" {command}" if command else "")
    threading.Thread(
        target=_watch, args=(read_fd, prefix), name="signals", daemon=True
    ).start()
    return True


def finish(status: int) -> None:
    """End a failed process of a multi-process fit now (its line is written):
    flush, then ``os._exit``. The interpreter's shutdown would wait there for
    the other processes (``jax.distributed``'s last barrier), which wait for it.
    """
    if status == 0:
        return
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(status)


# ------------------------------------------------ the process's environment

# the least address space (``ulimit -v``) a command starts JAX and torch in, with
# glibc's malloc kept to one arena (measured: 1.4 GiB runs the fit of an image
# folder and an evaluation; 1 GiB fails inside XLA or torch, beyond a clean line)
MIN_ADDRESS_SPACE = 3 << 29  # 1.5 GiB
_M_ARENA_MAX = -8  # mallopt's parameter
_STDOUT_OPEN: dict[str, bool] = {}  # as the process found it (run, then main)


def readable(text: str) -> str:
    """``text`` with the bytes of file names that are not UTF-8 (carried as
    surrogate escapes) shown as ``\\xNN``, printable on any stream."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def standard_streams() -> bool:
    """Make the standard streams safe to use; returns whether standard output
    is open.

    A closed descriptor 0, 1 or 2 (``>&-``) is opened on ``/dev/null``, so no
    file the command opens takes its number (a map written where a library
    prints, and ``sys.stdout`` writes there); a closed standard error stays
    silent. What the streams cannot encode (non-ASCII paths in the C locale,
    ``PYTHONIOENCODING=ascii``) is written as backslash escapes instead of
    failing after the work is done."""
    was_open = _STDOUT_OPEN.get("open", True)
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:  # the lowest free number: fd itself, or a lower one
                os.dup2(null, fd)
                os.close(null)
            was_open = was_open and fd != 1
    if sys.stderr is None:
        sys.stderr = open(2, "w", errors="backslashreplace", closefd=False)  # noqa: SIM115
    _STDOUT_OPEN["open"] = was_open = was_open and sys.stdout is not None
    if sys.stdout is None:  # closed at start: what is printed goes to /dev/null
        sys.stdout = open(1, "w", closefd=False)  # noqa: SIM115
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, ValueError, OSError):
            stream.reconfigure(errors="backslashreplace")
    return was_open


def library_folders() -> None:
    """Keep libraries' own folders out of the user's home: imageio (under
    skimage, reading an image PIL cannot) makes ``~/.imageio`` when it looks for
    plugins; it goes to the package's cache folder instead (``$RHYTHMIC_JAX_CACHE``,
    default ``~/.cache/rhythmic_jax``), unless ``$IMAGEIO_USERDIR`` says where."""
    cache = os.environ.get("RHYTHMIC_JAX_CACHE") or os.path.join(
        os.path.expanduser("~"), ".cache", "rhythmic_jax"
    )
    os.environ.setdefault("IMAGEIO_USERDIR", cache)


def memory_limit() -> int | None:
    """The address-space limit (``ulimit -v``) in bytes, or None when there is
    none. Under one, glibc's malloc keeps one arena: the arenas of JAX's and
    torch's threads would otherwise take it whole before any array does."""
    import resource

    soft = resource.getrlimit(resource.RLIMIT_AS)[0]
    if soft == resource.RLIM_INFINITY:
        return None
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).mallopt(_M_ARENA_MAX, 1)
    return soft


def out_of_memory(err: BaseException) -> bool:
    """Whether ``err`` says memory ran out (Python's, XLA's, a library's failed
    mapping, a thread's stack), not a disk or a bad input."""
    if isinstance(err, MemoryError):
        return True
    text = str(err)
    if isinstance(err, RuntimeError) and "can't start new thread" in text:
        return True
    if "RESOURCE_EXHAUSTED" in text:
        return "No space left" not in text and "allocat" in text.lower()
    return isinstance(err, ImportError) and "failed to map segment" in text
