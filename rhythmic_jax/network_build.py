"""The compiled descriptor network built in a background process.

A job that would load the compiled network (:mod:`rhythmic_jax.compiled`) but
finds it not built yet runs eagerly and calls :func:`start_build`: a detached
process (its own session, ``nice`` 10, no terminal output) rebuilds the same
descriptor from its settings, at the job's torch thread count (part of the
package's key), and writes the package atomically. At most one builder per
package runs: it holds ``<package>.lock`` (created exclusively, holding its
process id); a lock whose process is gone, or older than
:data:`LOCK_STALE_SECONDS`, is taken over. A builder that fails writes the
reason to ``<package>.failed``, and no job starts another for that package.

Run as ``python -m rhythmic_jax.network_build SPEC`` (SPEC: JSON written by
:func:`start_build`).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import subprocess
import sys
import time
from pathlib import Path

__all__ = ["LOCK_STALE_SECONDS", "build_main", "lock_held", "start_build"]

log = logging.getLogger(__name__)

LOCK_STALE_SECONDS = 3600.0
NICE = 10


def _lock_path(package: Path) -> Path:
    return package.with_suffix(".lock")


def _failed_path(package: Path) -> Path:
    return package.with_suffix(".failed")


def lock_held(lock: Path) -> bool:
    """Whether ``lock`` belongs to a running builder (its process is alive and
    the lock younger than :data:`LOCK_STALE_SECONDS`)."""
    try:
        pid = int(lock.read_text().strip() or 0)
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


def _take_lock(lock: Path) -> bool:
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

    from rhythmic_jax.compiled import package_path

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
    from rhythmic_jax.compiled import package_path

    package = package_path(descriptor, shape, cache_dir)
    if _failed_path(package).is_file() or lock_held(_lock_path(package)):
        return None
    try:
        spec = json.dumps(_spec(descriptor, shape, cache_dir), default=str)
    except (TypeError, ValueError):  # not a dataclass of plain settings
        return None
    log.info("building the compiled %s in the background", descriptor.name)
    return _spawn([sys.executable, "-m", "rhythmic_jax.network_build", spec])


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


def build_main(spec: dict) -> int:
    """The builder: take the lock, build the package unless it is ready,
    record a failure; 0 when the package is ready (or another builder has
    the lock), 1 on failure."""
    import torch

    from rhythmic_jax import compiled
    from rhythmic_jax.features import get_descriptor

    torch.set_num_threads(spec["threads"])
    descriptor = get_descriptor(spec["name"], **spec["fields"])
    shape = tuple(spec["shape"])
    package = compiled.package_path(descriptor, shape, spec["cache_dir"])
    if str(package) != spec["package"]:  # another key here: build nothing
        return 1
    package.parent.mkdir(parents=True, exist_ok=True)
    lock = _lock_path(package)
    if not _take_lock(lock):
        return 0
    try:
        for tmp in package.parent.glob(f"{package.stem}.tmp-*"):
            if time.time() - tmp.stat().st_mtime > LOCK_STALE_SECONDS:
                tmp.unlink(missing_ok=True)  # left by a build killed mid-write
        if compiled.package_ready(package):
            return 0
        compiled._check_compiler()
        example = torch.zeros(shape).contiguous(memory_format=torch.channels_last)
        compiled._build(descriptor.network().eval(), example, package)
        return 0
    except Exception as err:
        first = (str(err).strip().splitlines() or [""])[0][:300]
        _failed_path(package).write_text(f"{type(err).__name__}: {first}\n")
        return 1
    finally:
        lock.unlink(missing_ok=True)


if __name__ == "__main__":
    os.nice(NICE)
    sys.exit(build_main(json.loads(sys.argv[1])))
