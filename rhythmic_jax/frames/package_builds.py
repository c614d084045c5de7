"""Where a compiled network's package lives, and its build in the background.

:func:`package_path` keys the package by the descriptor's settings, the weights
file, the input shape, torch's version and thread count and the CPU's vector
instructions. A build runs in a detached, niced process
(:func:`start_build`, :mod:`rhythmic_jax.frames.network_build`) that holds the
package's lock (:func:`take_lock`, :func:`lock_held`) so one builder runs at a
time; a job queues its build (:func:`build_after_jobs`) to start when the job
is over (at exit, or :func:`start_pending_builds`), so the build does not share
a small machine's cores with the job that asked for it. A build that failed
leaves ``<package>.failed`` (:func:`failed_path`) and is not started again.
:mod:`rhythmic_jax.frames.compiled` decides when to build and runs the package.
"""

from __future__ import annotations

import atexit
import dataclasses
import hashlib
import json
import logging
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

from rhythmic_jax.frames.compile_policy import BUILD_SECONDS

__all__ = [
    "LOCK_STALE_SECONDS",
    "build_after_jobs",
    "failed_path",
    "lock_held",
    "lock_path",
    "package_path",
    "start_build",
    "start_pending_builds",
    "take_lock",
]

log = logging.getLogger(__name__)

LOCK_STALE_SECONDS = 3600.0  # a builder's lock older than this is abandoned


def _weights_ident(descriptor) -> list:
    path = getattr(descriptor, "_path", None)
    path = path() if callable(path) else getattr(descriptor, "weights", None)
    if not path:
        return []
    st = Path(path).stat()
    return [str(Path(path).resolve()), st.st_size, st.st_mtime_ns]


def package_path(descriptor, shape: tuple[int, ...], cache_dir=None) -> Path:
    """``<cache>/compiled/<name>-<hash>.pt2`` of ``descriptor`` at input ``shape``."""
    import torch

    from rhythmic_jax.frames.cache_files import default_cache_dir

    ident = dict(
        name=descriptor.name,
        settings=descriptor.settings(),
        weights=_weights_ident(descriptor),
        shape=list(shape),
        torch=torch.__version__,
        threads=torch.get_num_threads(),
        cpu=[platform.machine(), torch.backends.cpu.get_cpu_capability()],
    )
    digest = hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    return folder / "compiled" / f"{descriptor.name}-{digest[:16]}.pt2"


def lock_path(package: Path) -> Path:
    return package.with_suffix(".lock")


def failed_path(package: Path) -> Path:
    return package.with_suffix(".failed")


def lock_held(lock: Path) -> bool:
    """Whether ``lock`` belongs to a running builder (its process is alive and
    the lock younger than :data:`LOCK_STALE_SECONDS`)."""
    from rhythmic_jax.io.reader import read_text

    try:  # a pipe or device there: InputError, a ValueError
        pid = int(read_text(lock, 4096).strip() or 0)
        age = time.time() - lock.stat().st_mtime
    except (OSError, ValueError):
        return False
    if pid <= 0 or age > LOCK_STALE_SECONDS:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


def take_lock(lock: Path) -> bool:
    """Create ``lock`` with this process's id; take over a stale one."""
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            if lock_held(lock):
                return False
            lock.unlink(missing_ok=True)  # its builder is gone
            continue
        with os.fdopen(fd, "w") as f:
            f.write(f"{os.getpid()}\n")
        return True
    return False


def _spec(descriptor, shape: tuple[int, ...], cache_dir) -> dict:
    import torch

    fields = {
        f.name: getattr(descriptor, f.name)
        for f in dataclasses.fields(descriptor)
        if f.init
    }
    return dict(
        name=descriptor.name,
        fields=fields,
        shape=list(shape),
        cache_dir=None if cache_dir is None else str(cache_dir),
        threads=torch.get_num_threads(),
        package=str(package_path(descriptor, shape, cache_dir)),
    )


def start_build(descriptor, shape: tuple[int, ...], cache_dir=None):
    """Start a background build of ``descriptor``'s package at ``shape``; the
    process (``subprocess.Popen``), or None when a builder already runs, one
    failed before, or the descriptor cannot be described by its fields."""
    package = package_path(descriptor, shape, cache_dir)
    if failed_path(package).is_file() or lock_held(lock_path(package)):
        return None
    try:
        spec = json.dumps(_spec(descriptor, shape, cache_dir), default=str)
    except (TypeError, ValueError):  # not a dataclass of plain settings
        return None
    log.info("building the compiled %s in the background", descriptor.name)
    return _spawn([sys.executable, "-m", "rhythmic_jax.frames.network_build", spec])


_PENDING: dict[str, tuple] = {}  # package -> (descriptor, shape, cache folder)


def build_after_jobs(descriptor, shape: tuple[int, ...], cache_dir=None) -> None:
    """Queue a background build of ``descriptor``'s package at ``shape``, started
    when this process's jobs are over (at exit, or :func:`start_pending_builds`)
    rather than beside the job: on two cores a builder beside the first job
    halves its frames per second (``reports/network.md``)."""
    key = str(package_path(descriptor, shape, cache_dir))
    if not _PENDING:
        atexit.register(start_pending_builds)  # once per queue filled
    if key not in _PENDING:
        log.info(
            "the compiled %s is built in the background once this job is over "
            "(about %d s of CPU, once per machine); this job runs eagerly",
            descriptor.name, BUILD_SECONDS,
        )  # fmt: skip
    _PENDING.setdefault(key, (descriptor, shape, cache_dir))


def start_pending_builds() -> list[subprocess.Popen]:
    """Start the builds :func:`build_after_jobs` queued (each as
    :func:`start_build` does: not while another builder holds its lock, nor
    after a failure); the processes started."""
    started = []
    while _PENDING:
        _, (descriptor, shape, cache_dir) = _PENDING.popitem()
        try:
            proc = start_build(descriptor, shape, cache_dir)
        except OSError:  # a cache gone unwritable meanwhile: no build, no trace
            proc = None
        if proc is not None:
            started.append(proc)
    return started


def _spawn(argv: list[str]) -> subprocess.Popen:
    """Start ``argv`` detached: its own session, no terminal, not waited for."""
    return subprocess.Popen(
        argv,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        close_fds=True,
    )

