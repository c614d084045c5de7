"""Resumable minibatch training runs and batches streamed from disk.

:func:`train_run` takes optax Adam steps
(:func:`rhythmic_jax.solvers.optax_loops.minibatch_step`) over every epoch's batches
and keeps orbax checkpoints of the whole state (templates, optimiser state, step):
every ``checkpoint_every`` steps, at the end, and when the run stops early (an
exception, Ctrl-C). Started again on the same folder it resumes from the latest
one; the epoch and the position within it follow from the step, so
``batches_for_epoch(epoch)`` must be deterministic. A run killed at any moment
(even SIGKILL) and resumed ends on the templates of an uninterrupted run. When
the frames do not fit in memory
(:func:`rhythmic_jax.solvers.memory.check_memory`),
:func:`memmap_batches` streams them from a memory-mapped ``.npy`` file::

    batches = memmap_batches("ref.npy", labels, periods, batch_size=512, seed=0)
    params = train_run(batches, ridge_start(x0, y0, c), c, n, RunConfig(), "run/")

Names: n frames, d features, p templates (sum of the periods), m batch rows.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.reader import load_npy
from rhythmic_jax.progress import bar as progress_bar
from rhythmic_jax.solvers.objective import Templates, targets
from rhythmic_jax.solvers.optax_loops import TrainState, adam, minibatch_step
from rhythmic_jax.validate import check_int, check_labels

__all__ = ["RunConfig", "memmap_batches", "train_run"]

log = logging.getLogger(__name__)
Batch = tuple[np.ndarray | jax.Array, np.ndarray | jax.Array]
# settings that change the trajectory: a checkpoint only resumes a run that agrees
_TRAJECTORY = ("batch_size", "learning_rate", "seed", "source")


@dataclass(frozen=True)
class RunConfig:
    """A minibatch training run.

    Attributes:
      epochs: passes over the batches of :func:`train_run`'s ``batches_for_epoch``.
      batch_size: rows per batch (recorded; :func:`memmap_batches` takes it too).
      learning_rate: Adam's step size.
      checkpoint_every: steps between checkpoints (one more is kept at the end).
      seed: the batch order's seed (recorded; give the same to the batches).
      source: what the batches are (e.g. the augmentations and frames of an
        augmented fit); recorded, and a checkpoint only resumes the same source.

    ``RunConfig(epochs=2, batch_size=8, checkpoint_every=1)`` is the fault test's
    run (``pytest tests/test_faults.py``): killed with SIGKILL and resumed, it ends
    on the templates of an uninterrupted run.
    """

    epochs: int = 10
    batch_size: int = 256
    learning_rate: float = 1e-3
    checkpoint_every: int = 100
    seed: int = 0
    source: str = ""

    def __post_init__(self):
        for name in ("epochs", "batch_size", "checkpoint_every", "seed"):
            value, least = getattr(self, name), int(name != "seed")
            msg = f"RunConfig.{name} must be an integer >= {least}, got {value!r}"
            check_int(value, name, least, msg=msg)
        rate = self.learning_rate
        if isinstance(rate, bool) or not isinstance(rate, int | float) or rate <= 0:
            raise InputError(f"RunConfig.learning_rate must be positive, got {rate!r}")
        if not isinstance(self.source, str):
            raise InputError(f"RunConfig.source must be a string, got {self.source!r}")


# ------------------------------------------------------------------ checkpoints


# a manager's folder opened where tensorstore could not take its name: id -> fd
_ALIASES: dict[int, int] = {}


def _manager(ckpt_dir: Path):
    import orbax.checkpoint as ocp  # deferred: orbax is slow to import

    options = ocp.CheckpointManagerOptions(
        max_to_keep=2,
        create=True,
        cleanup_tmp_directories=True,  # what a killed save left behind
        enable_async_checkpointing=False,
    )
    handlers = {
        "state": ocp.StandardCheckpointHandler(),
        "config": ocp.JsonCheckpointHandler(),
    }
    from rhythmic_jax.io.checkpoint import orbax_folder

    folder, fd = orbax_folder(ckpt_dir)  # a name tensorstore takes
    manager = ocp.CheckpointManager(folder, options=options, item_handlers=handlers)
    if fd is not None:
        _ALIASES[id(manager)] = fd
    return manager


def _save(manager, state: TrainState, config: RunConfig) -> int:
    import orbax.checkpoint as ocp

    step = int(state.step)
    args = ocp.args.Composite(
        state=ocp.args.StandardSave(state),
        config=ocp.args.JsonSave(dataclasses.asdict(config)),
    )
    manager.save(step, args=args, force=True)
    manager.wait_until_finished()
    log.debug("checkpoint at step %d", step)
    return step


def _check_saved(manager, step: int, where: str, fresh: TrainState, config) -> None:
    """Refuse a checkpoint of other templates or another batch order / step size."""
    import orbax.checkpoint as ocp

    try:
        tree = manager.item_metadata(step)["state"].tree["params"]
        shapes = (tuple(tree["w"].shape), tuple(tree["b"].shape))
        saved = manager.restore(
            step, args=ocp.args.Composite(config=ocp.args.JsonRestore())
        ).config
    except Exception as err:  # noqa: BLE001 - orbax raises many kinds
        first = (str(err).splitlines() or [type(err).__name__])[0][:200]
        raise InputError(
            f"{where}: checkpoint {step} is not a training run's ({first})"
        ) from None
    want = (tuple(fresh.params.w.shape), tuple(fresh.params.b.shape))
    if shapes != want:
        raise InputError(
            f"{where}: checkpoint {step} holds templates w, b of shapes {shapes}, "
            f"this run has {want}; give a new folder"
        )
    if not isinstance(saved, dict):
        raise InputError(f"{where}: checkpoint {step} holds no run settings")
    saved = {**dataclasses.asdict(RunConfig()), **saved}  # fields added since
    differ = [k for k in _TRAJECTORY if saved[k] != getattr(config, k)]
    if differ:
        was = ", ".join(f"{k}={saved[k]!r}" for k in differ)
        now = ", ".join(f"{k}={getattr(config, k)!r}" for k in differ)
        raise InputError(
            f"{where}: checkpoints were written with {was}, this run has {now}; "
            "resume with the same settings or give a new folder"
        )


def _restore(manager, ckpt_dir: Path, fresh: TrainState, config: RunConfig):
    """The latest checkpoint's state, or None when the folder holds none."""
    import orbax.checkpoint as ocp

    step = manager.latest_step()
    if step is None:
        return None
    _check_saved(manager, step, str(ckpt_dir), fresh, config)
    abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, fresh)
    args = ocp.args.Composite(state=ocp.args.StandardRestore(abstract))
    state = manager.restore(step, args=args).state
    log.info("resuming from %s at step %d", ckpt_dir, int(state.step))
    return dataclasses.replace(
        fresh, params=state.params, opt_state=state.opt_state,
        step=jnp.asarray(state.step),
    )  # fmt: skip


# --------------------------------------------------------------------- the loop


def _remaining(batches: Iterable[Batch], skip: int) -> tuple[Iterable[Batch], int]:
    """Drop the first ``skip`` batches of an epoch: (what is left, still to skip)."""
    if hasattr(batches, "__len__") and skip >= len(batches):
        return (), skip - len(batches)  # the whole epoch is done: no reads
    if isinstance(batches, Sequence):
        return (batches[i] for i in range(skip, len(batches))), 0
    it = iter(batches)
    done = sum(1 for _ in itertools.islice(it, skip))
    return it, skip - done


def train_run(
    batches_for_epoch: Callable[[int], Iterable[Batch]],
    init: Templates,
    c: float,
    n: int,
    config: RunConfig,
    ckpt_dir: str | os.PathLike | None,
    progress: bool = False,
    timings: dict[str, float] | None = None,
) -> Templates:
    """Adam over ``config.epochs`` passes of minibatches, resumable from checkpoints.

    Args:
      batches_for_epoch: ``epoch -> iterable of (x (m, d), y (m, p))``; the same
        batches for the same epoch on every call (a resume skips the ones done).
        A sized sequence (such as :func:`memmap_batches`' epochs) is skipped
        without reading it.
      init: starting templates, w (d, p), b (p,) (e.g. ``ridge_start`` of a subset).
      c: the penalty C; n: frames per epoch (each batch's loss is weighted n / m).
      config: the run's settings.
      ckpt_dir: folder of the orbax checkpoints (the last 2 are kept); None for no
        checkpoints. A folder that holds a checkpoint resumes from its latest.
      progress: show a progress bar over steps.
      timings: when given, ``timings["step"]`` accumulates the seconds spent in
        optimiser steps.

    The run trains on the first local device: the state and every batch are put
    there (committed), so the step compiles once whether a batch comes from numpy,
    from torch by DLPack or from another device.

    Returns:
      The trained templates. On an exception or Ctrl-C the state reached is saved
      first, then the exception propagates.
    """
    # Every argument of the step lives committed on one device: a jit caches one
    # program per placement, so a batch handed over by DLPack (committed) after
    # one from numpy (not) would otherwise compile the step again.
    device = jax.local_devices()[0]
    params = Templates(jnp.asarray(init.w), jnp.asarray(init.b))
    state = TrainState.create(params, adam(config.learning_rate))
    state = jax.device_put(state, device)
    log.info("train_run %s, C=%.4g, n=%d, devices %s", config, c, n, jax.devices())
    manager = saved = None
    if ckpt_dir is not None:
        ckpt_dir = Path(ckpt_dir).expanduser().absolute()
        manager = _manager(ckpt_dir)
        try:
            restored = _restore(manager, ckpt_dir, state, config)
        except BaseException:
            _close(manager)
            raise
        if restored is not None:
            state, saved = jax.device_put(restored, device), int(restored.step)
    skip = int(state.step)
    first = batches_for_epoch(0)
    per_epoch = len(first) if hasattr(first, "__len__") else None
    total = per_epoch * config.epochs if per_epoch is not None else None
    bar = progress_bar(
        total=total, initial=skip, desc="train", unit="step", show=progress
    )
    try:
        for epoch in range(config.epochs):
            batches = first if epoch == 0 else batches_for_epoch(epoch)
            todo, skip = _remaining(batches, skip)
            for xb, yb in todo:
                xb = jax.device_put(jnp.asarray(xb, jnp.float32), device)
                yb = jax.device_put(jnp.asarray(yb, jnp.float32), device)
                scale = n / xb.shape[0]
                t = time.perf_counter()
                state, loss = minibatch_step(state, xb, yb, c, scale)
                step = int(state.step)
                if timings is not None:
                    loss.block_until_ready()
                    seconds = time.perf_counter() - t
                    timings["step"] = timings.get("step", 0.0) + seconds
                bar.update(1)
                if progress:
                    bar.set_postfix(epoch=epoch, loss=f"{float(loss):.5g}")
                if manager is not None and step % config.checkpoint_every == 0:
                    saved = _save(manager, state, config)
    except BaseException:
        if manager is not None and saved != int(state.step):
            try:  # keep what was reached; the original error matters more
                _save(manager, state, config)
            except Exception as err:  # noqa: BLE001
                log.warning("could not save the last checkpoint: %s", err)
        raise
    else:
        if manager is not None and saved != int(state.step):
            _save(manager, state, config)
    finally:
        bar.close()
        if manager is not None:
            _close(manager)
    return state.params


def _close(manager) -> None:
    """Close orbax's manager without masking the error (or Ctrl-C) being raised."""
    try:
        manager.close()
    except Exception as err:  # noqa: BLE001 - orbax raises many kinds
        log.warning("could not close the checkpoint manager cleanly: %s", err)
    fd = _ALIASES.pop(id(manager), None)
    if fd is not None:
        os.close(fd)


# -------------------------------------------------------------- streamed batches


class _EpochBatches(Sequence):
    """The batches of one epoch, read on access from a memory-mapped (n, d) array."""

    def __init__(self, x, path: Path, labels, periods, batch_size: int, order):
        self._x, self._path, self._labels = x, path, labels
        self._periods, self._size, self._order = periods, batch_size, order

    def __len__(self) -> int:
        return -(-len(self._order) // self._size)

    def __getitem__(self, i: int) -> tuple[np.ndarray, jax.Array]:
        if not 0 <= i < len(self):
            raise IndexError(i)
        rows = np.sort(self._order[i * self._size : (i + 1) * self._size])
        with np.errstate(over="ignore"):  # float64 beyond float32 -> inf, refused
            x = np.asarray(self._x[rows], dtype=np.float32)
        bad = ~np.isfinite(x).all(axis=1)
        if bad.any():
            row = int(rows[np.flatnonzero(bad)[0]])
            raise InputError(f"{self._path}: row {row} holds NaN or inf (as float32)")
        return x, targets(self._labels[rows], self._periods)


def memmap_batches(
    path: str | os.PathLike,
    labels,
    periods: Sequence[int],
    batch_size: int,
    seed: int,
) -> Callable[[int], Sequence[tuple[np.ndarray, jax.Array]]]:
    """Shuffled minibatches read from an (n, d) ``.npy`` file, for :func:`train_run`.

    The file is opened with ``np.load(mmap_mode="r")`` (nothing is unpickled):
    only the rows of a batch are read, when the batch is taken. Epoch ``e`` visits
    every row once in the order of ``default_rng([seed, e]).permutation(n)``;
    batch ``i`` holds the rows ``order[i*m : (i+1)*m]`` (sorted, for the disk),
    the last batch the remainder.

    Args:
      path: float (n, d) descriptors; labels: (n,) place of every row;
      periods: the template periods (targets ``y`` are (m, sum(periods)) ±1).

    Returns:
      ``epoch -> sequence of (x (m, d) float32, y (m, p) float32)``.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"descriptor file not found: {path}")
    try:
        x = load_npy(path, mmap=True)  # regular file; the header's rows in the file
    except InputError as err:
        raise InputError(f"{path}: not a readable .npy array ({err})") from None
    if x.dtype.kind not in "fiu" or x.ndim != 2 or 0 in x.shape:
        raise InputError(
            f"{path}: expected a non-empty (n, d) real array, got {x.dtype} {x.shape}"
        )
    labels = check_labels(labels, len(x))
    periods = tuple(int(t) for t in periods)
    if not periods or min(periods) < 1:
        raise InputError(f"periods must be positive integers, got {periods}")
    check_int(batch_size, "batch_size", 1)
    check_int(seed, "seed", 0)

    def batches_for_epoch(epoch: int) -> _EpochBatches:
        order = np.random.default_rng([seed, epoch]).permutation(len(x))
        return _EpochBatches(x, path, labels, periods, batch_size, order)

    return batches_for_epoch
