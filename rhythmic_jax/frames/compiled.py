"""The descriptor network compiled for this CPU (AOTInductor), with eager as reference.

A network descriptor (``prepare`` + ``network``, see
:mod:`rhythmic_jax.frames.features`) runs either eagerly or as an AOTInductor
package: ``torch.export`` of the module at a fixed batch of :data:`COMPILE_BATCH`
frames, compiled by inductor to C++ for this CPU with the weights frozen (batch
norms folded into the convolutions). A batch of any size runs in chunks of that
shape, the last chunk padded, so nothing is ever compiled again; the eager module
runs in slices of :data:`EAGER_BATCH` frames (:class:`Sliced`). The package is
written once (atomically) under ``<cache folder>/compiled/`` and keyed by the
descriptor's settings, the weights file, the input shape, torch's version and thread
count and the CPU's vector instructions; later jobs load it instead of compiling
(torch's package loader itself, without importing inductor, which is slower to
import than loading is; ``reports/frames.md``).

Whether compiling pays is decided per job (:func:`plan`, with the policy and
numbers of :mod:`rhythmic_jax.frames.compile_policy`): loading a ready
package costs about :data:`LOAD_SECONDS`, and the compiled network saves more
than a millisecond a frame (``reports/network.md``), so a job of
:data:`LOAD_MIN_FRAMES` frames or more loads it. When the package is not built
yet, building it costs about :data:`BUILD_SECONDS`: a job of
:data:`BUILD_MIN_FRAMES` frames or more builds it first; a smaller one runs
eagerly and hands the build to a detached, niced background process
(:func:`start_build`, :mod:`rhythmic_jax.frames.network_build`) started when the
job is over (:func:`build_after_jobs`: when the process exits, or at
:func:`start_pending_builds`), so the build does not share a small machine's
cores with the job that asked for it, and the next job on the machine runs
compiled. One builder at a time holds ``<package>.lock``; the
package appears whole or not at all (temporary file, ``os.replace``); a damaged
package is deleted and built again, never loaded.
``RHYTHMIC_JAX_NETWORK_BUILD=0`` keeps builds out of the background. Where
compiling cannot work (no C++ compiler, an unsupported platform) the job logs
one warning line and runs eagerly; a background build that failed leaves
``<package>.failed`` (delete it to try again) and is not started again.

The package's path, its lock and its build in the background are
:mod:`rhythmic_jax.frames.package_builds`'s (importable from here too).
"""

from __future__ import annotations

import functools
import logging
import os
import tempfile
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from rhythmic_jax.frames.compile_policy import (
    AUTO,
    BUILD_MIN_FRAMES,
    COMPILE_MODES,
    LOAD_MIN_FRAMES,
    CompilePolicy,
)
from rhythmic_jax.frames.package_builds import LOCK_STALE_SECONDS as LOCK_STALE_SECONDS
from rhythmic_jax.frames.package_builds import build_after_jobs as build_after_jobs
from rhythmic_jax.frames.package_builds import failed_path as failed_path
from rhythmic_jax.frames.package_builds import lock_held as lock_held
from rhythmic_jax.frames.package_builds import lock_path as lock_path
from rhythmic_jax.frames.package_builds import package_path as package_path
from rhythmic_jax.frames.package_builds import start_build as start_build
from rhythmic_jax.frames.package_builds import (
    start_pending_builds as start_pending_builds,
)
from rhythmic_jax.frames.package_builds import take_lock as take_lock

__all__ = [
    "AUTO",
    "BUILD_MIN_FRAMES",
    "build_after_jobs",
    "start_pending_builds",
    "COMPILE_BATCH",
    "COMPILE_MODES",
    "EAGER_BATCH",
    "LOAD_MIN_FRAMES",
    "CompilePolicy",
    "FastDescriptor",
    "Sliced",
    "network_runner",
    "package_path",
    "failed_path",
    "lock_held",
    "lock_path",
    "package_ready",
    "plan",
    "stages",
    "start_build",
    "take_lock",
]

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    import torch

# Frames per network call, compiled and eager. Small batches keep each layer's
# activations in the CPU's caches: on the 2-core reference machine
# (scripts/bench_frames.py network, reports/network.md, two runs) EfficientNet-Lite0 at
# 224x112 compiled ran at 447-535 frames/s in batches of 8 (507-518 at 4, within
# the runs' noise) against 276-279 in batches of 32 and 231-240 at 64, and
# eagerly at 298-300 frames/s in batches of 4 against 175-185 at 8 and 90-97 at 64.
COMPILE_BATCH = 8
EAGER_BATCH = 4
BUILD_ENV = "RHYTHMIC_JAX_NETWORK_BUILD"  # "0": no background builds


def plan(descriptor, frames: int, policy: CompilePolicy, ready: bool) -> str:
    """What a job of ``frames`` frames does with ``descriptor``'s network.

    ``ready``: the package is on disk, whole. Returns ``"eager"``, ``"load"``
    (the ready package), ``"build"`` (build it in this job, then load it) or
    ``"background"`` (run eagerly; a background process builds it for the next
    jobs).
    """
    if policy.mode == "never" or not hasattr(descriptor, "network"):
        return "eager"
    compiled = "load" if ready else "build"
    if policy.mode == "always":
        return compiled
    if policy.min_frames is not None:
        return compiled if frames >= policy.min_frames else "eager"
    if frames < LOAD_MIN_FRAMES:
        return "eager"
    if ready or frames >= BUILD_MIN_FRAMES:
        return compiled
    off = os.environ.get(BUILD_ENV, "").strip().lower() in ("0", "off", "no", "false")
    return "eager" if off else "background"


def package_ready(path: Path) -> bool:
    """Whether the package ``path`` is on disk and whole (every member's CRC
    checks); a damaged one is deleted, with a warning, to be built again."""
    if not path.is_file():
        return False
    try:
        with zipfile.ZipFile(path) as z:
            bad = z.testzip()
    except (OSError, zipfile.BadZipFile, EOFError) as err:
        bad = f"{type(err).__name__}: {err}"
    if bad is None:
        return True
    log.warning("%s: damaged compiled network (%s); building it again", path, bad)
    path.unlink(missing_ok=True)
    return False


def _build(module: torch.nn.Module, example: torch.Tensor, path: Path) -> None:
    """Export ``module`` at ``example``'s shape and write its AOTInductor package."""
    import torch
    import torch._inductor

    from rhythmic_jax.frames.cache_files import default_cache_dir

    os.environ.setdefault(
        "TORCHINDUCTOR_CACHE_DIR", str(default_cache_dir() / "inductor")
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    with torch.no_grad():
        exported = torch.export.export(module, (example,))
    fd, tmp = tempfile.mkstemp(
        dir=path.parent, prefix=f"{path.stem}.tmp-", suffix=".pt2"
    )
    os.close(fd)
    try:
        torch._inductor.aoti_compile_and_package(
            exported, package_path=tmp, inductor_configs={"freezing": True}
        )
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)


def _check_compiler() -> None:
    """Raise when inductor finds no working C++ compiler (``$CXX``, else g++)."""
    from torch._inductor import cpp_builder

    cpp_builder.get_cpp_compiler()


def _load(path: Path) -> Callable[[torch.Tensor], torch.Tensor]:
    """The package as a function of the batch, by torch's C++ package loader
    (what ``torch._inductor.aoti_load_package`` wraps, without importing
    inductor); a torch without it takes that public route."""
    import torch
    from torch.utils import _pytree as pytree

    try:
        loader = torch._C._aoti.AOTIModelPackageLoader(str(path), "model", False, 1, -1)
        out_spec = pytree.treespec_loads(loader.get_call_spec()[1])
    except AttributeError:  # another torch's layout: its public loader
        import torch._inductor

        return torch._inductor.aoti_load_package(str(path))

    def run(x: torch.Tensor) -> torch.Tensor:
        return pytree.tree_unflatten(loader.boxed_run([x]), out_spec)

    return run


def _chunked(
    fn: Callable[[torch.Tensor], torch.Tensor], batch: int, pad: bool = True
) -> Callable[[torch.Tensor], torch.Tensor]:
    """Run ``fn`` on any number of rows in chunks of ``batch``: (m, ...) -> (m,
    dim). With ``pad`` (``fn`` takes exactly ``batch`` rows) the last chunk is
    padded with zeros and its padding dropped; without, it goes as it is."""
    import torch

    def run(x: torch.Tensor) -> torch.Tensor:
        outs = []
        for i in range(0, len(x), batch):
            part = x[i : i + batch]
            m = len(part)
            if pad and m < batch:
                zeros = part.new_zeros((batch - m, *part.shape[1:]))
                part = torch.cat([part, zeros]).contiguous(
                    memory_format=torch.channels_last
                )
            outs.append(fn(part)[:m])
        if not outs:
            return fn(x.new_zeros((batch, *x.shape[1:])) if pad else x)[:0]
        return outs[0] if len(outs) == 1 else torch.cat(outs)

    return run


class Sliced:
    """The eager ``module`` run on at most ``batch`` rows at a time (faster on a
    CPU than one large call: see :data:`EAGER_BATCH`); (m, ...) -> (m, dim)."""

    def __init__(self, module: torch.nn.Module, batch: int):
        self.module, self.batch = module, batch
        self._run = _chunked(module, batch, pad=False)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return self._run(x)


@functools.lru_cache(maxsize=4)
def _compiled(descriptor, shape: tuple[int, ...], cache_dir) -> Callable | None:
    """The loaded package (built first when missing); None when compiling fails."""
    import torch

    path = package_path(descriptor, shape, cache_dir)
    try:
        if not package_ready(path):
            _check_compiler()  # before minutes of export and code generation
            log.info("compiling %s for %s (once per machine)", descriptor.name, shape)
            example = torch.zeros(shape).contiguous(memory_format=torch.channels_last)
            _build(descriptor.network().eval(), example, path)
        return _load(path)
    except Exception as err:  # no compiler, unsupported platform, broken package
        reason = (str(err).strip().splitlines() or [type(err).__name__])[0][:160]
        log.warning(
            "%s: compiling the network failed (%s: %s); running it eagerly",
            descriptor.name,
            type(err).__name__,
            reason,
        )
        return None


def network_runner(
    descriptor,
    frames: int,
    policy: CompilePolicy = AUTO,
    cache_dir=None,
) -> Callable[[torch.Tensor], torch.Tensor]:
    """The function a job of ``frames`` frames runs on prepared batches.

    ``(m, 3, h, w)`` (``descriptor.prepare``'s output) -> ``(m, dim)`` rows, the
    compiled package where :func:`plan` says it pays and it can be built, else
    the eager module (the reference); with ``"background"`` a builder process
    is queued for the next jobs, started once this one is over
    (:func:`build_after_jobs`).
    """

    if isinstance(descriptor, FastDescriptor):
        return descriptor._run
    if not hasattr(descriptor, "network"):
        return descriptor
    eager = Sliced(descriptor.network().eval(), EAGER_BATCH)
    shape = (COMPILE_BATCH, 3, descriptor.height, descriptor.width)
    path = package_path(descriptor, shape, cache_dir)
    try:
        step = plan(descriptor, frames, policy, path.is_file())
        if step == "load" and not package_ready(path):  # damaged: deleted
            step = plan(descriptor, frames, policy, False)
        if step == "background":
            lock_held(lock_path(path))  # an unreadable cache: said now, not at exit
            build_after_jobs(descriptor, shape, cache_dir)
    except OSError as err:  # a cache that cannot be read or written: warn once
        from rhythmic_jax.frames.cache_files import cache_unusable

        cache_unusable(path.parent, "using the compiled network", err)
        return eager
    if step in ("eager", "background"):
        return eager
    fn = _compiled(descriptor, shape, None if cache_dir is None else str(cache_dir))
    return eager if fn is None else _chunked(fn, COMPILE_BATCH)


class FastDescriptor:
    """``descriptor`` whose network runs through :func:`network_runner`.

    Same ``name``, ``settings()``, ``dim`` and ``prepare``; calling it on a batch
    (b, 3, H, W) in [0, 1] gives the same rows (b, dim) as the descriptor (to
    float32 rounding), from the compiled network when the job is large enough.
    """

    def __init__(self, descriptor, frames: int, policy: CompilePolicy = AUTO):
        self.descriptor = descriptor
        self.name = descriptor.name
        self._run = network_runner(descriptor, frames, policy)
        self._prepare = getattr(descriptor, "prepare", None)

    def __getattr__(self, key: str):
        return getattr(self.descriptor, key)

    def __call__(self, batch: torch.Tensor) -> torch.Tensor:
        import torch

        with torch.inference_mode():
            x = self._prepare(batch) if self._prepare is not None else batch
            return self._run(x)


def stages(descriptor) -> tuple[Callable, Callable]:
    """``(prepare, run)`` with ``descriptor(batch) == run(prepare(batch))``.

    ``prepare`` (resizing) can run ahead in another thread; ``run`` is the
    network (compiled for a :class:`FastDescriptor`), or the whole descriptor
    when it has no network.
    """
    if isinstance(descriptor, FastDescriptor):
        return descriptor._prepare or _same, descriptor._run
    if hasattr(descriptor, "network"):
        return descriptor.prepare, Sliced(descriptor.network().eval(), EAGER_BATCH)
    return _same, descriptor


def _same(x):
    return x
