"""The background builder of the compiled descriptor network.

``python -m rhythmic_jax.frames.network_build SPEC`` is the process that
:func:`rhythmic_jax.frames.compiled.start_build` starts (detached, ``nice`` 10): it
rebuilds the descriptor from SPEC (JSON: its name and fields, the input shape,
the cache folder, the job's torch thread count, which is part of the package's
key), takes the package's lock (:func:`rhythmic_jax.frames.compiled.take_lock`), and
builds the package unless it is ready; a failure is written to
``<package>.failed``.
"""

from __future__ import annotations

import json
import os
import sys
import time

__all__ = ["NICE", "build_main"]

NICE = 10


def build_main(spec: dict) -> int:
    """The builder: take the lock, build the package unless it is ready,
    record a failure; 0 when the package is ready (or another builder has
    the lock), 1 on failure."""
    import torch

    from rhythmic_jax.frames import compiled
    from rhythmic_jax.frames.features import get_descriptor

    torch.set_num_threads(spec["threads"])
    descriptor = get_descriptor(spec["name"], **spec["fields"])
    shape = tuple(spec["shape"])
    package = compiled.package_path(descriptor, shape, spec["cache_dir"])
    if str(package) != spec["package"]:  # another key here: build nothing
        return 1
    package.parent.mkdir(parents=True, exist_ok=True)
    lock = compiled.lock_path(package)
    if not compiled.take_lock(lock):
        return 0
    try:
        for tmp in package.parent.glob(f"{package.stem}.tmp-*"):
            if time.time() - tmp.stat().st_mtime > compiled.LOCK_STALE_SECONDS:
                tmp.unlink(missing_ok=True)  # left by a build killed mid-write
        if compiled.package_ready(package):
            return 0
        compiled._check_compiler()
        example = torch.zeros(shape).contiguous(memory_format=torch.channels_last)
        compiled._build(descriptor.network().eval(), example, package)
        return 0
    except Exception as err:
        first = (str(err).strip().splitlines() or [""])[0][:300]
        compiled.failed_path(package).write_text(f"{type(err).__name__}: {first}\n")
        return 1
    finally:
        lock.unlink(missing_ok=True)


if __name__ == "__main__":
    os.nice(NICE)
    sys.exit(build_main(json.loads(sys.argv[1])))
